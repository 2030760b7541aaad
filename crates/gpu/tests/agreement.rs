//! The device's step against the CPU engine's on the reference workload (a deforming ball of
//! about 17,000 particles under drag and `Fc` controls every 10 steps), in f64.

use morph_engine::effects::WallMode;
use morph_engine::integrator::StepControl;
use morph_engine::mpm::model::Model;
use morph_engine::mpm::{Euler, KernelKind, State, StateGrad};
use morph_engine::scene::{EffectConfig, SceneConfig, ball_particles};
use morph_gpu::{Device, GpuEuler};
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;

fn device() -> Arc<Device> {
    Device::shared().unwrap_or_else(|e| {
        panic!("{e} (the GPU tests need a device; Mesa's lavapipe is one: apt-get install mesa-vulkan-drivers)")
    })
}

/// The bench's reference workload: the model, the initial state and each step's controls.
fn workload(
    kernel: KernelKind,
    steps: usize,
) -> (SceneConfig, Vec<f64>, State, Vec<Option<StepControl>>) {
    let mut scene = SceneConfig::reference();
    scene.kernel = kernel;
    let (x, vol) = ball_particles(&scene.grid, Vector3::zeros(), 8.0, 2);
    let mut initial = State::at_rest(x);
    for p in 0..initial.len() {
        let r = initial.x[p];
        initial.v[p] = Vector3::new(-r[1], r[0], 0.3 * r[2]) * 0.5 + Vector3::new(0.5, 0.0, 0.0);
    }
    let controls = (0..steps)
        .map(|s| {
            (s % 10 == 0).then(|| {
                initial
                    .x
                    .iter()
                    .map(|x| {
                        let a = 0.02 * (0.4 * x[0] + 0.3 * x[1]).sin();
                        Matrix3::new(a, 0.01, 0.0, -0.01, -a, 0.005, 0.0, 0.002, 0.5 * a)
                    })
                    .collect::<StepControl>()
            })
        })
        .collect();
    (scene, vol, initial, controls)
}

fn model(scene: &SceneConfig, vol: &[f64]) -> Model {
    scene.model(vol.to_vec()).unwrap()
}

/// Largest `|a - b|` over the largest `|b|`, field by field.
fn rel<'a, const R: usize, const C: usize>(
    a: impl Iterator<Item = &'a nalgebra::SMatrix<f64, R, C>>,
    b: impl Iterator<Item = &'a nalgebra::SMatrix<f64, R, C>> + Clone,
) -> f64 {
    let scale = b.clone().map(|m| m.amax()).fold(0.0, f64::max);
    a.zip(b).map(|(a, b)| (a - b).amax()).fold(0.0, f64::max) / scale
}

fn agree(kernel: KernelKind) {
    agree_with(kernel, SceneConfig::reference().effects, 30);
}

fn agree_with(kernel: KernelKind, effects: Vec<EffectConfig>, steps: usize) {
    let (mut scene, vol, initial, controls) = workload(kernel, steps);
    scene.effects = effects;
    let cpu = Euler::from(model(&scene, &vol));
    let mut on_cpu = initial.clone();
    cpu.forward(&mut on_cpu, &controls, 0, steps, None).unwrap();
    let dev = device();
    let m = model(&scene, &vol);
    let gpu = GpuEuler::new(dev.clone(), model(&scene, &vol)).unwrap();
    let mut on_gpu = initial.clone();
    gpu.forward(&mut on_gpu, &controls, 0, steps).unwrap();
    let fields = [
        ("x", rel(on_gpu.x.iter(), on_cpu.x.iter())),
        ("v", rel(on_gpu.v.iter(), on_cpu.v.iter())),
        ("C", rel(on_gpu.c.iter(), on_cpu.c.iter())),
        ("F", rel(on_gpu.f.iter(), on_cpu.f.iter())),
    ];
    let mass_cpu = m.mass_grid(&on_cpu.x).unwrap();
    let mass_gpu = m.mass_grid(&on_gpu.x).unwrap();
    let mmax = mass_cpu.iter().cloned().fold(0.0, f64::max);
    let mass = mass_gpu
        .iter()
        .zip(&mass_cpu)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
        / mmax;
    eprintln!(
        "{kernel:?} on {}: {fields:?}, grid mass {mass:.3e}",
        dev.name
    );
    for (name, e) in fields {
        assert!(e < 1e-10, "{name}: relative difference {e:.3e}");
    }
    assert!(mass < 1e-10, "grid mass: relative difference {mass:.3e}");
}

