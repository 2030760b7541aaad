//! Linear drag, as in the reference morphing code: each Euler step P2G transfers
//! `(1 - dt c(t)) m v` instead of `m v`; in the ODE form it is the rate `a_i -= c(t) v_i` on
//! the grid (the same to first order in dt).
//!
//! The coefficient may switch on at a time, eased in over a ramp: `c(t) = c s((t - start) /
//! ramp)`, `s` the smoothstep. A morph uses that to let the held shape come to rest after the
//! last keyframe without braking the motion before it (see docs/morph.md); a step switch
//! would be a jolt the viewer sees. The coefficient depends on time only, so the reverse pass
//! is the same scaling.

use super::{Effect, GridContext, GridForm, NodeMotion};

#[derive(Clone, Copy, Debug)]
pub struct Drag {
    /// Damping per second once fully on.
    pub coefficient: f64,
    /// When it starts to act (seconds of simulation time).
    pub start: f64,
    /// Over how long it eases in (0: at once).
    pub ramp: f64,
}

impl Drag {
    /// Drag that acts from the first step on.
    pub fn always(coefficient: f64) -> Self {
        Drag {
            coefficient,
            start: 0.0,
            ramp: 0.0,
        }
    }

    /// The coefficient at time `t`.
    pub fn coefficient_at(&self, t: f64) -> f64 {
        if t < self.start {
            return 0.0;
        }
        if self.ramp <= 0.0 {
            return self.coefficient;
        }
        let u = ((t - self.start) / self.ramp).min(1.0);
        self.coefficient * u * u * (3.0 - 2.0 * u)
    }
}

impl Effect for Drag {
    fn name(&self) -> &'static str {
        "drag"
    }

    fn momentum_retention(&self, dt: f64, time: f64) -> f64 {
        1.0 - dt * self.coefficient_at(time)
    }

    /// On the grid in the ODE form only: the Euler step's drag is its momentum retention.
    fn acts_on_grid(&self, form: GridForm) -> bool {
        form == GridForm::Rate
    }

    fn apply_grid(&self, ctx: &GridContext, _: usize, m: &mut NodeMotion) {
        m.a -= self.coefficient_at(ctx.time) * m.v;
    }

    fn reverse_grid(
        &self,
        ctx: &GridContext,
        _: usize,
        _: &NodeMotion,
        grad: &mut NodeMotion,
        _: &mut [f64],
    ) {
        grad.v -= self.coefficient_at(ctx.time) * grad.a;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_coefficient_eases_in_from_its_start() {
        let d = Drag {
            coefficient: 4.0,
            start: 1.0,
            ramp: 0.5,
        };
        assert_eq!(d.coefficient_at(0.99), 0.0);
        assert_eq!(d.coefficient_at(1.0), 0.0);
        assert!((d.coefficient_at(1.25) - 2.0).abs() < 1e-12);
        assert_eq!(d.coefficient_at(1.5), 4.0);
        assert_eq!(d.coefficient_at(9.0), 4.0);
        assert_eq!(Drag::always(4.0).coefficient_at(0.0), 4.0);
    }
}
