//! What both integrators (the Euler engine here and the ODE form's RK4) require of a scene
//! before they run it: one validation and one stable time-step bound.

use super::{GridSpec, SimError};
use crate::material::ConstitutiveModel;

/// The densest particle's density `m / V`.
pub fn max_density(mass: &[f64], volume: &[f64]) -> f64 {
    mass.iter()
        .zip(volume)
        .map(|(m, v)| m / v)
        .fold(0.0f64, f64::max)
}

/// The elastic bound `(dx / c, c)` of these particles on this grid.
pub fn stable_dt(
    grid: &GridSpec,
    material: &dyn ConstitutiveModel,
    mass: &[f64],
    volume: &[f64],
) -> (f64, f64) {
    crate::material::stable_dt(material.wave_modulus(), max_density(mass, volume), grid.dx)
}

/// Checks a scene: a sane grid, a positive finite `dt`, one positive finite mass and volume
/// per particle, a valid material, and `dt` within the elastic bound `dx / c`.
pub fn validate(
    grid: &GridSpec,
    dt: f64,
    material: &dyn ConstitutiveModel,
    mass: &[f64],
    volume: &[f64],
) -> Result<(), SimError> {
    grid.validate()?;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(SimError::InvalidScene(format!(
            "dt must be positive and finite, got {dt}"
        )));
    }
    if mass.len() != volume.len() {
        return Err(SimError::InvalidScene(
            "mass and volume lengths differ".into(),
        ));
    }
    if let Some(p) = (0..mass.len()).find(|&p| {
        !(mass[p].is_finite() && mass[p] > 0.0 && volume[p].is_finite() && volume[p] > 0.0)
    }) {
        return Err(SimError::InvalidScene(format!(
            "particle {p} has mass {} and volume {}; both must be positive and finite",
            mass[p], volume[p]
        )));
    }
    let modulus = material.wave_modulus();
    if !(modulus.is_finite() && modulus >= 0.0) {
        return Err(SimError::InvalidScene(format!(
            "material modulus {modulus} is invalid"
        )));
    }
    let (limit, wave_speed) = stable_dt(grid, material, mass, volume);
    if dt > limit {
        return Err(SimError::UnstableTimeStep {
            dt,
            limit,
            wave_speed,
            dx: grid.dx,
        });
    }
    Ok(())
}
