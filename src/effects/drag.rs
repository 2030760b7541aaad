//! Linear drag, as in the reference morphing code: each Euler step P2G transfers
//! `(1 - dt * coefficient) m v` instead of `m v`; in the ODE form it is the rate
//! `a_i -= coefficient v_i` on the grid (the same to first order in dt).

use super::{Effect, GridContext};
use nalgebra::Vector3;

#[derive(Clone, Copy, Debug)]
pub struct Drag {
    pub coefficient: f64,
}

impl Effect for Drag {
    fn name(&self) -> &'static str {
        "drag"
    }

    fn momentum_retention(&self, dt: f64) -> f64 {
        1.0 - dt * self.coefficient
    }

    fn acts_on_rates(&self) -> bool {
        true
    }

    fn apply_rate(&self, _: &GridContext, _: usize, v: &mut Vector3<f64>, a: &mut Vector3<f64>) {
        *a -= self.coefficient * *v;
    }

    fn reverse_rate(
        &self,
        _: &GridContext,
        _: usize,
        _: &Vector3<f64>,
        _: &Vector3<f64>,
        grad_v: &mut Vector3<f64>,
        grad_a: &mut Vector3<f64>,
        _: &mut [f64],
    ) {
        *grad_v -= self.coefficient * *grad_a;
    }
}
