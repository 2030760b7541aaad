//! The model both integrators run (the Euler engine here and the ODE form's RK4): grid,
//! time step, kernel, material, effects and the particles' masses and rest volumes, with one
//! validation, one stable time-step bound and one set of state checks.

use super::ControlForm;
use super::effect::Effect;
use super::transfer;
use super::{GridSpec, KernelKind, SimError};
use crate::lanes::SimdLevel;
use crate::material::ConstitutiveModel;
use crate::mpm::boundary;
use crate::mpm::{ControlEffect, ControlKind, ControlParams, ControlPlan, ControlSchedule};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// A run's global steps, `first..first + count` (time-dependent effects read them and
/// errors name them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Steps {
    pub first: usize,
    pub count: usize,
}

impl Steps {
    pub fn new(first: usize, count: usize) -> Steps {
        Steps { first, count }
    }
}

/// Everything fixed during a simulation, whichever integrator runs it.
#[derive(Debug)]
pub struct Model {
    pub grid: GridSpec,
    pub dt: f64,
    pub kernel: KernelKind,
    pub material: Arc<dyn ConstitutiveModel>,
    /// The optional physics the scene declared, in order (the `effects` module implements
    /// them), then the boundary controls [`Model::with_controls`] added.
    pub effects: Vec<Box<dyn Effect>>,
    pub mass: Vec<f64>,
    pub volume: Vec<f64>,
    /// Largest allowed particle displacement per step, in cells.
    pub max_cfl: f64,
    /// The boundary controls' schedule (one interval of the whole run when there are none).
    control_schedule: ControlSchedule,
    /// How a deformation-gradient control `Fc` acts on `F` (see [`ControlForm`]).
    pub control_form: ControlForm,
    /// The vector instruction set the lane kernels run (the widest this CPU has unless set):
    /// it changes the speed, never the bits ([`crate::lanes`]).
    pub simd: SimdLevel,
    /// The kinematic control moving each particle (`FREE` for free particles).
    clamp_of: Vec<u32>,
}

/// `clamp_of` entry of a particle no kinematic control moves.
const FREE: u32 = u32::MAX;

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
        let clamp_of = vec![FREE; mass.len()];
        Ok(Model {
            grid,
            dt,
            kernel,
            material,
            effects,
            mass,
            clamp_of,
            volume,
            max_cfl: 1.0,
            control_schedule: ControlSchedule::whole_run(1),
            control_form: ControlForm::default(),
            simd: SimdLevel::Auto,
        })
    }

    /// The model with boundary controls under one schedule, validated against its particles
    /// and appended to its effects (replacing any it had).
    pub fn with_controls(
        mut self,
        schedule: ControlSchedule,
        controls: Vec<ControlEffect>,
    ) -> Result<Model, SimError> {
        boundary::validate(&schedule, &controls, self.num_particles())?;
        self.effects.retain(|e| e.as_control().is_none());
        self.clamp_of = vec![FREE; self.num_particles()];
        for (e, c) in controls.into_iter().enumerate() {
            if c.kind.is_kinematic() {
                for &p in &c.particles {
                    self.clamp_of[p] = e as u32;
                }
            }
            self.effects.push(Box::new(c));
        }
        self.control_schedule = schedule;
        Ok(self)
    }

    /// The boundary controls of the effect list and their schedule.
    pub fn controls(&self) -> ControlPlan<'_> {
        ControlPlan::new(self.control_schedule, &self.effects)
    }

    /// Whether particle `p` moves with a prescribed velocity.
    #[inline]
    pub fn is_clamped(&self, p: usize) -> bool {
        self.clamp_of[p] != FREE
    }

    /// The kinematic control moving particle `p`, if any.
    #[inline]
    pub fn kinematic_control(&self, p: usize) -> Option<usize> {
        match self.clamp_of[p] {
            FREE => None,
            e => Some(e as usize),
        }
    }

    /// The prescribed velocity of particle `p` given the control values, if it has one.
    #[inline]
    pub fn prescribed_velocity(&self, values: &[Vector3<f64>], p: usize) -> Option<Vector3<f64>> {
        match self.clamp_of[p] {
            FREE => None,
            e => Some(values[e as usize]),
        }
    }

    /// Per-particle body accelerations from the body-force controls' values.
    pub fn body_accelerations(&self, values: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let mut b = vec![Vector3::zeros(); self.num_particles()];
        for (e, c) in self.controls().iter().enumerate() {
            if c.kind == ControlKind::BodyForce {
                for &p in &c.particles {
                    b[p] += values[e];
                }
            }
        }
        b
    }

    /// Sums per-particle adjoints into one per control: `grad_u` (of the prescribed
    /// velocities) for kinematic controls, `grad_body` (of the body accelerations) for body
    /// forces; in particle order, so the sums do not depend on the thread count.
    pub fn control_value_grads(
        &self,
        grad_u: &[Vector3<f64>],
        grad_body: &[Vector3<f64>],
    ) -> Vec<Vector3<f64>> {
        self.controls()
            .iter()
            .map(|c| {
                let src = if c.kind.is_kinematic() {
                    grad_u
                } else {
                    grad_body
                };
                c.particles.iter().map(|&p| src[p]).sum()
            })
            .collect()
    }

    /// The control values at fraction `theta` of step `step`.
    pub fn control_values(
        &self,
        params: &ControlParams,
        step: usize,
        theta: f64,
    ) -> Vec<Vector3<f64>> {
        self.controls().values(params, step, theta, self.dt)
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

    /// A deformation-gradient control must have one finite `Fc` per particle, each one the
    /// model's [`ControlForm`] can apply.
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
        let form = self.control_form;
        match fc
            .par_iter()
            .enumerate()
            .find_first(|(p, m)| form.check(m, step, *p).is_err())
        {
            Some((p, m)) => form.check(m, step, p),
            None => Ok(()),
        }
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
