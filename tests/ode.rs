//! Finite-difference checks of the ODE form's reverse pass: the right-hand side, RK4 through
//! 12 steps, and both control effects (prescribed clamp velocity and body force), with
//! prescribed clamp position, piecewise-constant and piecewise-linear schedules (f64, 4th-order central differences).

mod common;

use common::Lcg;
use morph::control::rope::{Actuation, ClampMode, RopeConfig};
use morph::material::MaterialModel;
use morph::mpm::KernelKind;
use morph::ode::{ControlParams, Interpolation, OdeState, OdeSystem, Rk4Tape};
use nalgebra::{Matrix3, Vector3};

const STEPS: usize = 12;
const TOL: f64 = 1e-6;
const H: f64 = 1e-4;

fn fd(f: impl Fn(f64) -> f64, h: f64) -> f64 {
    (8.0 * (f(h) - f(-h)) - (f(2.0 * h) - f(-2.0 * h))) / (12.0 * h)
}

fn rel_err(a: f64, b: f64) -> f64 {
    (a - b).abs() / a.abs().max(b.abs()).max(1e-300)
}

/// A small rope with both controls, a deformed and moving initial state, and random knots.
fn setup(
    kernel: KernelKind,
    interpolation: Interpolation,
    clamp_mode: ClampMode,
    seed: u64,
    material: MaterialModel,
) -> (OdeSystem, OdeState, ControlParams) {
    let cfg = RopeConfig {
        material,
        clamp_mode,
        cells_along: 8,
        steps: STEPS,
        control_interval: 4,
        kernel,
        interpolation,
        actuation: Actuation::Both,
        dt: 1.0e-3,
        ..RopeConfig::default()
    };
    let rope = cfg.build().unwrap();
    let mut s = rope.initial.clone();
    let mut rng = Lcg(seed);
    for p in 0..s.len() {
        let r = s.x[p];
        s.v[p] = Vector3::new(-r[1], r[0], 0.3 * r[2]) * 4.0 + 0.5 * rng.vec3();
        s.f[p] = Matrix3::identity() + 0.05 * rng.mat3();
    }
    let mut params = rope.system.controls.zero_params();
    for (e, knots) in params.iter_mut().enumerate() {
        let amp = match (e, clamp_mode) {
            (0, ClampMode::Velocity) => 0.2,
            (0, ClampMode::Position) => 0.002,
            _ => 3.0,
        };
        for k in knots.iter_mut() {
            *k = amp * Vector3::new(rng.next(), rng.next(), 0.0);
        }
    }
    (rope.system, s, params)
}

/// Cost: kinetic energy summed over the steps plus a random linear function of the final state
/// (so every field of the final state is seeded).
struct Cost {
    probe: OdeState,
}

impl Cost {
    fn new(n: usize, rng: &mut Lcg) -> Cost {
        Cost {
            probe: OdeState {
                x: (0..n).map(|_| rng.vec3()).collect(),
                v: (0..n).map(|_| 0.1 * rng.vec3()).collect(),
                f: (0..n).map(|_| rng.mat3()).collect(),
            },
        }
    }

    fn eval(&self, sys: &OdeSystem, init: &OdeState, params: &ControlParams) -> f64 {
        let mut s = init.clone();
        let e = sys.run(&mut s, params, 0, STEPS, None, |_, _| {}).unwrap();
        e.iter().sum::<f64>() + self.probe.dot(&s)
    }
}

fn check(kernel: KernelKind, interpolation: Interpolation, clamp_mode: ClampMode) {
    check_material(
        kernel,
        interpolation,
        clamp_mode,
        MaterialModel::FixedCorotated,
    );
}

fn check_material(
    kernel: KernelKind,
    interpolation: Interpolation,
    clamp_mode: ClampMode,
    material: MaterialModel,
) {
    let (sys, init, params) = setup(
        kernel,
        interpolation,
        clamp_mode,
        7 + kernel as u64,
        material,
    );
    let mut rng = Lcg(99);
    let cost = Cost::new(init.len(), &mut rng);
    let mut tape = Rk4Tape::default();
    let mut last = init.clone();
    sys.run(&mut last, &params, 0, STEPS, Some(&mut tape), |_, _| {})
        .unwrap();
    let g = sys.kinetic_cost_gradient(&tape, &params, &last, 1.0, Some(&cost.probe));
    let label = format!("{kernel:?}/{interpolation:?}/{clamp_mode:?}/{material:?}");

    // Control knots of each effect, along a random direction (in-plane components).
    for (e, name) in [(0, "clamp velocity"), (1, "tip body force")] {
        let dir: Vec<Vector3<f64>> = params[e]
            .iter()
            .map(|_| Vector3::new(rng.next(), rng.next(), 0.0))
            .collect();
        let analytic: f64 = g.params[e].iter().zip(&dir).map(|(a, b)| a.dot(b)).sum();
        let numeric = fd(
            |t| {
                let mut p = params.clone();
                for (k, d) in p[e].iter_mut().zip(&dir) {
                    *k += t * d;
                }
                cost.eval(&sys, &init, &p)
            },
            H,
        );
        let err = rel_err(analytic, numeric);
        println!("{label} {name}: analytic {analytic:.10e} fd {numeric:.10e} rel {err:.2e}");
        assert!(analytic.abs() > 1e-8, "{label} {name}: gradient vanishes");
        assert!(err < TOL, "{label} {name}: rel err {err:.3e}");
    }

    // Initial state, field by field.
    let n = init.len();
    let dir = OdeState {
        x: (0..n).map(|_| rng.vec3()).collect(),
        v: (0..n).map(|_| rng.vec3()).collect(),
        f: (0..n).map(|_| rng.mat3()).collect(),
    };
    for field in ["x", "v", "F"] {
        let mut d = OdeState::zeros(n);
        match field {
            "x" => d.x = dir.x.clone(),
            "v" => d.v = dir.v.clone(),
            _ => d.f = dir.f.clone(),
        }
        let analytic = g.initial.dot(&d);
        // Positions move the B-spline weights, whose second derivative jumps at cell
        // boundaries: a smaller step keeps a particle near a boundary from biasing the FD.
        let h = if field == "x" { H / 5.0 } else { H };
        let numeric = fd(
            |t| {
                let mut s = init.clone();
                s.axpy(t, &d);
                cost.eval(&sys, &s, &params)
            },
            h,
        );
        let err = rel_err(analytic, numeric);
        println!(
            "{label} initial {field}: analytic {analytic:.10e} fd {numeric:.10e} rel {err:.2e}"
        );
        assert!(err < TOL, "{label} initial {field}: rel err {err:.3e}");
    }
}

#[test]
fn rk4_reverse_and_controls_match_finite_differences_quadratic_linear_position() {
    check(
        KernelKind::Quadratic,
        Interpolation::Linear,
        ClampMode::Position,
    );
}

#[test]
fn rk4_reverse_and_controls_match_finite_differences_quadratic_constant_velocity() {
    check(
        KernelKind::Quadratic,
        Interpolation::Constant,
        ClampMode::Velocity,
    );
}

#[test]
fn rk4_reverse_and_controls_match_finite_differences_cubic_linear_velocity() {
    check(
        KernelKind::Cubic,
        Interpolation::Linear,
        ClampMode::Velocity,
    );
}

/// The second material, stable Neo-Hookean, through RK4 and both controls.
#[test]
fn rk4_reverse_matches_finite_differences_stable_neo_hookean() {
    check_material(
        KernelKind::Cubic,
        Interpolation::Linear,
        ClampMode::Velocity,
        MaterialModel::StableNeoHookean,
    );
}
