//! Energy test: an undamped, uncontrolled elastic bar ringing in its first axial mode for
//! many periods. The engine's symplectic-Euler MLS-MPM step loses mechanical energy in its
//! transfers; RK4 on the ODE form (whose semi-discrete system conserves energy exactly) keeps
//! far more, at the same grid and dt and also at equal compute (Euler with dt/4, four steps
//! per RK4 step).

use morph::engine::material::{ConstitutiveModel, FixedCorotated};
use morph::engine::mpm::model::{Model, Steps};
use morph::engine::mpm::{Euler, GridSpec, KernelKind, State};
use morph::engine::ode::Rk4;
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;
use std::time::Instant;

const CELLS_ALONG: usize = 16;
const DENSITY: f64 = morph::apps::bench::physics::BAR_DENSITY;
/// Peak axial speed of the mode (m/s); small against the wave speed (11.6 m/s).
const AMPLITUDE: f64 = 0.5;
const DT: f64 = 2.5e-3;
/// Simulated time: 2 s, about 11.6 periods of the mode (period 2L/c = 0.172 s).
const SIM_TIME: f64 = 2.0;

struct Bar {
    grid: GridSpec,
    x: Vec<Vector3<f64>>,
    v: Vec<Vector3<f64>>,
    /// Velocity gradient of the mode (the APIC C the engine starts with).
    grad_v: Vec<Matrix3<f64>>,
    vol: f64,
    material: Arc<FixedCorotated>,
}

/// The 1 m bar of `morph bench-accuracy` (2x2 cells thick, 2x2x2 particles per cell), with
/// the free-free first axial mode's velocity `v_x = A cos(pi X / L)`.
fn bar() -> Bar {
    let b = morph::apps::bench::physics::bar(CELLS_ALONG);
    let (v, grad_v) =
        b.x.iter()
            .map(|x| morph::apps::bench::physics::mode_velocity(x, AMPLITUDE))
            .unzip();
    Bar {
        grid: b.grid,
        x: b.x,
        v,
        grad_v,
        vol: b.vol,
        material: b.material,
    }
}

fn elastic(material: &FixedCorotated, f: &[Matrix3<f64>], vol: f64) -> f64 {
    f.iter().map(|f| vol * material.energy_density(f)).sum()
}

fn kinetic(v: &[Vector3<f64>], m: f64) -> f64 {
    v.iter().map(|v| 0.5 * m * v.norm_squared()).sum()
}

/// Fraction of the initial mechanical energy left after SIM_TIME with the engine's step at
/// `dt`, and the wall seconds it took.
fn euler(b: &Bar, dt: f64) -> (f64, f64) {
    let n = b.x.len();
    let m = DENSITY * b.vol;
    let sim = Euler::from(
        Model::new(
            b.grid.clone(),
            dt,
            KernelKind::Quadratic,
            b.material.clone(),
            Vec::new(),
            vec![m; n],
            vec![b.vol; n],
        )
        .unwrap(),
    );
    let mut s = State::at_rest(b.x.clone());
    s.v = b.v.clone();
    s.c = b.grad_v.clone();
    let e0 = kinetic(&s.v, m) + elastic(&b.material, &s.f, b.vol);
    let steps = (SIM_TIME / dt).round() as usize;
    let t = Instant::now();
    sim.forward(&mut s, &[], 0, steps, None).unwrap();
    let secs = t.elapsed().as_secs_f64();
    let e = kinetic(&s.v, m) + elastic(&b.material, &s.f, b.vol);
    (e / e0, secs)
}

fn rk4(b: &Bar, dt: f64) -> (f64, f64) {
    let n = b.x.len();
    let m = DENSITY * b.vol;
    let steps = (SIM_TIME / dt).round() as usize;
    let model = Model::new(
        b.grid.clone(),
        dt,
        KernelKind::Quadratic,
        b.material.clone(),
        Vec::new(),
        vec![m; n],
        vec![b.vol; n],
    )
    .unwrap();
    let sys = Rk4::new(model).unwrap();
    let mut s = State::ode_at_rest(b.x.clone());
    s.v = b.v.clone();
    let e0 = kinetic(&s.v, m) + sys.elastic_energy(&s);
    let params = sys.controls().zero_params();
    let t = Instant::now();
    sys.rollout(&mut s, &params, Steps::new(0, steps), None, |_, _| {})
        .unwrap();
    let secs = t.elapsed().as_secs_f64();
    let e = kinetic(&s.v, m) + sys.elastic_energy(&s);
    (e / e0, secs)
}

#[test]
fn rk4_keeps_far_more_energy_than_the_euler_step() {
    let b = bar();
    let (e_rk4, t_rk4) = rk4(&b, DT);
    let (e_eu, t_eu) = euler(&b, DT);
    let (e_eu4, t_eu4) = euler(&b, DT / 4.0);
    println!(
        "energy kept after {SIM_TIME} s ({} particles, dx {:.4}):",
        b.x.len(),
        b.grid.dx
    );
    println!("| integrator | dt | energy kept | wall s |\n|---|---|---|---|");
    println!("| RK4 (ODE form) | {DT} | {e_rk4:.4} | {t_rk4:.3} |");
    println!("| symplectic Euler MLS-MPM | {DT} | {e_eu:.4} | {t_eu:.3} |");
    println!(
        "| symplectic Euler MLS-MPM | {} | {e_eu4:.4} | {t_eu4:.3} |",
        DT / 4.0
    );
    assert!(e_rk4.is_finite() && e_eu.is_finite() && e_eu4.is_finite());
    // RK4 must neither gain energy (instability) nor lose much.
    assert!(e_rk4 < 1.01, "RK4 gained energy: {e_rk4}");
    assert!(e_rk4 > 0.9, "RK4 kept only {e_rk4}");
    // "Clearly more": RK4 loses at most half of what either Euler run loses.
    assert!(
        1.0 - e_rk4 < 0.5 * (1.0 - e_eu),
        "RK4 {e_rk4} vs Euler {e_eu} at the same dt"
    );
    assert!(
        1.0 - e_rk4 < 0.5 * (1.0 - e_eu4),
        "RK4 {e_rk4} vs Euler {e_eu4} at equal compute (dt/4)"
    );
}
