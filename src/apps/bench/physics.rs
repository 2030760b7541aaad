//! Physical accuracy apart from the morph: a problem with a known answer. A free-free elastic
//! bar (1 m, square section two cells wide, 2x2x2 particles per cell, E = 1e5 Pa,
//! nu = 0.3, rho = 1000) rings in its first axial mode; its period against the slender-bar
//! answer `2 L / sqrt(E / rho)` = 0.2 s, and the mechanical energy it keeps, for each grid
//! spacing, time step, kernel and integrator. `morph bench-accuracy` prints one JSON line per
//! case and the observed orders of convergence.

use crate::engine::Engine;
use crate::engine::integrator::{Integrator, IntegratorKind};
use crate::engine::material::{ConstitutiveModel, FixedCorotated};
use crate::engine::mpm::model::Model;
use crate::engine::mpm::{GridSpec, KernelKind, SimError, State};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use std::f64::consts::PI;
use std::sync::Arc;

const LENGTH: f64 = 1.0;
const DENSITY: f64 = 1000.0;
const YOUNG: f64 = 1.0e5;
const POISSON: f64 = 0.3;
/// Peak axial speed of the mode (m/s), small against the wave speed.
const AMPLITUDE: f64 = 0.05;
/// Periods simulated.
const PERIODS: f64 = 2.0;

/// The slender bar's first axial period `2 L / sqrt(E / rho)`.
pub fn exact_period() -> f64 {
    2.0 * LENGTH / (YOUNG / DENSITY).sqrt()
}

/// The bar: its grid (6 cells of margin), particles at rest (2x2x2 per cell, two cells
/// thick), each particle's rest volume, and the material.
pub struct Bar {
    pub grid: GridSpec,
    pub x: Vec<Vector3<f64>>,
    pub vol: f64,
    pub material: Arc<FixedCorotated>,
}

/// The 1 m bar with `cells_along` cells along its length, centred on the origin.
pub fn bar(cells_along: usize) -> Bar {
    let dx = LENGTH / cells_along as f64;
    let h = dx / 2.0;
    let (nl, nt) = (2 * cells_along, 4);
    let mut x = Vec::new();
    for i in 0..nl {
        for j in 0..nt {
            for k in 0..nt {
                x.push(Vector3::new(
                    (i as f64 + 0.5) * h - 0.5 * LENGTH,
                    (j as f64 + 0.5) * h - dx,
                    (k as f64 + 0.5) * h - dx,
                ));
            }
        }
    }
    Bar {
        grid: GridSpec {
            origin: [-0.5 * LENGTH - 6.0 * dx, -6.0 * dx, -6.0 * dx],
            dx,
            cells: [cells_along + 12, 12, 12],
        },
        x,
        vol: h * h * h,
        material: Arc::new(FixedCorotated::from_young_poisson(YOUNG, POISSON)),
    }
}

/// The free-free first axial mode at rest position `x` with peak speed `amplitude`: the
/// velocity `v_x = A cos(pi X / L)` and its gradient.
pub fn mode_velocity(x: &Vector3<f64>, amplitude: f64) -> (Vector3<f64>, Matrix3<f64>) {
    let s = PI * (x[0] + 0.5 * LENGTH) / LENGTH;
    let mut g = Matrix3::zeros();
    g[(0, 0)] = -amplitude * PI / LENGTH * s.sin();
    (Vector3::new(amplitude * s.cos(), 0.0, 0.0), g)
}

/// Density of the bar (kg/m³).
pub const BAR_DENSITY: f64 = DENSITY;

/// One case and what it measured.
#[derive(Clone, Debug, Serialize)]
pub struct BarCase {
    pub integrator: IntegratorKind,
    pub kernel: KernelKind,
    pub cells_along: usize,
    /// The time step as a fraction of the elastic bound `dx / c`.
    pub dt_fraction: f64,
    pub dt: f64,
    pub period: f64,
    pub period_error: f64,
    /// Mechanical (kinetic + elastic) energy left after the run, as a fraction.
    pub energy_kept: f64,
    pub seconds: f64,
}

