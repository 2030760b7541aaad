//! Finite-difference checks of the boundary controls' reverse pass, through both integrators
//! (RK4 on the ODE form and the Euler step) over 12 steps: both control effects (prescribed
//! clamp velocity or position, and body force) with piecewise-constant and piecewise-linear
//! schedules, the kinetic-energy cost, and the initial state (f64, 4th-order central
//! differences).

use crate::common;

use common::Lcg;
use morph::apps::rope::scene::{Actuation, ClampMode, RopeConfig};
use morph::engine::Engine;
use morph::engine::integrator::{
    Controlled, Controls, Integrator, IntegratorKind, StepControl, Steps,
};
use morph::engine::material::MaterialModel;
use morph::engine::mpm::{ControlParams, Interpolation};
use morph::engine::mpm::{KernelKind, State};
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

/// `<a, b>` over every field of two states.
fn dot(a: &State, b: &State) -> f64 {
    let v = |p: &[Vector3<f64>], q: &[Vector3<f64>]| -> f64 {
        p.iter().zip(q).map(|(a, b)| a.dot(b)).sum()
    };
    let m = |p: &[Matrix3<f64>], q: &[Matrix3<f64>]| -> f64 {
        p.iter().zip(q).map(|(a, b)| a.dot(b)).sum()
    };
    v(&a.x, &b.x) + v(&a.v, &b.v) + m(&a.c, &b.c) + m(&a.f, &b.f)
}

/// A small rope with both controls, a deformed and moving initial state, and random knots.
fn setup(
    kernel: KernelKind,
    interpolation: Interpolation,
    clamp_mode: ClampMode,
    seed: u64,
    material: MaterialModel,
    integrator: IntegratorKind,
) -> (Engine, State, ControlParams) {
    let cfg = RopeConfig {
        material,
        integrator,
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
        if integrator == IntegratorKind::Euler {
            s.c[p] = 0.5 * rng.mat3();
        }
    }
    let mut params = rope.engine.model().controls().zero_params();
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
    (rope.engine, s, params)
}

/// Cost: kinetic energy summed over the steps plus a random linear function of the final state
/// (so every field of the final state is seeded).
struct Cost {
    probe: State,
}

impl Cost {
    fn new(n: usize, rng: &mut Lcg) -> Cost {
        Cost {
            probe: State {
                x: (0..n).map(|_| rng.vec3()).collect(),
                v: (0..n).map(|_| 0.1 * rng.vec3()).collect(),
                c: (0..n).map(|_| 0.01 * rng.mat3()).collect(),
                f: (0..n).map(|_| rng.mat3()).collect(),
            },
        }
    }

    fn eval<S: Controlled>(&self, sys: &S, init: &State, params: &ControlParams) -> f64 {
        let mut s = init.clone();
        let e = sys
            .run(&mut s, params, Steps::new(0, STEPS), None, &mut |_, _| {})
            .unwrap();
        e.iter().sum::<f64>() + dot(&self.probe, &s)
    }
}

fn check(
    kernel: KernelKind,
    interpolation: Interpolation,
    clamp_mode: ClampMode,
    integrator: IntegratorKind,
) {
    check_material(
        kernel,
        interpolation,
        clamp_mode,
        MaterialModel::FixedCorotated,
        integrator,
    );
}

fn check_material(
    kernel: KernelKind,
    interpolation: Interpolation,
    clamp_mode: ClampMode,
    material: MaterialModel,
    integrator: IntegratorKind,
) {
    let (engine, init, params) = setup(
        kernel,
        interpolation,
        clamp_mode,
        7 + kernel as u64,
        material,
        integrator,
    );
    morph::engine::with_integrator!(&engine, sys => check_run(sys, init, params, &format!(
        "{integrator:?}/{kernel:?}/{interpolation:?}/{clamp_mode:?}/{material:?}"
    )));
}

