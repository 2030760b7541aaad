//! Multi-step RK4 runs and the gradient of a kinetic-energy cost through them.
//!
//! The cost of a run of steps `k = first .. first + n` is `sum_k KE(S_{k+1})`, the kinetic
//! energy of the motion at the end of every step ([`Rk4::motion_energy`]: particles at
//! the velocity they move with, clamped ones at their prescribed velocity), the
//! active-damping objective.

use super::rhs::Rk4;
use super::rk4::Rk4Tape;
use crate::integrator::{ControlGradient, Controlled, Steps};
use crate::mpm::ControlParams;
use crate::mpm::SimError;
use crate::mpm::State;
use crate::mpm::StateGrad;
use rayon::prelude::*;

/// dL/d(initial state) and dL/d(control knots) of a run.
#[derive(Clone, Debug)]
pub struct RunGradient {
    pub initial: State,
    pub params: ControlParams,
    /// dL/d(effect parameters), in model order.
    pub effect_params: Vec<Vec<f64>>,
}

impl Rk4 {
    /// Runs `n_steps` RK4 steps from `s` (global steps `first_step..`), recording a tape when
    /// given one. Returns the kinetic energy at the end of each step; `on_step(k, state)` sees
    /// every state after step `k`.
    pub fn rollout(
        &self,
        s: &mut State,
        params: &ControlParams,
        steps: Steps,
        mut tape: Option<&mut Rk4Tape>,
        mut on_step: impl FnMut(usize, &State),
    ) -> Result<Vec<f64>, SimError> {
        let Steps {
            first: first_step,
            count: n_steps,
        } = steps;
        self.controls.check_params(params)?;
        self.check_state(s, first_step)?;
        if let Some(t) = tape.as_deref_mut() {
            t.first_step = first_step;
            t.steps.clear();
        }
        let mut energy = Vec::with_capacity(n_steps);
        let taped = tape.is_some();
        for k in first_step..first_step + n_steps {
            let stages = self.rk4_step(s, params, k, taped)?;
            if let (Some(t), Some(st)) = (tape.as_deref_mut(), stages) {
                t.steps.push(st);
            }
            if !taped {
                energy.push(self.motion_energy(s, &self.control_values(params, k, 1.0), k)?);
            }
            on_step(k, s);
        }
        if let Some(t) = tape {
            t.last = s.clone().with_affine();
            // With a tape every state is kept, so the energies can be evaluated afterwards in
            // parallel (the same evaluations, so the same bits).
            energy = (0..n_steps)
                .into_par_iter()
                .map(|i| {
                    let k = first_step + i;
                    let after = t.steps.get(i + 1).map_or(&*s, |st| &st[0]);
                    self.motion_energy(after, &self.control_values(params, k, 1.0), k)
                })
                .collect::<Result<_, _>>()?;
        }
        Ok(energy)
    }

    /// Gradient of `weight * sum_k KE(S_{k+1}) + <grad_last, S_last>` over a taped run whose
    /// final state is `last`.
    pub fn rollout_cost_gradient(
        &self,
        tape: &Rk4Tape,
        params: &ControlParams,
        last: &State,
        weight: f64,
        grad_last: Option<&State>,
    ) -> RunGradient {
        let n = last.len();
        let mut adj = grad_last.cloned().unwrap_or_else(|| State::ode_zeros(n));
        let mut grad_params = self.controls.zero_params();
        let mut grad_effects = self.zero_effect_params();
        // The energy terms' adjoints do not depend on the sweep: evaluate them in parallel first.
        let after = |i: usize| {
            if i + 1 < tape.steps.len() {
                &tape.steps[i + 1][0]
            } else {
                last
            }
        };
        let energy_grads: Vec<_> = (0..tape.steps.len())
            .into_par_iter()
            .map(|i| {
                let k = tape.first_step + i;
                let values = self.control_values(params, k, 1.0);
                self.motion_energy_reverse(after(i), &values, k, weight)
            })
            .collect();
        for (i, g) in energy_grads.iter().enumerate().rev() {
            let k = tape.first_step + i;
            adj.axpy(1.0, &g.state);
            self.controls
                .values_reverse(k, 1.0, self.dt, &g.controls, &mut grad_params);
            self.rk4_step_reverse(
                &tape.steps[i],
                params,
                k,
                &mut adj,
                &mut grad_params,
                &mut grad_effects,
            );
        }
        RunGradient {
            initial: adj,
            params: grad_params,
            effect_params: grad_effects,
        }
    }
}

/// The ODE form through the common interface: the caller's full states go in as their ODE
/// part ([`State::ode_part`]: the APIC matrix `c` is not part of the ODE form) and come back
/// with a zero `c` ([`State::with_affine`]).
impl Controlled for Rk4 {
    fn run(
        &self,
        state: &mut State,
        params: &ControlParams,
        steps: Steps,
        tape: Option<&mut Rk4Tape>,
        on_step: &mut dyn FnMut(usize, &State),
    ) -> Result<Vec<f64>, SimError> {
        let mut s = state.ode_part();
        let energy = self.rollout(&mut s, params, steps, tape, |k, st| {
            on_step(k, &st.clone().with_affine())
        })?;
        *state = s.with_affine();
        Ok(energy)
    }

    fn kinetic_cost_gradient(
        &self,
        tape: &Rk4Tape,
        params: &ControlParams,
        weight: f64,
        grad_last: Option<&StateGrad>,
    ) -> ControlGradient {
        let last = tape.last.ode_part();
        let seed = grad_last.map(State::ode_part);
        let g = self.rollout_cost_gradient(tape, params, &last, weight, seed.as_ref());
        ControlGradient {
            initial: g.initial.with_affine(),
            params: g.params,
            effect_params: g.effect_params,
        }
    }

    fn particle_energy(&self, state: &State, params: &ControlParams, step: usize) -> f64 {
        self.kinetic_energy(&state.ode_part(), &self.control_values(params, step, 1.0))
    }
}
