//! Effects: the optional physics a scene switches on. A scene pays only for the effects it
//! lists; the step itself knows none of them.
//!
//! An effect acts at one of two hook points, each with its reverse pass beside it:
//! - on particle momentum before P2G (drag: `m v -> (1 - dt drag) m v`);
//! - on grid velocities after `v_i = p_i / m_i` (gravity, walls; later body-force controls and
//!   prescribed boundary velocities). Effects run in list order; the reverse pass runs them
//!   backwards, each given the velocity it saw as input.
//!
//! Effects may have differentiable parameters (gravity's vector, a control's forces): the
//! reverse pass accumulates their gradients into a slice of length [`Effect::num_params`].

mod drag;
mod gravity;
mod walls;

pub use drag::Drag;
pub use gravity::Gravity;
pub use walls::{WallMode, Walls};

use crate::mpm::GridSpec;
use nalgebra::Vector3;

/// What a grid effect may read: the grid, nodal masses and the time step.
pub struct GridContext<'a> {
    pub spec: &'a GridSpec,
    pub mass: &'a [f64],
    pub dt: f64,
    pub step: usize,
}

pub trait Effect: Send + Sync + std::fmt::Debug {
    fn name(&self) -> &'static str;

    /// Factor applied to each particle's momentum `m v` in P2G (1 = no effect).
    fn momentum_retention(&self, _dt: f64) -> f64 {
        1.0
    }

    /// Whether [`Effect::apply_grid`] does anything (particle-only effects skip the grid pass).
    fn acts_on_grid(&self) -> bool {
        false
    }

    /// Forward: update grid velocities in place (only nodes with mass matter).
    fn apply_grid(&self, _ctx: &GridContext, _v: &mut [Vector3<f64>]) {}

    /// Reverse of [`Effect::apply_grid`]: `v_in` is the velocity the forward pass received;
    /// `grad_v` holds dL/d(output) and is replaced by dL/d(input); parameter gradients are
    /// added to `grad_params`.
    fn reverse_grid(
        &self,
        _ctx: &GridContext,
        _v_in: &[Vector3<f64>],
        _grad_v: &mut [Vector3<f64>],
        _grad_params: &mut [f64],
    ) {
    }

    /// Number of differentiable parameters.
    fn num_params(&self) -> usize {
        0
    }
}
