//! The reference benchmark workload (issue: "the MPM engine"): a solid ball of radius 8 cells
//! centred in a 32^3 grid (dx 1), 2x2x2 particles per cell, density 40, lam 58333,
//! mu 38888.9, drag 0.5, f64. The body is deforming: it starts with a swirl and expansion
//! velocity and receives control deformation gradients every 10 steps.

pub mod geometry;
pub mod hard_cases;
pub mod morph;
pub mod physics;
pub mod roofline;

use crate::engine::Engine;
use crate::engine::integrator::{Integrator, IntegratorKind};
use crate::engine::lanes::SimdLevel;
use crate::engine::material::svd::{svd3, svd3_batch};
use crate::engine::mpm::{KernelKind, SimError, State, StateGrad};
use crate::engine::scene::{EffectConfig, SceneConfig, ball_particles};
use crate::loss::{MassLoss, MassLossKind};
use nalgebra::{Matrix3, Vector3};
use serde_json::json;
use std::time::Instant;

/// The reference scene (with the integrator asked), its deforming initial state and per-step
/// controls.
pub struct Workload {
    pub engine: Engine,
    pub initial: State,
    pub controls: Vec<Option<crate::engine::integrator::StepControl>>,
    pub loss: MassLoss,
}

/// The reference ball's radius, in cells.
pub const REFERENCE_RADIUS: f64 = 8.0;

/// Builds the reference workload for `steps` steps with the given kernel.
pub fn reference_workload(
    kernel: KernelKind,
    integrator: IntegratorKind,
    steps: usize,
) -> Result<Workload, SimError> {
    ball_workload(REFERENCE_RADIUS, kernel, integrator, steps)
}

/// The reference workload on a ball of `radius` cells (8 is the reference, about 17,000
/// particles; 21 is about 310,000, a detailed morph's size). The grid grows with the ball:
/// 32 cells, or the ball's diameter and 8 cells of margin when that is more.
pub fn ball_workload(
    radius: f64,
    kernel: KernelKind,
    integrator: IntegratorKind,
    steps: usize,
) -> Result<Workload, SimError> {
    let scene = SceneConfig::reference();
    workload_on(radius, kernel, integrator, steps, scene.effects, true)
}

/// The grid a ball of `radius` cells is simulated on (see [`ball_workload`]).
pub fn ball_grid(radius: f64) -> crate::engine::mpm::grid::GridSpec {
    let cells = ((2.0 * radius).ceil() as usize + 8).max(32);
    crate::engine::mpm::grid::GridSpec::centred_cube(cells, 1.0)
}

/// The reference ball with the given effects, with or without control `Fc`.
pub fn workload(
    kernel: KernelKind,
    integrator: IntegratorKind,
    steps: usize,
    effects: Vec<EffectConfig>,
    with_controls: bool,
) -> Result<Workload, SimError> {
    workload_on(
        REFERENCE_RADIUS,
        kernel,
        integrator,
        steps,
        effects,
        with_controls,
    )
}