#[test]
fn thirty_cubic_steps_agree_with_the_cpu_engine() {
    agree(KernelKind::Cubic);
}

#[test]
fn thirty_quadratic_steps_agree_with_the_cpu_engine() {
    agree(KernelKind::Quadratic);
}

#[test]
fn two_runs_give_the_same_bits() {
    let steps = 12;
    let (scene, vol, initial, controls) = workload(KernelKind::Cubic, steps);
    let gpu = GpuEuler::new(device(), model(&scene, &vol)).unwrap();
    let run = || {
        let mut s = initial.clone();
        gpu.forward(&mut s, &controls, 0, steps).unwrap();
        (s, gpu.last_grid_mass())
    };
    let (a, ma) = run();
    let (b, mb) = run();
    assert!(a.x == b.x && a.v == b.v && a.c == b.c && a.f == b.f);
    assert!(ma.iter().zip(&mb).all(|(p, q)| p.to_bits() == q.to_bits()));
}

/// A loss on the last state: half the squared distance of its nodal masses from a target's
/// (the ball moved by `shift` cells; the bench's moves two), and fixed weights on every
/// velocity and F.
struct Loss {
    target: Vec<f64>,
}

impl Loss {
    fn new(m: &Model, initial: &State, shift: f64) -> Loss {
        let moved: Vec<_> = initial
            .x
            .iter()
            .map(|x| x + Vector3::new(shift, 0.0, 0.0))
            .collect();
        Loss {
            target: m.mass_grid(&moved).unwrap(),
        }
    }

    fn weight(p: usize, k: usize) -> f64 {
        ((p * 7 + k * 13) % 11) as f64 / 11.0 - 0.5
    }

    fn value(&self, m: &Model, s: &State) -> f64 {
        let mass = m.mass_grid(&s.x).unwrap();
        let grid: f64 = mass
            .iter()
            .zip(&self.target)
            .map(|(a, b)| 0.5 * (a - b) * (a - b))
            .sum();
        let mut extra = 0.0;
        for p in 0..s.len() {
            for k in 0..3 {
                extra += Self::weight(p, k) * s.v[p][k];
            }
            for k in 0..9 {
                extra += Self::weight(p, k + 3) * s.f[p][k];
            }
        }
        grid + 1e-3 * extra
    }

    fn seed(&self, m: &Model, s: &State) -> StateGrad {
        let mass = m.mass_grid(&s.x).unwrap();
        let dm: Vec<f64> = mass.iter().zip(&self.target).map(|(a, b)| a - b).collect();
        let mut g = StateGrad::zeros(s.len());
        g.x = m.mass_grid_reverse(&s.x, &dm);
        for p in 0..s.len() {
            for k in 0..3 {
                g.v[p][k] = 1e-3 * Self::weight(p, k);
            }
            for k in 0..9 {
                g.f[p][k] = 1e-3 * Self::weight(p, k + 3);
            }
        }
        g
    }
}

/// Largest relative difference of two lists of gradients, each against the largest of `b`.
fn rel_all(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |s, v| s.max(v.abs()));
    a.iter()
        .zip(b)
        .fold(0.0f64, |e, (a, b)| e.max((a - b).abs()))
        / scale
}

fn flat<const R: usize, const C: usize>(v: &[nalgebra::SMatrix<f64, R, C>]) -> Vec<f64> {
    v.iter()
        .flat_map(|m| m.iter().cloned().collect::<Vec<_>>())
        .collect()
}