fn check_run<S: Controlled>(sys: &S, init: State, params: ControlParams, label: &str) {
    let mut rng = Lcg(99);
    let cost = Cost::new(init.len(), &mut rng);
    let mut tape = S::Tape::default();
    let mut last = init.clone();
    sys.run(
        &mut last,
        &params,
        Steps::new(0, STEPS),
        Some(&mut tape),
        &mut |_, _| {},
    )
    .unwrap();
    let g = sys.kinetic_cost_gradient(&tape, &params, 1.0, Some(&cost.probe));

    // Control knots of each effect, along a random direction (in-plane components).
    for (e, name) in [(0, "clamp"), (1, "tip body force")] {
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
                cost.eval(sys, &init, &p)
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
    for field in ["x", "v", "C", "F"] {
        let mut d = State::zeros(n);
        match field {
            "x" => d.x = (0..n).map(|_| rng.vec3()).collect(),
            "v" => d.v = (0..n).map(|_| rng.vec3()).collect(),
            "C" => d.c = (0..n).map(|_| rng.mat3()).collect(),
            _ => d.f = (0..n).map(|_| rng.mat3()).collect(),
        }
        let analytic = dot(&g.initial, &d);
        // Positions move the B-spline weights, whose second derivative jumps at cell
        // boundaries: a smaller step keeps a particle near a boundary from biasing the FD.
        let h = if field == "x" { H / 5.0 } else { H };
        let numeric = fd(
            |t| {
                let mut s = init.clone();
                for p in 0..n {
                    s.x[p] += t * d.x[p];
                    s.v[p] += t * d.v[p];
                    s.c[p] += t * d.c[p];
                    s.f[p] += t * d.f[p];
                }
                cost.eval(sys, &s, &params)
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
        IntegratorKind::Rk4,
    );
}

#[test]
fn rk4_reverse_and_controls_match_finite_differences_quadratic_constant_velocity() {
    check(
        KernelKind::Quadratic,
        Interpolation::Constant,
        ClampMode::Velocity,
        IntegratorKind::Rk4,
    );
}

#[test]
fn rk4_reverse_and_controls_match_finite_differences_cubic_linear_velocity() {
    check(
        KernelKind::Cubic,
        Interpolation::Linear,
        ClampMode::Velocity,
        IntegratorKind::Rk4,
    );
}

/// The materials' contract: every model `MaterialModel` lists, through RK4 and both controls
/// (a new material is checked here without a line of its own).
#[test]
fn every_material_matches_finite_differences_with_rk4_and_both_controls() {
    for model in MaterialModel::ALL {
        check_material(
            KernelKind::Cubic,
            Interpolation::Linear,
            ClampMode::Velocity,
            model,
            IntegratorKind::Rk4,
        );
    }
}

/// The Euler step with the same boundary controls and cost (clamp read at mid-step, body
/// force as momentum impulse).
#[test]
fn euler_reverse_and_controls_match_finite_differences_quadratic_linear_position() {
    check(
        KernelKind::Quadratic,
        Interpolation::Linear,
        ClampMode::Position,
        IntegratorKind::Euler,
    );
}

#[test]
fn euler_reverse_and_controls_match_finite_differences_cubic_constant_velocity() {
    check(
        KernelKind::Cubic,
        Interpolation::Constant,
        ClampMode::Velocity,
        IntegratorKind::Euler,
    );
}

/// Both kinds of control in one run, through the one interface both integrators take
/// ([`Controls`]): every step's `Fc` and the boundary controls' knots together, and the
/// gradients of a linear function of the final state with respect to each, along a random
/// direction, against central differences.
#[test]
fn both_kinds_of_control_in_one_run_match_finite_differences() {
    for integrator in IntegratorKind::ALL {
        let (engine, init, params) = setup(
            KernelKind::Quadratic,
            Interpolation::Linear,
            ClampMode::Velocity,
            11,
            MaterialModel::FixedCorotated,
            integrator,
        );
        let label = format!("{integrator:?}");
        morph::engine::with_integrator!(&engine, sys => check_both(sys, &init, &params, &label));
    }
}

fn check_both<S: Integrator>(sys: &S, init: &State, params: &ControlParams, label: &str) {
    let n = init.len();
    let mut rng = Lcg(5);
    let layer = |rng: &mut Lcg, scale: f64| -> Vec<Matrix3<f64>> {
        (0..n).map(|_| scale * rng.mat3()).collect()
    };
    let fc: Vec<Vec<Matrix3<f64>>> = (0..STEPS).map(|_| layer(&mut rng, 0.01)).collect();
    let dir_f: Vec<Vec<Matrix3<f64>>> = (0..STEPS).map(|_| layer(&mut rng, 1.0)).collect();
    let dir_k: ControlParams = params
        .iter()
        .map(|k| k.iter().map(|_| rng.vec3()).collect())
        .collect();
    let probe = Cost::new(n, &mut rng).probe;
    let shared = |f: &[Vec<Matrix3<f64>>]| -> Vec<Option<StepControl>> {
        f.iter().map(|l| Some(l.clone().into())).collect()
    };
    let run = |f: &[Option<StepControl>], knots: &ControlParams, tape: Option<&mut S::Tape>| {
        let mut s = init.clone();
        let controls = Controls {
            f,
            knots: Some(knots),
        };
        sys.forward_observed(&mut s, controls, Steps::new(0, STEPS), tape, None)
            .unwrap();
        dot(&probe, &s)
    };
    let mut tape = S::Tape::default();
    run(&shared(&fc), params, Some(&mut tape));
    let controls = Controls {
        f: &shared(&fc),
        knots: Some(params),
    };
    let g = sys.backward_seeded(&tape, controls, probe.clone(), &mut |_, _, _| {});
    // Along the knots' direction.
    let analytic: f64 = g
        .knots
        .iter()
        .zip(&dir_k)
        .flat_map(|(a, d)| a.iter().zip(d))
        .map(|(a, d)| a.dot(d))
        .sum();
    let numeric = fd(
        |h| {
            let knots: ControlParams = params
                .iter()
                .zip(&dir_k)
                .map(|(k, d)| k.iter().zip(d).map(|(k, d)| k + h * d).collect())
                .collect();
            run(&shared(&fc), &knots, None)
        },
        H,
    );
    let e = rel_err(analytic, numeric);
    assert!(
        e < TOL,
        "{label}: knots {analytic} vs {numeric} (rel {e:.2e})"
    );
    // Along every step's Fc.
    let analytic: f64 = g
        .controls
        .iter()
        .zip(&dir_f)
        .map(|(g, d)| {
            let g = g.as_ref().expect("every step had a control");
            g.iter().zip(d).map(|(a, b)| a.dot(b)).sum::<f64>()
        })
        .sum();
    let numeric = fd(
        |h| {
            let moved: Vec<Vec<Matrix3<f64>>> = fc
                .iter()
                .zip(&dir_f)
                .map(|(l, d)| l.iter().zip(d).map(|(a, b)| a + h * b).collect())
                .collect();
            run(&shared(&moved), params, None)
        },
        H,
    );
    let e = rel_err(analytic, numeric);
    assert!(e < TOL, "{label}: Fc {analytic} vs {numeric} (rel {e:.2e})");
}