/// [`workload`] on a ball of `radius` cells.
fn workload_on(
    radius: f64,
    kernel: KernelKind,
    integrator: IntegratorKind,
    steps: usize,
    effects: Vec<EffectConfig>,
    with_controls: bool,
) -> Result<Workload, SimError> {
    let mut scene = SceneConfig::reference();
    scene.grid = ball_grid(radius);
    scene.kernel = kernel;
    scene.effects = effects;
    let (x, vol) = ball_particles(&scene.grid, Vector3::zeros(), radius, 2);
    let engine = Engine::new(
        scene.model_with(vol, &crate::geometry::MeshSolids)?,
        integrator,
    )?;
    let mut initial = State::at_rest(x);
    for p in 0..initial.len() {
        let r = initial.x[p];
        initial.v[p] = Vector3::new(-r[1], r[0], 0.3 * r[2]) * 0.5 + Vector3::new(0.5, 0.0, 0.0);
    }
    let controls = (0..steps)
        .map(|s| {
            (with_controls && s % 10 == 0).then(|| {
                initial
                    .x
                    .iter()
                    .map(|x| {
                        let a = 0.02 * (0.4 * x[0] + 0.3 * x[1]).sin();
                        Matrix3::new(a, 0.01, 0.0, -0.01, -a, 0.005, 0.0, 0.002, 0.5 * a)
                    })
                    .collect::<crate::engine::integrator::StepControl>()
            })
        })
        .collect();
    // Target: the ball shifted by two cells, as a morph would ask.
    let shifted: Vec<Vector3<f64>> = initial
        .x
        .iter()
        .map(|x| x + Vector3::new(2.0, 0.0, 0.0))
        .collect();
    let target = engine.model().mass_grid(&shifted)?;
    Ok(Workload {
        engine,
        initial,
        controls,
        loss: MassLoss::new(MassLossKind::Log, target),
    })
}

impl Workload {
    /// Forward only.
    pub fn run_forward(&self, steps: usize) -> Result<State, SimError> {
        let mut s = self.initial.clone();
        crate::engine::with_integrator!(&self.engine, sim => {
            sim.forward(&mut s, &self.controls, 0, steps, None)
        })?;
        Ok(s)
    }

    /// Forward with tape, loss on the final mass grid, reverse pass. Returns (loss, gradients).
    pub fn run_forward_reverse(
        &self,
        steps: usize,
    ) -> Result<(f64, crate::engine::mpm::Gradients), SimError> {
        crate::engine::with_integrator!(&self.engine, sim => {
            let mut s = self.initial.clone();
            let mut tape = Default::default();
            sim.forward(&mut s, &self.controls, 0, steps, Some(&mut tape))?;
            let model = sim.model();
            let mass = model.mass_grid(&s.x)?;
            let (loss, gm) = self.loss.value_and_grad(&mass);
            let mut seed = StateGrad::zeros(s.len());
            seed.x = model.mass_grid_reverse(&s.x, &gm);
            Ok((loss, sim.backward(&tape, &self.controls, seed)))
        })
    }
}