#[test]
fn the_reverse_pass_agrees_with_the_cpu_engine() {
    let steps = 12;
    let (scene, vol, initial, controls) = workload(KernelKind::Cubic, steps);
    let m = model(&scene, &vol);
    let loss = Loss::new(&m, &initial, 2.0);
    let cpu = Euler::from(model(&scene, &vol));
    let mut s = initial.clone();
    let mut tape = Default::default();
    cpu.forward(&mut s, &controls, 0, steps, Some(&mut tape))
        .unwrap();
    let want = cpu.backward(&tape, &controls, loss.seed(&m, &s));
    let dev = device();
    let gpu = GpuEuler::new(dev.clone(), model(&scene, &vol)).unwrap();
    let mut s = initial.clone();
    let gtape = gpu.forward_taped(&mut s, &controls, 0, steps).unwrap();
    let got = gpu.backward(&gtape, &controls, &loss.seed(&m, &s));
    let fields = [
        ("x", rel_all(&flat(&got.initial.x), &flat(&want.initial.x))),
        ("v", rel_all(&flat(&got.initial.v), &flat(&want.initial.v))),
        ("C", rel_all(&flat(&got.initial.c), &flat(&want.initial.c))),
        ("F", rel_all(&flat(&got.initial.f), &flat(&want.initial.f))),
    ];
    let mut worst_fc = 0.0f64;
    for (k, (g, w)) in got.controls.iter().zip(&want.controls).enumerate() {
        assert_eq!(g.is_some(), w.is_some(), "step {k}");
        if let (Some(g), Some(w)) = (g, w) {
            worst_fc = worst_fc.max(rel_all(&flat(g), &flat(w)));
        }
    }
    eprintln!("reverse on {}: {fields:?}, Fc {worst_fc:.3e}", dev.name);
    for (name, e) in fields {
        assert!(e < 1e-8, "dL/d{name}: relative difference {e:.3e}");
    }
    assert!(
        worst_fc < 1e-8,
        "dL/dFc: relative difference {worst_fc:.3e}"
    );
}

#[test]
fn the_reverse_pass_matches_central_differences_on_the_device() {
    let steps = 4;
    let (scene, vol, initial, controls) = workload(KernelKind::Cubic, steps);
    let m = model(&scene, &vol);
    // A target near the body keeps the loss small, so that the differences' rounding
    // (machine epsilon times the loss over h) stays below their truncation error.
    let loss = Loss::new(&m, &initial, 0.1);
    let dev = device();
    let gpu = GpuEuler::new(dev.clone(), model(&scene, &vol)).unwrap();
    let mut s = initial.clone();
    let tape = gpu.forward_taped(&mut s, &controls, 0, steps).unwrap();
    let g = gpu.backward(&tape, &controls, &loss.seed(&m, &s));
    let run = |start: &State, controls: &[Option<StepControl>]| {
        let mut s = start.clone();
        gpu.forward(&mut s, controls, 0, steps).unwrap();
        loss.value(&m, &s)
    };
    // The nodal masses' rounding (about 1e-14 on each of 36,000 nodes) limits the differences
    // below h = 1e-5; at 1e-4 they agree with the device to about 1e-6 (3e-4: the same).
    let h = 1e-4;
    // Probes: an initial velocity, position and F entry, and an entry of step 0's Fc.
    for p in [0, initial.len() / 2, initial.len() - 1] {
        let probes: [(&str, f64); 4] = [
            ("v", g.initial.v[p][1]),
            ("x", g.initial.x[p][0]),
            ("F", g.initial.f[p][(0, 1)]),
            ("Fc", g.controls[0].as_ref().unwrap()[p][(1, 0)]),
        ];
        for (name, analytic) in probes {
            let shifted = |sign: f64| {
                let (mut s, mut c) = (initial.clone(), controls.clone());
                match name {
                    "v" => s.v[p][1] += sign * h,
                    "x" => s.x[p][0] += sign * h,
                    "F" => s.f[p][(0, 1)] += sign * h,
                    _ => {
                        let mut fc = c[0].as_ref().unwrap().to_vec();
                        fc[p][(1, 0)] += sign * h;
                        c[0] = Some(fc.into());
                    }
                }
                run(&s, &c)
            };
            let fd = (shifted(1.0) - shifted(-1.0)) / (2.0 * h);
            let err = (fd - analytic).abs() / fd.abs().max(analytic.abs()).max(1e-6);
            eprintln!("particle {p} d/d{name}: device {analytic:.9e}, central difference {fd:.9e}");
            assert!(
                err < 1e-5,
                "particle {p} d/d{name}: {analytic:e} against {fd:e}"
            );
        }
    }
}

