//! The device's step against the CPU engine's on the reference workload (a deforming ball of
//! about 17,000 particles under drag and `Fc` controls every 10 steps), in f64.

use morph_engine::integrator::StepControl;
use morph_engine::mpm::model::Model;
use morph_engine::mpm::{Euler, KernelKind, State};
use morph_engine::scene::{SceneConfig, ball_particles};
use morph_gpu::{Device, GpuEuler};
use nalgebra::{Matrix3, Vector3};

fn device() -> Device {
    Device::open().unwrap_or_else(|e| {
        panic!("{e} (the GPU tests need a device; Mesa's lavapipe is one: apt-get install mesa-vulkan-drivers)")
    })
}

/// The bench's reference workload: the model, the initial state and each step's controls.
fn workload(kernel: KernelKind, steps: usize) -> (SceneConfig, Vec<f64>, State, Vec<Option<StepControl>>) {
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
    let steps = 30;
    let (scene, vol, initial, controls) = workload(kernel, steps);
    let cpu = Euler::from(model(&scene, &vol));
    let mut on_cpu = initial.clone();
    cpu.forward(&mut on_cpu, &controls, 0, steps, None).unwrap();
    let dev = device();
    let m = model(&scene, &vol);
    let gpu = GpuEuler::new(&dev, &m).unwrap();
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
    let mass = mass_gpu.iter().zip(&mass_cpu).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max) / mmax;
    eprintln!("{kernel:?} on {}: {fields:?}, grid mass {mass:.3e}", dev.name);
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
    let dev = device();
    let m = model(&scene, &vol);
    let gpu = GpuEuler::new(&dev, &m).unwrap();
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
