//! The model both integrators run (the Euler engine here and the ODE form's RK4): grid,
//! time step, kernel, material, effects and the particles' masses and rest volumes, with one
//! validation, one stable time-step bound and one set of state checks.

use super::transfer;
use super::{GridSpec, KernelKind, SimError};
use crate::effects::Effect;
use crate::material::ConstitutiveModel;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// Everything fixed during a simulation, whichever integrator runs it.
#[derive(Debug)]
pub struct Model {
    pub grid: GridSpec,
    pub dt: f64,
    pub kernel: KernelKind,
    pub material: Arc<dyn ConstitutiveModel>,
    /// The optional physics the scene declared, in order (see [`crate::effects`]).
    pub effects: Vec<Box<dyn Effect>>,
    pub mass: Vec<f64>,
    pub volume: Vec<f64>,
    /// Largest allowed particle displacement per step, in cells.
    pub max_cfl: f64,
}

impl Model {
    /// Validates the scene: a sane grid, a positive finite `dt`, one positive finite mass and
    /// volume per particle, a valid material, and `dt` within the elastic bound `dx / c`.
    pub fn new(
        grid: GridSpec,
        dt: f64,
        kernel: KernelKind,
        material: Arc<dyn ConstitutiveModel>,
        effects: Vec<Box<dyn Effect>>,
        mass: Vec<f64>,
        volume: Vec<f64>,
    ) -> Result<Model, SimError> {
        validate(&grid, dt, material.as_ref(), &mass, &volume)?;
        Ok(Model {
            grid,
            dt,
            kernel,
            material,
            effects,
            mass,
            volume,
            max_cfl: 1.0,
        })
    }

    pub fn num_particles(&self) -> usize {
        self.mass.len()
    }

    pub fn inv_d(&self) -> f64 {
        self.kernel.inv_d(self.grid.dx)
    }

    /// The largest stable time step `dx / c` and the elastic wave speed `c` it comes from.
    pub fn stable_dt(&self) -> (f64, f64) {
        stable_dt(&self.grid, self.material.as_ref(), &self.mass, &self.volume)
    }

    /// Nodal masses `m_i = sum_p w_ip m_p` of particles at `positions` (for losses).
    pub fn mass_grid(&self, positions: &[Vector3<f64>]) -> Result<Vec<f64>, SimError> {
        transfer::mass_grid(&self.grid, self.kernel, positions, &self.mass)
    }

    /// Reverse of [`Model::mass_grid`]: dL/dx_p from dL/dm_i.
    pub fn mass_grid_reverse(
        &self,
        positions: &[Vector3<f64>],
        grad_mass: &[f64],
    ) -> Vec<Vector3<f64>> {
        transfer::mass_grid_reverse(&self.grid, self.kernel, positions, &self.mass, grad_mass)
    }

    /// A state has one entry per particle of the scene.
    pub fn check_size(&self, particles: usize) -> Result<(), SimError> {
        if particles != self.num_particles() {
            return Err(SimError::InvalidScene(format!(
                "state has {particles} particles, the scene {}",
                self.num_particles()
            )));
        }
        Ok(())
    }

    /// Every field is finite (`non_finite`: the state's first non-finite particle and field,
    /// if any) and no particle moves more than `max_cfl` cells a step.
    pub fn check_finite_and_cfl(
        &self,
        non_finite: Option<(usize, &'static str)>,
        v: &[Vector3<f64>],
        step: usize,
    ) -> Result<(), SimError> {
        if let Some((particle, field)) = non_finite {
            return Err(SimError::NonFinite {
                step,
                particle,
                field,
            });
        }
        self.check_cfl(v, step)
    }

    /// No particle may move more than `max_cfl` cells in one step.
    pub fn check_cfl(&self, v: &[Vector3<f64>], step: usize) -> Result<(), SimError> {
        let limit = self.max_cfl * self.grid.dx / self.dt;
        if let Some(p) = v.par_iter().position_first(|v| v.norm() > limit) {
            return Err(SimError::CflExceeded {
                step,
                particle: p,
                cells: v[p].norm() * self.dt / self.grid.dx,
                limit: self.max_cfl,
            });
        }
        Ok(())
    }

    /// A deformation-gradient control must have one finite `Fc` per particle.
    pub fn check_control(&self, fc: Option<&[Matrix3<f64>]>, step: usize) -> Result<(), SimError> {
        let Some(fc) = fc else { return Ok(()) };
        let particles = self.num_particles();
        if fc.len() != particles {
            return Err(SimError::InvalidScene(format!(
                "control at step {step} has {} entries for {particles} particles",
                fc.len()
            )));
        }
        if let Some(p) = fc
            .par_iter()
            .position_first(|m| !m.iter().all(|a| a.is_finite()))
        {
            return Err(SimError::NonFinite {
                step,
                particle: p,
                field: "control Fc",
            });
        }
        Ok(())
    }

    /// Total number of effect parameters, and a zeroed gradient buffer for them.
    pub fn zero_effect_params(&self) -> Vec<Vec<f64>> {
        self.effects
            .iter()
            .map(|e| vec![0.0; e.num_params()])
            .collect()
    }

    /// Potential energy of the conservative effects (gravity) at positions `x`.
    pub fn potential_energy(&self, x: &[Vector3<f64>]) -> f64 {
        self.effects
            .iter()
            .map(|e| e.potential_energy(x, &self.mass))
            .sum()
    }
}

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