/// Through the engine's `Integrator` trait, as the morph calls it: a run observed step by
/// step, and a reverse with a cost on every state along the run (a velocity term after each
/// step), against the CPU engine's.
#[test]
fn as_an_integrator_it_matches_the_cpu_engine_with_per_step_costs() {
    use morph_engine::integrator::{Controls, Integrator, RunTape, Steps};
    let steps = 6;
    let (scene, vol, initial, controls) = workload(KernelKind::Quadratic, steps);
    let m = model(&scene, &vol);
    let loss = Loss::new(&m, &initial, 2.0);
    let cpu = Euler::from(model(&scene, &vol));
    let gpu = GpuEuler::new(device(), model(&scene, &vol)).unwrap();
    let seed = |k: usize, s: &State, adj: &mut StateGrad| {
        for p in 0..s.len() {
            adj.v[p] += (1e-3 * k as f64) * s.v[p];
        }
    };
    let (mut seen_cpu, mut seen_gpu) = (Vec::new(), Vec::new());
    let run = Steps::new(5, steps);
    let mut s = initial.clone();
    let mut tape = Default::default();
    let mut on = |k: usize, s: &State| seen_cpu.push((k, s.x[7]));
    cpu.forward_observed(
        &mut s,
        Controls::of_f(&controls),
        run,
        Some(&mut tape),
        Some(&mut on),
    )
    .unwrap();
    let want = cpu.backward_seeded(&tape, Controls::of_f(&controls), loss.seed(&m, &s), &mut {
        seed
    });
    let mut s = initial.clone();
    let mut gtape = Default::default();
    let mut on = |k: usize, s: &State| seen_gpu.push((k, s.x[7]));
    gpu.forward_observed(
        &mut s,
        Controls::of_f(&controls),
        run,
        Some(&mut gtape),
        Some(&mut on),
    )
    .unwrap();
    assert_eq!(gtape.len(), steps);
    let got = gpu.backward_seeded(&gtape, Controls::of_f(&controls), loss.seed(&m, &s), &mut {
        seed
    });
    assert_eq!(seen_cpu.len(), seen_gpu.len());
    for ((kc, xc), (kg, xg)) in seen_cpu.iter().zip(&seen_gpu) {
        assert_eq!(kc, kg);
        assert!(
            (xc - xg).amax() < 1e-12 * xc.amax(),
            "step {kc}: {xc} against {xg}"
        );
    }
    let e = rel_all(&flat(&got.initial.v), &flat(&want.initial.v))
        .max(rel_all(&flat(&got.initial.x), &flat(&want.initial.x)))
        .max(rel_all(&flat(&got.initial.f), &flat(&want.initial.f)));
    assert!(e < 1e-8, "dL/d(initial state): relative difference {e:.3e}");
    // The tape splits and joins again as the morph's look-ahead does.
    let mut head = gtape.clone();
    let tail = head.split_off(2);
    assert_eq!((head.len(), tail.len()), (2, steps - 2));
    assert_eq!(head.last().x, gtape.state_at(2).x);
    head.append(tail);
    let again = gpu.backward_seeded(&head, Controls::of_f(&controls), loss.seed(&m, &s), &mut {
        seed
    });
    assert_eq!(flat(&again.initial.v), flat(&got.initial.v));
}

/// Gravity and walls, the grid effects the device runs: slip walls thick enough that the
/// ball, falling and swirling, reaches them, and sticky ones.
fn walls_and_gravity(mode: WallMode) -> Vec<EffectConfig> {
    vec![
        EffectConfig::drag(0.5),
        EffectConfig::Gravity {
            acceleration: [0.0, -300.0, 0.0],
        },
        EffectConfig::Walls { mode, thickness: 9 },
    ]
}

