//! The rope scene: a hyperelastic (fixed-corotated) rope hanging from a clamp at its top end,
//! released at rest tilted from the vertical under gravity, so it swings like a heavy
//! pendulum while its elastic modes ring. The controller moves the clamped end (a
//! prescribed position, bounded offset in the swing plane) and/or pushes the free end (a
//! bounded body force).
//! Units are SI. docs/control.md gives the numbers and why they were chosen.

use crate::engine::Engine;
use crate::engine::integrator::IntegratorKind;
use crate::engine::material::{MaterialModel, lame_from_young_poisson};
use crate::engine::mpm::State;
use crate::engine::mpm::{ControlEffect, ControlKind, ControlSchedule, Interpolation};
use crate::engine::mpm::{GridSpec, KernelKind, SimError};
use crate::engine::scene::{EffectConfig, MaterialConfig, SceneConfig};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// What the controller may move.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Actuation {
    /// The clamped end, in the swing plane: its position offset or its velocity (see
    /// `ClampMode`).
    Clamp,
    /// A body force on the free quarter of the rope, in the swing plane.
    TipForce,
    /// Both.
    Both,
    /// Body forces on each quarter of the rope, independently (distributed actuation: four
    /// controls, eight numbers per knot).
    Segments,
}

impl Actuation {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Actuation; 4] = [
        Actuation::Clamp,
        Actuation::TipForce,
        Actuation::Both,
        Actuation::Segments,
    ];
}

/// How the clamp is driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClampMode {
    /// Knots are offsets from the start (bounded by `max_clamp_offset`), linear in time.
    Position,
    /// Knots are velocities (bounded by `max_clamp_speed`).
    Velocity,
}

impl ClampMode {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [ClampMode; 2] = [ClampMode::Position, ClampMode::Velocity];
}

/// Rope scene settings (all SI).
#[derive(Clone, Debug, Serialize)]
pub struct RopeConfig {
    pub length: f64,
    /// Grid cells along the rope (dx = length / cells_along).
    pub cells_along: usize,
    /// Square cross-section side, in cells.
    pub thickness_cells: usize,
    /// Particles per cell per axis.
    pub particles_per_cell: usize,
    pub density: f64,
    /// The constitutive model (fixed-corotated by default).
    pub material: MaterialModel,
    /// The time integrator (RK4 by default: far less numerical damping than Euler, which
    /// matters when the controllers are judged by the energy left).
    pub integrator: IntegratorKind,
    pub youngs_modulus: f64,
    pub poisson_ratio: f64,
    pub gravity: f64,
    pub dt: f64,
    /// Simulated steps (the control horizon).
    pub steps: usize,
    /// Length of the clamped end, in cells.
    pub clamp_cells: usize,
    pub kernel: KernelKind,
    pub actuation: Actuation,
    pub interpolation: Interpolation,
    /// Steps per control interval.
    pub control_interval: usize,
    /// Initial tilt from the vertical (degrees), released at rest.
    pub initial_angle_deg: f64,
    pub clamp_mode: ClampMode,
    /// Largest clamp offset per axis (m), position mode.
    pub max_clamp_offset: f64,
    /// Largest clamp speed per axis (m/s), velocity mode.
    pub max_clamp_speed: f64,
    /// Largest tip acceleration per axis (m/s^2).
    pub max_tip_acceleration: f64,
}

impl Default for RopeConfig {
    fn default() -> Self {
        RopeConfig {
            length: 0.5,
            cells_along: 16,
            thickness_cells: 1,
            particles_per_cell: 2,
            density: 1000.0,
            material: MaterialModel::FixedCorotated,
            integrator: IntegratorKind::Rk4,
            youngs_modulus: 1.0e5,
            poisson_ratio: 0.3,
            gravity: 9.81,
            dt: 2.0e-3,
            steps: 1000,
            clamp_cells: 1,
            kernel: KernelKind::Quadratic,
            actuation: Actuation::Segments,
            interpolation: Interpolation::Linear,
            control_interval: 10,
            initial_angle_deg: 40.0,
            clamp_mode: ClampMode::Position,
            max_clamp_offset: 0.15,
            max_clamp_speed: 0.5,
            max_tip_acceleration: 5.0,
        }
    }
}

/// A built rope: the model with its controls and integrator, and its initial state.
pub struct Rope {
    pub engine: Engine,
    pub initial: State,
    pub config: RopeConfig,
}

