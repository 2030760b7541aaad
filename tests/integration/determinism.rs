//! Results are bitwise identical for 1 and 2 worker threads (forward and reverse).

use crate::common;

use common::*;
use morph::engine::effects::WallMode;
use morph::engine::integrator::{Integrator, IntegratorKind, Steps};
use morph::engine::lanes::SimdLevel;
use morph::engine::mpm::{Gradients, KernelKind, State};
use morph::engine::scene::{EffectConfig, SceneConfig};
use morph::loss::MassLossKind;
use nalgebra::Vector3;

fn run_with_threads(threads: usize, kernel: KernelKind) -> (State, Gradients) {
    run_on(threads, kernel, IntegratorKind::Euler, 20, SimdLevel::Auto)
}

/// A deforming ball (about 1,400 particles at radius 7; 2,048 or more for the ODE form's
/// parallel path at radius 8) with gravity and controls, `steps` steps with `integrator`.
fn run_on(
    threads: usize,
    kernel: KernelKind,
    integrator: IntegratorKind,
    steps: usize,
    simd: SimdLevel,
) -> (State, Gradients) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut scene = SceneConfig::reference();
        scene.kernel = kernel;
        scene.effects.push(EffectConfig::Gravity {
            acceleration: [0.0, -5.0, 0.0],
        });
        scene.effects.push(EffectConfig::Walls {
            mode: WallMode::Slip,
            thickness: 3,
        });
        let radius = match integrator {
            IntegratorKind::Euler => 7.0,
            IntegratorKind::Rk4 => 8.0,
        };
        let (engine, mut init) = ball_engine(&scene, radius, integrator);
        let engine = engine.with_simd(simd);
        let mut rng = Lcg(3);
        deform(&mut init, &mut rng);
        let ctrl = controls(init.len(), steps, 10, 0.05, &mut rng);
        let loss = shifted_target(
            engine.model(),
            &init,
            Vector3::new(2.0, 0.0, 1.0),
            MassLossKind::Log,
        );
        morph::engine::with_integrator!(&engine, sim => {
            if integrator == IntegratorKind::Rk4 {
                assert!(init.len() >= 2048, "{} particles", init.len());
            }
            let mut tape = Default::default();
            let (_, last) = rollout_loss(sim, &init, &ctrl, steps, &loss, Some(&mut tape));
            let grads = sim.backward(&tape, &shared(&ctrl), loss_seed(sim.model(), &last, &loss));
            (last, grads)
        })
    })
}

fn bits(s: &State) -> Vec<u64> {
    let mut out = Vec::new();
    for p in 0..s.len() {
        out.extend(
            s.x[p]
                .iter()
                .chain(s.v[p].iter())
                .chain(s.c[p].iter())
                .chain(s.f[p].iter())
                .map(|a| a.to_bits()),
        );
    }
    out
}

#[test]
fn one_and_two_threads_give_identical_bits() {
    for kernel in [KernelKind::Quadratic, KernelKind::Cubic] {
        let (s1, g1) = run_with_threads(1, kernel);
        let (s2, g2) = run_with_threads(2, kernel);
        same_bits(kernel, &(s1, g1), &(s2, g2));
    }
}

/// The same for RK4 through the integrator interface (deformation-gradient controls, effect
/// rates and their parameter gradients), on the ODE form's parallel path.
#[test]
fn rk4_one_and_two_threads_give_identical_bits() {
    let run = |t| {
        run_on(
            t,
            KernelKind::Cubic,
            IntegratorKind::Rk4,
            12,
            SimdLevel::Auto,
        )
    };
    same_bits(KernelKind::Cubic, &run(1), &run(2));
}