/// Rings the bar for `PERIODS` periods and measures its period from the zero crossings of
/// the mode's amplitude `sum m v_x cos(pi X / L)` (X the rest position).
pub fn ring(
    integrator: IntegratorKind,
    kernel: KernelKind,
    cells_along: usize,
    dt_fraction: f64,
) -> Result<BarCase, SimError> {
    let Bar {
        grid,
        x,
        vol,
        material,
    } = bar(cells_along);
    let n = x.len();
    let dx = grid.dx;
    let wave = (material.wave_modulus() / DENSITY).sqrt();
    let dt = dt_fraction * dx / wave;
    let model = Model::new(
        grid,
        dt,
        kernel,
        material.clone(),
        Vec::new(),
        vec![DENSITY * vol; n],
        vec![vol; n],
    )?;
    let engine = Engine::new(model, integrator)?;
    let rest = x.clone();
    let mode = |p: usize| (PI * (rest[p][0] + 0.5 * LENGTH) / LENGTH).cos();
    let mut s = State::at_rest(x);
    for (p, x0) in rest.iter().enumerate() {
        let (v, grad_v) = mode_velocity(x0, AMPLITUDE);
        s.v[p] = v;
        if integrator == IntegratorKind::Euler {
            // APIC starts with the mode's velocity gradient.
            s.c[p] = grad_v;
        }
    }
    let m = DENSITY * vol;
    let energy = |s: &State| -> f64 {
        let kinetic: f64 = s.v.iter().map(|v| 0.5 * m * v.norm_squared()).sum();
        let elastic: f64 = s.f.iter().map(|f| vol * material.energy_density(f)).sum();
        kinetic + elastic
    };
    let amplitude = |s: &State| -> f64 { (0..n).map(|p| s.v[p][0] * mode(p)).sum() };
    let e0 = energy(&s);
    let steps = (PERIODS * exact_period() / dt).ceil() as usize;
    let clock = std::time::Instant::now();
    let mut crossings = Vec::new();
    let mut prev = amplitude(&s);
    for k in 0..steps {
        crate::engine::with_integrator!(&engine, sim => sim.forward(&mut s, &[], k, 1, None))?;
        let a = amplitude(&s);
        if prev.signum() != a.signum() && a != 0.0 {
            // Linear interpolation of the crossing time within the step.
            crossings.push((k as f64 + prev / (prev - a)) * dt);
        }
        prev = a;
    }
    let seconds = clock.elapsed().as_secs_f64();
    let period = match crossings.len() {
        0 | 1 => f64::NAN,
        c => 2.0 * (crossings[c - 1] - crossings[0]) / (c - 1) as f64,
    };
    Ok(BarCase {
        integrator,
        kernel,
        cells_along,
        dt_fraction,
        dt,
        period,
        period_error: (period - exact_period()) / exact_period(),
        energy_kept: energy(&s) / e0,
        seconds,
    })
}

/// Observed order of convergence from errors at spacings `h` and `h / 2`.
pub fn observed_order(coarse: f64, fine: f64) -> f64 {
    (coarse.abs() / fine.abs()).log2()
}

/// The study: grid refinement (8, 16, 32 cells along, dt at a quarter of the bound) and time
/// step refinement (16 cells, dt at 1/2, 1/4, 1/8 of the bound), both kernels and both
/// integrators. Prints one JSON line per case, then one per refinement with the observed
/// orders.
pub fn run() -> anyhow::Result<()> {
    use serde_json::json;
    for integrator in IntegratorKind::ALL {
        for kernel in KernelKind::ALL {
            let by_dx: Vec<BarCase> = [8, 16, 32]
                .iter()
                .map(|&c| ring(integrator, kernel, c, 0.25))
                .collect::<Result<_, _>>()?;
            let by_dt: Vec<BarCase> = [0.5, 0.25, 0.125]
                .iter()
                .map(|&f| ring(integrator, kernel, 16, f))
                .collect::<Result<_, _>>()?;
            for c in by_dx.iter().chain(&by_dt) {
                println!("{}", json!({"bench": "bar_mode", "case": c}));
            }
            let orders = |cases: &[BarCase]| -> Vec<f64> {
                cases
                    .windows(2)
                    .map(|w| observed_order(w[0].period_error, w[1].period_error))
                    .collect()
            };
            println!(
                "{}",
                json!({
                    "bench": "bar_mode_orders", "integrator": integrator, "kernel": kernel,
                    "period_order_in_dx": orders(&by_dx), "period_order_in_dt": orders(&by_dt),
                    "exact_period": exact_period(),
                })
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bar_rings_near_its_period() {
        let c = ring(IntegratorKind::Rk4, KernelKind::Quadratic, 8, 0.5).unwrap();
        assert!(c.period_error.abs() < 0.1, "{c:?}");
        assert!(c.energy_kept > 0.9 && c.energy_kept < 1.01, "{c:?}");
    }
}
