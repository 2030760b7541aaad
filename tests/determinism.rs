//! Results are bitwise identical for 1 and 2 worker threads (forward and reverse).

mod common;

use common::*;
use morph::loss::MassLossKind;
use morph::mpm::{Gradients, KernelKind, State, Tape};
use morph::scene::{EffectConfig, SceneConfig};
use nalgebra::Vector3;

fn run_with_threads(threads: usize, kernel: KernelKind) -> (State, Gradients) {
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
        let (sim, mut init) = ball(&scene, 7.0);
        let mut rng = Lcg(3);
        deform(&mut init, &mut rng);
        let ctrl = controls(init.len(), 20, 10, 0.05, &mut rng);
        let loss = shifted_target(&sim, &init, Vector3::new(2.0, 0.0, 1.0), MassLossKind::Log);
        let mut tape = Tape::default();
        let (_, last) = rollout_loss(&sim, &init, &ctrl, 20, &loss, Some(&mut tape));
        let grads = sim.backward(&tape, &ctrl, loss_seed(&sim, &last, &loss));
        (last, grads)
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
        assert!(bits(&s1) == bits(&s2), "{kernel:?}: final states differ");
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
            fc_bits(&g1) == fc_bits(&g2),
            "{kernel:?}: control gradients differ"
        );
        assert_eq!(g1.effect_params, g2.effect_params);
    }
}