/// Every vector width this CPU has (`morph::engine::lanes`: the x86-64 baseline, AVX2, AVX-512)
/// gives the bits of the baseline, forward and reverse, under both integrators: a golden
/// file made on one machine holds on another.
#[test]
fn every_simd_width_gives_the_same_bits() {
    let levels = SimdLevel::available_levels();
    println!("widths on this CPU: {levels:?}");
    for (integrator, steps) in [(IntegratorKind::Euler, 20), (IntegratorKind::Rk4, 6)] {
        for kernel in [KernelKind::Quadratic, KernelKind::Cubic] {
            let run = |simd| run_on(2, kernel, integrator, steps, simd);
            let baseline = run(SimdLevel::Baseline);
            for &level in &levels[1..] {
                same_bits(kernel, &baseline, &run(level));
            }
        }
    }
}

fn same_bits(kernel: KernelKind, (s1, g1): &(State, Gradients), (s2, g2): &(State, Gradients)) {
    {
        assert!(bits(s1) == bits(s2), "{kernel:?}: final states differ");
        assert!(
            bits(&g1.initial) == bits(&g2.initial),
            "{kernel:?}: initial-state gradients differ"
        );
        let fc_bits = |g: &Gradients| -> Vec<u64> {
            g.controls
                .iter()
                .flatten()
                .flatten()
                .flat_map(|m| m.iter().map(|a| a.to_bits()).collect::<Vec<_>>())
                .collect()
        };
        assert!(
            fc_bits(g1) == fc_bits(g2),
            "{kernel:?}: control gradients differ"
        );
        assert_eq!(g1.effect_params, g2.effect_params);
    }
}

/// The rope (2,048 particles or more, the ODE form's parallel path) with its boundary
/// controls and the kinetic-energy cost, under both integrators: a run and its reverse pass
/// give the same bits on 1 and 2 threads.
#[test]
fn ode_parallel_path_is_bitwise_identical_across_thread_counts() {
    for kind in IntegratorKind::ALL {
        controlled_rope_bits(kind);
    }
}

fn controlled_rope_bits(integrator: IntegratorKind) {
    use morph::apps::rope::scene::{Actuation, RopeConfig};
    use morph::engine::integrator::Controlled;
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let cfg = RopeConfig {
                cells_along: 16,
                thickness_cells: 4,
                particles_per_cell: 2,
                steps: 6,
                control_interval: 2,
                actuation: Actuation::Both,
                integrator,
                ..RopeConfig::default()
            };
            let rope = cfg.build().unwrap();
            morph::engine::with_integrator!(&rope.engine, sys => {
            let model = sys.model();
            assert!(model.num_particles() >= 2048, "{}", model.num_particles());
            let mut params = model.controls().zero_params();
            let mut rng = Lcg(9);
            for knots in params.iter_mut() {
                for k in knots.iter_mut() {
                    *k = 0.002 * Vector3::new(rng.next(), rng.next(), 0.0);
                }
            }
            model.controls().project(&mut params);
            let mut s = rope.initial.clone();
            let mut tape = Default::default();
            let energy = Controlled::run(sys, &mut s, &params, Steps::new(0, 6), Some(&mut tape), &mut |_, _| {})
                .unwrap();
            let grad = sys.kinetic_cost_gradient(&tape, &params, 1.0, None);
            let mut out: Vec<u64> = energy.iter().map(|e| e.to_bits()).collect();
            for p in 0..s.len() {
                out.extend(s.x[p].iter().chain(s.v[p].iter()).map(|a| a.to_bits()));
                out.extend(s.f[p].iter().map(|a| a.to_bits()));
                out.extend(grad.initial.x[p].iter().map(|a| a.to_bits()));
                out.extend(grad.initial.f[p].iter().map(|a| a.to_bits()));
            }
            for knots in &grad.params {
                out.extend(knots.iter().flat_map(|k| k.iter().map(|a| a.to_bits())));
            }
            // Gravity's parameter gradient, summed over the grid nodes.
            out.extend(grad.effect_params.iter().flatten().map(|a| a.to_bits()));
            out
            })
        })
    };
    assert!(
        run(1) == run(2),
        "{integrator:?}: the controlled rope differs between 1 and 2 threads"
    );
}
