//! Shared scene builders for the integration tests, and helpers for the tests that run the
//! `morph` binary.
#![allow(dead_code)]

pub mod cli;

use morph::engine::Engine;
use morph::engine::integrator::{Integrator, IntegratorKind};
use morph::engine::mpm::model::Model;
use morph::engine::mpm::{Euler, GridSpec, KernelKind, State, StateGrad};
use morph::engine::scene::{EffectConfig, MaterialConfig, SceneConfig, ball_particles};
use morph::loss::{MassLoss, MassLossKind};
use nalgebra::{Matrix3, Vector3};

/// A small scene with the reference material and time step: 16^3 cells, dx 1.
pub fn small_scene(kernel: KernelKind, effects: Vec<EffectConfig>) -> SceneConfig {
    SceneConfig {
        grid: GridSpec::centred_cube(16, 1.0),
        dt: 1.0 / 120.0,
        kernel,
        material: MaterialConfig {
            model: Default::default(),
            mu: 38888.9,
            lambda: 58333.0,
            density: 40.0,
        },
        effects,
    }
}

/// A ball of `radius` cells with 2x2x2 particles per cell; returns the simulator and the state
/// at rest.
pub fn ball(scene: &SceneConfig, radius: f64) -> (Euler, State) {
    let (x, vol) = ball_particles(&scene.grid, Vector3::new(0.1, -0.2, 0.05), radius, 2);
    let sim = scene.build(vol).expect("valid scene");
    (sim, State::at_rest(x))
}

/// Deterministic pseudo-random numbers in [-1, 1) (a small LCG keeps tests independent of any
/// crate's stream).
pub struct Lcg(pub u64);
impl Lcg {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
    pub fn vec3(&mut self) -> Vector3<f64> {
        Vector3::new(self.next(), self.next(), self.next())
    }
    pub fn mat3(&mut self) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| self.next())
    }
}

/// Gives the body a really deforming motion: swirl, shear and expansion velocities, a
/// perturbed F and affine velocity.
pub fn deform(state: &mut State, rng: &mut Lcg) {
    for p in 0..state.len() {
        let r = state.x[p];
        state.v[p] = Vector3::new(-r[1] + 0.4 * r[2], r[0], 0.5 * r[2]) * 1.5 + 0.3 * rng.vec3();
        state.c[p] = 0.2 * rng.mat3();
        state.f[p] = Matrix3::identity() + 0.05 * rng.mat3();
    }
}

/// Controls: non-zero Fc at every `stride`-th step (and None elsewhere).
pub fn controls(
    n: usize,
    steps: usize,
    stride: usize,
    amp: f64,
    rng: &mut Lcg,
) -> Vec<Option<Vec<Matrix3<f64>>>> {
    (0..steps)
        .map(|s| (s % stride == 0).then(|| (0..n).map(|_| amp * rng.mat3()).collect()))
        .collect()
}

/// Controls as the integrators take them (shared per step), from the owned ones the tests
/// build and perturb.
pub fn shared(
    ctrl: &[Option<Vec<Matrix3<f64>>>],
) -> Vec<Option<morph::engine::integrator::StepControl>> {
    ctrl.iter()
        .map(|c| c.as_ref().map(|c| c.as_slice().into()))
        .collect()
}

/// Mass loss of the final state after `steps` steps (and the tape when asked), with either
/// integrator.
pub fn rollout_loss<I: Integrator>(
    sim: &I,
    init: &State,
    ctrl: &[Option<Vec<Matrix3<f64>>>],
    steps: usize,
    loss: &MassLoss,
    tape: Option<&mut I::Tape>,
) -> (f64, State) {
    let mut s = init.clone();
    sim.forward(&mut s, &shared(ctrl), 0, steps, tape)
        .expect("forward");
    let m = sim.model().mass_grid(&s.x).expect("mass grid");
    (loss.value_and_grad(&m).0, s)
}

/// The ball of [`ball`] with the integrator `kind`.
pub fn ball_engine(scene: &SceneConfig, radius: f64, kind: IntegratorKind) -> (Engine, State) {
    ball_engine_with(
        scene,
        radius,
        kind,
        morph::engine::mpm::ControlForm::default(),
    )
}

/// [`ball_engine`] with the deformation-gradient control acting by `form`.
pub fn ball_engine_with(
    scene: &SceneConfig,
    radius: f64,
    kind: IntegratorKind,
    form: morph::engine::mpm::ControlForm,
) -> (Engine, State) {
    let (x, vol) = ball_particles(&scene.grid, Vector3::new(0.1, -0.2, 0.05), radius, 2);
    let mut model = scene
        .model_with(vol, &morph::geometry::MeshSolids)
        .expect("valid scene");
    model.control_form = form;
    let engine = Engine::new(model, kind).expect("engine");
    (engine, State::at_rest(x))
}

/// Target masses: the initial body shifted by `shift`.
pub fn shifted_target(
    sim: &Model,
    init: &State,
    shift: Vector3<f64>,
    kind: MassLossKind,
) -> MassLoss {
    let x: Vec<_> = init.x.iter().map(|x| x + shift).collect();
    MassLoss::new(kind, sim.mass_grid(&x).unwrap())
}

/// Seed dL/d(final state) for a mass loss.
pub fn loss_seed(sim: &Model, last: &State, loss: &MassLoss) -> StateGrad {
    let m = sim.mass_grid(&last.x).unwrap();
    let (_, gm) = loss.value_and_grad(&m);
    let mut seed = StateGrad::zeros(last.len());
    seed.x = sim.mass_grid_reverse(&last.x, &gm);
    seed
}