/// Runs the benchmark on a ball of `radius` cells ([`REFERENCE_RADIUS`] is the reference) and
/// prints one JSON line per configuration.
pub fn run(
    radius: f64,
    steps: usize,
    repeats: usize,
    threads: &[usize],
    kernels: &[KernelKind],
    integrators: &[IntegratorKind],
) -> anyhow::Result<()> {
    // SVD: ours against nalgebra's general SVD, single thread.
    let mats: Vec<Matrix3<f64>> = (0..200_000)
        .map(|i| {
            let t = i as f64 * 0.001;
            Matrix3::new(
                1.0 + 0.3 * t.sin(),
                0.2 * t.cos(),
                0.1,
                0.05 * t,
                0.9,
                0.3 * (2.0 * t).sin(),
                -0.1,
                0.2,
                1.1 + 0.1 * t.cos(),
            )
        })
        .collect();
    let time_it = |f: &dyn Fn(&Matrix3<f64>) -> f64| {
        let mut best = f64::INFINITY;
        for _ in 0..repeats.max(1) {
            let t0 = Instant::now();
            let acc: f64 = mats.iter().map(f).sum();
            std::hint::black_box(acc);
            best = best.min(t0.elapsed().as_secs_f64());
        }
        best / mats.len() as f64 * 1e9
    };
    let ours = time_it(&|m| svd3(m).sigma[0]);
    let theirs = time_it(&|m| m.svd(true, true).singular_values[0]);
    // In vector lanes, at each width this CPU has: time per matrix.
    let mut lanes = serde_json::Map::new();
    for simd in SimdLevel::available_levels() {
        let mut best = f64::INFINITY;
        for _ in 0..repeats.max(1) {
            let t0 = Instant::now();
            std::hint::black_box(svd3_batch(simd, &mats));
            best = best.min(t0.elapsed().as_secs_f64());
        }
        lanes.insert(simd.name().into(), json!(best / mats.len() as f64 * 1e9));
    }
    println!(
        "{}",
        json!({"bench": "svd3", "ns_per_call_morph": ours, "ns_per_call_morph_lanes": lanes,
               "ns_per_call_nalgebra": theirs})
    );

    for (&kernel, &integrator) in kernels
        .iter()
        .flat_map(|k| integrators.iter().map(move |i| (k, i)))
    {
        let w = ball_workload(radius, kernel, integrator, steps)?;
        for &t in threads {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build()?;
            let (fwd, fwdrev) = pool.install(|| -> Result<(f64, f64), SimError> {
                let mut best_f = f64::INFINITY;
                let mut best_fr = f64::INFINITY;
                for _ in 0..repeats.max(1) {
                    let t0 = Instant::now();
                    std::hint::black_box(w.run_forward(steps)?);
                    best_f = best_f.min(t0.elapsed().as_secs_f64());
                    let t0 = Instant::now();
                    std::hint::black_box(w.run_forward_reverse(steps)?);
                    best_fr = best_fr.min(t0.elapsed().as_secs_f64());
                }
                Ok((best_f, best_fr))
            })?;
            let n = w.engine.model().num_particles();
            for (mode, secs) in [("forward", fwd), ("forward_reverse", fwdrev)] {
                println!(
                    "{}",
                    json!({
                        "bench": mode, "particles": n, "kernel": kernel.name(),
                        "integrator": integrator, "device": "cpu", "threads": t,
                        "steps": steps, "seconds": secs,
                        "particle_steps_per_s": (n * steps) as f64 / secs,
                        "ms_per_step": secs / steps as f64 * 1e3,
                    })
                );
            }
        }
    }
    let threads = *threads.iter().max().unwrap_or(&1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    pool.install(|| effect_costs(steps, repeats))
}

/// The reference workload on the GPU device (Euler, in `precision`), the lines of [`run`] for each
/// kernel, with the adapter's name; the loss and its seed on the host, as [`run`]'s.
pub fn run_on_device(
    radius: f64,
    steps: usize,
    repeats: usize,
    kernels: &[KernelKind],
    precision: crate::gpu::Precision,
) -> anyhow::Result<()> {
    let dev = crate::gpu::Device::shared()?;
    if dev.software {
        eprintln!(
            "morph: warning: {} is a software driver, not a GPU",
            dev.name
        );
    }
    for &kernel in kernels {
        let w = ball_workload(radius, kernel, IntegratorKind::Euler, steps)?;
        let model = w.engine.into_model();
        let gpu = crate::gpu::GpuEuler::with_precision(dev.clone(), model, precision)?;
        let model = &gpu.model;
        let (mut best_f, mut best_fr) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..repeats.max(1) {
            let t0 = Instant::now();
            let mut s = w.initial.clone();
            gpu.forward(&mut s, &w.controls, 0, steps)?;
            best_f = best_f.min(t0.elapsed().as_secs_f64());
            let t0 = Instant::now();
            let mut s = w.initial.clone();
            let tape = gpu.forward_taped(&mut s, &w.controls, 0, steps)?;
            let (_, gm) = w.loss.value_and_grad(&model.mass_grid(&s.x)?);
            let mut seed = StateGrad::zeros(s.len());
            seed.x = model.mass_grid_reverse(&s.x, &gm);
            std::hint::black_box(gpu.backward(&tape, &w.controls, &seed));
            best_fr = best_fr.min(t0.elapsed().as_secs_f64());
        }
        let n = model.num_particles();
        for (mode, secs) in [("forward", best_f), ("forward_reverse", best_fr)] {
            println!(
                "{}",
                json!({
                    "bench": mode, "particles": n, "kernel": kernel.name(),
                    "integrator": IntegratorKind::Euler, "device": "gpu", "adapter": dev.name,
                    "precision": precision,
                    "steps": steps, "seconds": secs,
                    "particle_steps_per_s": (n * steps) as f64 / secs,
                    "ms_per_step": secs / steps as f64 * 1e3,
                })
            );
        }
    }
    Ok(())
}

/// A scene pays only for what it declares: ms per step of the cubic reference ball, forward
/// and forward+reverse (on the largest thread count asked), with no effects, with each
/// effect alone, and with everything.
fn effect_costs(steps: usize, repeats: usize) -> anyhow::Result<()> {
    use crate::engine::effects::WallMode;
    let drag = EffectConfig::drag(0.5);
    let gravity = EffectConfig::Gravity {
        acceleration: [0.0, -9.81, 0.0],
    };
    let walls = |mode| EffectConfig::Walls { mode, thickness: 3 };
    // A ground a half cell into the ball's bottom, and a cube of 8 cells under it (a mesh
    // collider, written to a temporary file), both with friction.
    let ground = EffectConfig::Collider {
        shape: crate::engine::scene::ColliderConfig::Plane {
            point: [0.0, -7.5, 0.0],
            normal: [0.0, 1.0, 0.0],
        },
        friction: 0.5,
    };
    let cube_path =
        std::env::temp_dir().join(format!("morph-bench-cube-{}.obj", std::process::id()));
    // Written just before its case and removed right after.
    let cube = EffectConfig::Collider {
        shape: crate::engine::scene::ColliderConfig::Mesh {
            path: cube_path.clone(),
            scale: 4.0,
            translation: [0.0, -11.5, 0.0],
        },
        friction: 0.5,
    };
    let cases: Vec<(&str, Vec<EffectConfig>, bool)> = vec![
        ("none", vec![], false),
        ("drag", vec![drag.clone()], false),
        ("gravity", vec![gravity.clone()], false),
        ("ground", vec![ground.clone()], false),
        ("mesh collider", vec![cube], false),
        ("slip walls", vec![walls(WallMode::Slip)], false),
        ("sticky walls", vec![walls(WallMode::Sticky)], false),
        ("controls Fc", vec![], true),
        (
            "all",
            vec![drag, gravity, ground, walls(WallMode::Slip)],
            true,
        ),
    ];
    let mut baseline = None;
    for (name, effects, controls) in cases {
        if name == "mesh collider" {
            crate::geometry::assets::cube(2.0, 8).write_obj(&cube_path)?;
        }
        let w = workload(
            KernelKind::Cubic,
            IntegratorKind::Euler,
            steps,
            effects,
            controls,
        );
        if name == "mesh collider" {
            let _ = std::fs::remove_file(&cube_path);
        }
        let w = w?;
        let (mut forward, mut both) = (f64::INFINITY, f64::INFINITY);
        // One untimed run first: the first case would otherwise pay the allocator's warm-up.
        std::hint::black_box(w.run_forward_reverse(steps)?);
        for _ in 0..repeats.max(1) {
            let t0 = Instant::now();
            std::hint::black_box(w.run_forward(steps)?);
            forward = forward.min(t0.elapsed().as_secs_f64());
            let t0 = Instant::now();
            std::hint::black_box(w.run_forward_reverse(steps)?);
            both = both.min(t0.elapsed().as_secs_f64());
        }
        let ms = forward / steps as f64 * 1e3;
        let ms_both = both / steps as f64 * 1e3;
        let (base, base_both) = *baseline.get_or_insert((ms, ms_both));
        println!(
            "{}",
            json!({
                "bench": "effects", "effects": name, "kernel": "cubic",
                "threads": rayon::current_num_threads(), "steps": steps,
                "ms_per_step": ms, "vs_none": ms / base,
                "ms_per_step_forward_reverse": ms_both, "vs_none_forward_reverse": ms_both / base_both,
            })
        );
    }
    Ok(())
}
