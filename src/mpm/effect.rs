//! The interface every effect implements, for both integrators (the effects themselves are in
//! the `effects` module): the engine calls these hooks and knows no effect by name.
//!
//! For the symplectic-Euler step an effect acts at one of two hook points, each with its
//! reverse pass beside it: on particle momentum before P2G (`momentum_retention`), or on grid
//! velocities after `v_i = p_i / m_i` (`apply_grid`). For the ODE form (RK4) it states its part
//! of the grid rates instead (`apply_rate`). Effects run in list order; the reverse passes run
//! them backwards, each given what it saw as input.

use super::GridSpec;
use nalgebra::Vector3;

/// What a grid effect may read: the grid, nodal masses, the time step, the global step index
/// and the time (`step * dt` for the Euler step; the stage's time for RK4).
pub struct GridContext<'a> {
    pub spec: &'a GridSpec,
    pub mass: &'a [f64],
    pub dt: f64,
    pub step: usize,
    pub time: f64,
}

pub trait Effect: Send + Sync + std::fmt::Debug {
    fn name(&self) -> &'static str;

    /// Factor applied to each particle's momentum `m v` in P2G of the step that starts at
    /// `time` (1 = no effect).
    fn momentum_retention(&self, _dt: f64, _time: f64) -> f64 {
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

    /// Whether [`Effect::apply_rate`] does anything in the ODE form.
    fn acts_on_rates(&self) -> bool {
        false
    }

    /// ODE form, forward: this effect's part of the rates at grid node `node` (which has
    /// mass `ctx.mass[node] > 0`): it may change the node velocity `v` and acceleration `a`.
    fn apply_rate(
        &self,
        _ctx: &GridContext,
        _node: usize,
        _v: &mut Vector3<f64>,
        _a: &mut Vector3<f64>,
    ) {
    }

    /// Reverse of [`Effect::apply_rate`]: `v_in`, `a_in` are what the forward pass received;
    /// `grad_v`, `grad_a` hold dL/d(outputs) and are replaced by dL/d(inputs); parameter
    /// gradients are added to `grad_params`.
    #[allow(clippy::too_many_arguments)]
    fn reverse_rate(
        &self,
        _ctx: &GridContext,
        _node: usize,
        _v_in: &Vector3<f64>,
        _a_in: &Vector3<f64>,
        _grad_v: &mut Vector3<f64>,
        _grad_a: &mut Vector3<f64>,
        _grad_params: &mut [f64],
    ) {
    }

    /// Potential energy of a conservative effect at these particle positions (gravity
    /// `-sum m g . x`), for energy reports; 0 for others.
    fn potential_energy(&self, _x: &[Vector3<f64>], _mass: &[f64]) -> f64 {
        0.0
    }

    /// Number of differentiable parameters.
    fn num_params(&self) -> usize {
        0
    }
}
