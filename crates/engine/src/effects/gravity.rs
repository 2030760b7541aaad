//! Constant external acceleration (gravity): `v_i += dt g` on every node with mass (Euler),
//! `a_i += g` (ODE form).

use super::{Effect, GridContext, GridForm, GridRule, NodeMotion};
use nalgebra::Vector3;

#[derive(Clone, Copy, Debug)]
pub struct Gravity {
    pub acceleration: Vector3<f64>,
}

impl Effect for Gravity {
    fn name(&self) -> &'static str {
        "gravity"
    }

    fn acts_on_grid(&self, _: GridForm) -> bool {
        true
    }

    fn grid_rule(&self) -> Option<GridRule> {
        Some(GridRule::Gravity(self.acceleration.into()))
    }

    fn apply_grid(&self, ctx: &GridContext, _: usize, m: &mut NodeMotion) {
        match ctx.form {
            GridForm::Step => m.v += ctx.dt * self.acceleration,
            GridForm::Rate => m.a += self.acceleration,
        }
    }

    /// The motion passes through unchanged; dL/dg is `dt` dL/dv (Euler) or dL/da (rates).
    fn reverse_grid(
        &self,
        ctx: &GridContext,
        _: usize,
        _: &NodeMotion,
        grad: &mut NodeMotion,
        grad_params: &mut [f64],
    ) {
        let dg = match ctx.form {
            GridForm::Step => ctx.dt * grad.v,
            GridForm::Rate => grad.a,
        };
        for a in 0..3 {
            grad_params[a] += dg[a];
        }
    }

    fn potential_energy(&self, x: &[Vector3<f64>], mass: &[f64]) -> f64 {
        x.iter()
            .zip(mass)
            .map(|(x, m)| -m * self.acceleration.dot(x))
            .sum()
    }

    fn num_params(&self) -> usize {
        3
    }
}