impl RopeConfig {
    pub fn dx(&self) -> f64 {
        self.length / self.cells_along as f64
    }

    fn check(&self) -> Result<(), SimError> {
        let bad = |m: String| Err(SimError::InvalidScene(m));
        let positive = [
            ("length", self.length),
            ("density", self.density),
            ("youngs modulus", self.youngs_modulus),
            ("dt", self.dt),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("rope {name} must be positive and finite, got {v}"));
            }
        }
        for (name, v) in [
            ("gravity", self.gravity),
            ("max clamp offset", self.max_clamp_offset),
            ("max clamp speed", self.max_clamp_speed),
            ("max tip acceleration", self.max_tip_acceleration),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("rope {name} must be finite and >= 0, got {v}"));
            }
        }
        if !(self.poisson_ratio.is_finite() && (0.0..0.5).contains(&self.poisson_ratio)) {
            return bad(format!(
                "Poisson ratio must be in [0, 0.5), got {}",
                self.poisson_ratio
            ));
        }
        if !(4..=256).contains(&self.cells_along) {
            return bad(format!(
                "cells along the rope must be in 4..=256, got {}",
                self.cells_along
            ));
        }
        if self.thickness_cells == 0 || self.particles_per_cell == 0 || self.particles_per_cell > 4
        {
            return bad("thickness needs >= 1 cell and 1..=4 particles per cell".into());
        }
        if self.clamp_cells == 0 || self.clamp_cells >= self.cells_along {
            return bad(format!(
                "the clamp must cover 1..{} cells, got {}",
                self.cells_along, self.clamp_cells
            ));
        }
        if !(self.initial_angle_deg.is_finite() && self.initial_angle_deg.abs() <= 180.0) {
            return bad(format!(
                "initial angle must be within [-180, 180] degrees, got {}",
                self.initial_angle_deg
            ));
        }
        if self.steps == 0 {
            return bad("the horizon must have at least one step".into());
        }
        if self.control_interval == 0 || !self.steps.is_multiple_of(self.control_interval) {
            return bad(format!(
                "the control interval ({} steps) must be >= 1 and divide the horizon ({} steps)",
                self.control_interval, self.steps
            ));
        }
        Ok(())
    }

    /// Builds the rope: particles on a regular sub-cell lattice, the grid large enough for the
    /// rope to swing through a full circle around the clamp even after the clamp has drifted
    /// at full speed for the whole horizon.
    pub fn build(&self) -> Result<Rope, SimError> {
        self.check()?;
        let lattice = self.lattice();
        let h = self.dx() / self.particles_per_cell as f64;
        let n = lattice.x.len();
        let (use_clamp, use_tip) = match self.actuation {
            Actuation::Clamp => (true, false),
            Actuation::TipForce => (false, true),
            Actuation::Both => (true, true),
            Actuation::Segments => (false, false),
        };
        let grid = self.grid(use_clamp);
        let schedule = ControlSchedule {
            interpolation: self.interpolation,
            steps_per_interval: self.control_interval,
            intervals: self.steps / self.control_interval,
        };
        let controls = self.control_effects(use_clamp, use_tip, lattice.sets);
        let (mu, lambda) = lame_from_young_poisson(self.youngs_modulus, self.poisson_ratio);
        // The rope is a scene like any other: built through the one scene description.
        let scene = SceneConfig {
            grid,
            dt: self.dt,
            kernel: self.kernel,
            material: MaterialConfig {
                model: self.material,
                mu,
                lambda,
                density: self.density,
            },
            effects: vec![EffectConfig::Gravity {
                acceleration: [0.0, -self.gravity, 0.0],
            }],
        };
        let model = scene
            .model(vec![h * h * h; n])?
            .with_controls(schedule, controls)?;
        let engine = Engine::new(model, self.integrator)?;
        Ok(Rope {
            engine,
            initial: State::at_rest(lattice.x),
            config: self.clone(),
        })
    }

    /// Half the rope's thickness.
    fn half_thickness(&self) -> f64 {
        0.5 * self.thickness_cells as f64 * self.dx()
    }

    /// The particles on a regular sub-cell lattice in the rope's frame (s along it from the
    /// clamp), then tilted about z; and the sets the controls act on.
    fn lattice(&self) -> RopeLattice {
        let dx = self.dx();
        let ppc = self.particles_per_cell;
        let h = dx / ppc as f64;
        let (nl, nt) = (self.cells_along * ppc, self.thickness_cells * ppc);
        let half_t = self.half_thickness();
        let angle = self.initial_angle_deg.to_radians();
        let along = Vector3::new(angle.sin(), -angle.cos(), 0.0);
        let across = Vector3::new(angle.cos(), angle.sin(), 0.0);
        let mut x = Vec::with_capacity(nl * nt * nt);
        let mut sets = ControlSets::default();
        for i in 0..nl {
            let s_along = (i as f64 + 0.5) * h;
            for j in 0..nt {
                for k in 0..nt {
                    let p = s_along * along
                        + ((j as f64 + 0.5) * h - half_t) * across
                        + Vector3::new(0.0, 0.0, (k as f64 + 0.5) * h - half_t);
                    if s_along < self.clamp_cells as f64 * dx {
                        sets.clamped.push(x.len());
                    }
                    if s_along > 0.75 * self.length {
                        sets.tip.push(x.len());
                    }
                    let q = ((4.0 * s_along / self.length) as usize).min(3);
                    sets.quarters[q].push(x.len());
                    x.push(p);
                }
            }
        }
        RopeLattice { x, sets }
    }

    /// The grid: the rope (30% stretch allowed) swings through a full circle around the clamp,
    /// wherever the clamp can get from its start.
    fn grid(&self, use_clamp: bool) -> GridSpec {
        let dx = self.dx();
        let half_t = self.half_thickness();
        let horizon = self.steps as f64 * self.dt;
        let drift = match (use_clamp, self.clamp_mode) {
            (false, _) => 0.0,
            (true, ClampMode::Position) => self.max_clamp_offset,
            (true, ClampMode::Velocity) => self.max_clamp_speed * horizon,
        };
        let margin = 4.0 * dx;
        let reach = 1.3 * self.length + drift + margin;
        let top = drift + margin + half_t;
        let cells_x = (2.0 * reach / dx).ceil() as usize;
        let cells_y = ((reach + top) / dx).ceil() as usize;
        let cells_z = (2.0 * (half_t + margin) / dx).ceil() as usize;
        GridSpec {
            origin: [-reach, -reach, -0.5 * cells_z as f64 * dx],
            dx,
            cells: [cells_x, cells_y, cells_z.max(4)],
        }
    }

    /// The controls the actuation calls for: the clamp always (holding still, bound 0,
    /// without clamp actuation), a force on the tip, or one on each quarter of the rope.
    fn control_effects(
        &self,
        use_clamp: bool,
        use_tip: bool,
        sets: ControlSets,
    ) -> Vec<ControlEffect> {
        let mut effects = Vec::new();
        let (kind, b) = match self.clamp_mode {
            ClampMode::Position => (ControlKind::PrescribedPosition, self.max_clamp_offset),
            ClampMode::Velocity => (ControlKind::PrescribedVelocity, self.max_clamp_speed),
        };
        let b = if use_clamp { b } else { 0.0 };
        effects.push(ControlEffect {
            kind,
            name: "clamp".into(),
            particles: sets.clamped,
            bound: Vector3::new(b, b, 0.0),
        });
        if use_tip {
            effects.push(ControlEffect {
                kind: ControlKind::BodyForce,
                name: "tip-force".into(),
                particles: sets.tip,
                bound: Vector3::new(self.max_tip_acceleration, self.max_tip_acceleration, 0.0),
            });
        }
        if self.actuation == Actuation::Segments {
            for (q, set) in sets.quarters.into_iter().enumerate() {
                let b = self.max_tip_acceleration;
                effects.push(ControlEffect {
                    kind: ControlKind::BodyForce,
                    name: format!("segment-{q}"),
                    particles: set,
                    bound: Vector3::new(b, b, 0.0),
                });
            }
        }
        effects
    }
}

/// The rope's particles and the sets its controls act on.
struct RopeLattice {
    x: Vec<Vector3<f64>>,
    sets: ControlSets,
}

/// The particles of the clamp, of the tip (the last quarter) and of each quarter.
#[derive(Default)]
struct ControlSets {
    clamped: Vec<usize>,
    tip: Vec<usize>,
    quarters: [Vec<usize>; 4],
}
