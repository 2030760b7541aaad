//! Constant external acceleration (gravity): `v_i += dt g` on every node with mass (Euler),
//! `a_i += g` (ODE form).

use super::{Effect, GridContext};
use nalgebra::Vector3;
use rayon::prelude::*;

#[derive(Clone, Copy, Debug)]
pub struct Gravity {
    pub acceleration: Vector3<f64>,
}

impl Effect for Gravity {
    fn name(&self) -> &'static str {
        "gravity"
    }

    fn acts_on_grid(&self) -> bool {
        true
    }

    fn apply_grid(&self, ctx: &GridContext, v: &mut [Vector3<f64>]) {
        let dv = ctx.dt * self.acceleration;
        v.par_iter_mut()
            .zip(ctx.mass.par_iter())
            .for_each(|(v, &m)| {
                if m > 0.0 {
                    *v += dv;
                }
            });
    }

    /// The velocity passes through unchanged; dL/dg = dt * sum of dL/dv over nodes with mass
    /// (summed sequentially so the result does not depend on the thread count).
    fn reverse_grid(
        &self,
        ctx: &GridContext,
        _v_in: &[Vector3<f64>],
        grad_v: &mut [Vector3<f64>],
        grad_params: &mut [f64],
    ) {
        let mut sum = Vector3::zeros();
        for (g, &m) in grad_v.iter().zip(ctx.mass) {
            if m > 0.0 {
                sum += g;
            }
        }
        for a in 0..3 {
            grad_params[a] += ctx.dt * sum[a];
        }
    }

    fn acts_on_rates(&self) -> bool {
        true
    }

    fn apply_rate(&self, _: &GridContext, _: usize, _: &mut Vector3<f64>, a: &mut Vector3<f64>) {
        *a += self.acceleration;
    }

    fn reverse_rate(
        &self,
        _: &GridContext,
        _: usize,
        _: &Vector3<f64>,
        _: &Vector3<f64>,
        _: &mut Vector3<f64>,
        grad_a: &mut Vector3<f64>,
        grad_params: &mut [f64],
    ) {
        for a in 0..3 {
            grad_params[a] += grad_a[a];
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