#[test]
fn grid_effects_agree_with_the_cpu_engine() {
    agree_with(KernelKind::Cubic, walls_and_gravity(WallMode::Slip), 20);
    agree_with(
        KernelKind::Quadratic,
        walls_and_gravity(WallMode::Sticky),
        20,
    );
}

#[test]
fn the_reverse_through_grid_effects_agrees_with_the_cpu_engine() {
    for mode in [WallMode::Slip, WallMode::Sticky] {
        let steps = 10;
        let (mut scene, vol, initial, controls) = workload(KernelKind::Cubic, steps);
        scene.effects = walls_and_gravity(mode);
        let m = model(&scene, &vol);
        let loss = Loss::new(&m, &initial, 2.0);
        let cpu = Euler::from(model(&scene, &vol));
        let mut s = initial.clone();
        let mut tape = Default::default();
        cpu.forward(&mut s, &controls, 0, steps, Some(&mut tape))
            .unwrap();
        let want = cpu.backward(&tape, &controls, loss.seed(&m, &s));
        let gpu = GpuEuler::new(device(), model(&scene, &vol)).unwrap();
        let mut s = initial.clone();
        let gtape = gpu.forward_taped(&mut s, &controls, 0, steps).unwrap();
        let got = gpu.backward(&gtape, &controls, &loss.seed(&m, &s));
        let e = rel_all(&flat(&got.initial.x), &flat(&want.initial.x))
            .max(rel_all(&flat(&got.initial.v), &flat(&want.initial.v)))
            .max(rel_all(&flat(&got.initial.f), &flat(&want.initial.f)));
        eprintln!("{mode:?} walls and gravity, reverse: {e:.3e}");
        assert!(e < 1e-8, "{mode:?}: relative difference {e:.3e}");
    }
}

/// In f32 (`--precision f32`): 30 steps and the gradients of 12 follow the CPU engine's f64 to
/// within f32's rounding, grown over the steps, and a run still gives the same bits twice.
#[test]
fn in_f32_the_steps_and_gradients_follow_the_cpu_engine() {
    use morph_gpu::Precision;
    let steps = 30;
    let (scene, vol, initial, controls) = workload(KernelKind::Cubic, steps);
    let cpu = Euler::from(model(&scene, &vol));
    let mut on_cpu = initial.clone();
    cpu.forward(&mut on_cpu, &controls, 0, steps, None).unwrap();
    let gpu = GpuEuler::with_precision(device(), model(&scene, &vol), Precision::F32).unwrap();
    let run = || {
        let mut s = initial.clone();
        gpu.forward(&mut s, &controls, 0, steps).unwrap();
        s
    };
    let (a, b) = (run(), run());
    assert!(a.x == b.x && a.f == b.f, "two f32 runs differ");
    let fields = [
        ("x", rel(a.x.iter(), on_cpu.x.iter())),
        ("v", rel(a.v.iter(), on_cpu.v.iter())),
        ("F", rel(a.f.iter(), on_cpu.f.iter())),
    ];
    let steps = 12;
    let m = model(&scene, &vol);
    let loss = Loss::new(&m, &initial, 2.0);
    let mut s = initial.clone();
    let mut tape = Default::default();
    cpu.forward(&mut s, &controls, 0, steps, Some(&mut tape))
        .unwrap();
    let want = cpu.backward(&tape, &controls, loss.seed(&m, &s));
    let mut s = initial.clone();
    let gtape = gpu.forward_taped(&mut s, &controls, 0, steps).unwrap();
    let got = gpu.backward(&gtape, &controls, &loss.seed(&m, &s));
    let grads = [
        (
            "dL/dx",
            rel_all(&flat(&got.initial.x), &flat(&want.initial.x)),
        ),
        (
            "dL/dv",
            rel_all(&flat(&got.initial.v), &flat(&want.initial.v)),
        ),
        (
            "dL/dF",
            rel_all(&flat(&got.initial.f), &flat(&want.initial.f)),
        ),
    ];
    eprintln!("f32: {fields:?} {grads:?}");
    for (name, e) in fields.iter().chain(&grads) {
        assert!(*e < 1e-4, "{name}: relative difference {e:.3e} in f32");
    }
}
