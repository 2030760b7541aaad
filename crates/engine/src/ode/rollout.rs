//! Multi-step RK4 runs and the gradient of a kinetic-energy cost through them.
//!
//! The cost of a run of steps `k = first .. first + n` is `sum_k KE(S_{k+1})`, the kinetic
//! energy of the motion at the end of every step ([`Rk4::motion_energy`]: particles at
//! the velocity they move with, clamped ones at their prescribed velocity), the
//! active-damping objective.

use super::rhs::Rk4;
use super::rk4::Rk4Tape;
use crate::integrator::{ControlGradient, Controlled, StepControls, Steps};
use crate::mpm::ControlParams;
use crate::mpm::SimError;
use crate::mpm::State;
use crate::mpm::StateGrad;
use nalgebra::Matrix3;
use rayon::prelude::*;

/// dL/d(initial state), dL/d(control knots) and dL/dFc of a run.
#[derive(Clone, Debug)]
pub struct RunGradient {
    pub initial: State,
    pub params: ControlParams,
    /// dL/d(effect parameters), in model order.
    pub effect_params: Vec<Vec<f64>>,
    /// dL/dFc per step, for the steps whose control was given.
    pub controls: Vec<Option<Vec<Matrix3<f64>>>>,
}

impl Rk4 {
    /// The one RK4 run, with both kinds of control: from the ODE state `s`, `steps` steps,
    /// each starting with its control `Fc` applied to F (`controls[i]` for local step `i`, if
    /// any, as in the Euler step) and reading the boundary controls' knots `params` at its
    /// stage times. Records a tape when given one; `on_step(k, state)` sees the state after
    /// every global step `k`.
    pub fn forward_driven(
        &self,
        s: &mut State,
        controls: &StepControls,
        params: &ControlParams,
        steps: Steps,
        mut tape: Option<&mut Rk4Tape>,
        mut on_step: impl FnMut(usize, &State),
    ) -> Result<(), SimError> {
        self.controls().check_params(params)?;
        self.check_state(s, steps.first)?;
        if let Some(t) = tape.as_deref_mut() {
            t.first_step = steps.first;
            t.steps.clear();
            t.pre_control_f.clear();
        }
        for i in 0..steps.count {
            let k = steps.first + i;
            let fc = controls.get(i).and_then(|c| c.as_deref());
            self.check_control(fc, k)?;
            let pre_f = fc.map(|fc| self.apply_control(s, fc));
            let stages = self.rk4_step(s, params, k, tape.is_some())?;
            if let (Some(t), Some(st)) = (tape.as_deref_mut(), stages) {
                t.steps.push(st);
                t.pre_control_f.push(pre_f);
            }
            on_step(k, s);
        }
        if let Some(t) = tape {
            t.last = s.clone().with_affine();
        }
        Ok(())
    }

    /// The control's jump of F at a step's start; returns F before it.
    fn apply_control(&self, s: &mut State, fc: &[Matrix3<f64>]) -> Vec<Matrix3<f64>> {
        let (form, pre) = (self.control_form, s.f.clone());
        s.f.par_iter_mut()
            .zip(&pre)
            .zip(fc)
            .for_each(|((f, pre), c)| *f = form.apply(pre, c));
        pre
    }

    /// The reverse of [`Rk4::forward_driven`] over its tape, from `adj` = dL/d(last state):
    /// `seed(i, adj, grad_params)` adds a cost on the state after local step `i` before
    /// that step is reversed.
    pub fn backward_driven(
        &self,
        tape: &Rk4Tape,
        controls: &StepControls,
        params: &ControlParams,
        mut adj: State,
        mut seed: impl FnMut(usize, &mut State, &mut ControlParams),
    ) -> RunGradient {
        let mut grad_params = self.controls().zero_params();
        let mut effect_params = self.zero_effect_params();
        let mut grad_controls = vec![None; tape.steps.len()];
        for i in (0..tape.steps.len()).rev() {
            seed(i, &mut adj, &mut grad_params);
            let k = tape.first_step + i;
            let (grads, effects) = (&mut grad_params, &mut effect_params);
            self.rk4_step_reverse(&tape.steps[i], params, k, &mut adj, grads, effects);
            // Reverse of the control's jump at the step's start.
            if let (Some(Some(fc)), Some(Some(pre_f))) =
                (controls.get(i), tape.pre_control_f.get(i))
            {
                let form = self.control_form;
                let (grad_f, grad_fc): (Vec<_>, Vec<_>) = adj
                    .f
                    .par_iter()
                    .zip(pre_f.par_iter().zip(fc.par_iter()))
                    .map(|(g, (f, c))| form.apply_reverse(f, c, g))
                    .unzip();
                adj.f = grad_f;
                grad_controls[i] = Some(grad_fc);
            }
        }
        RunGradient {
            initial: adj,
            params: grad_params,
            effect_params,
            controls: grad_controls,
        }
    }

    /// [`Rk4::forward_driven`] with the boundary controls alone, returning the kinetic
    /// energy of the motion at the end of each step.
    pub fn rollout(
        &self,
        s: &mut State,
        params: &ControlParams,
        steps: Steps,
        mut tape: Option<&mut Rk4Tape>,
        mut on_step: impl FnMut(usize, &State),
    ) -> Result<Vec<f64>, SimError> {
        let mut energy = Vec::with_capacity(steps.count);
        let taped = tape.is_some();
        let mut failed = None;
        let ran = self.forward_driven(s, &[], params, steps, tape.as_deref_mut(), |k, st| {
            if !taped && failed.is_none() {
                match self.motion_energy(st, &self.control_values(params, k, 1.0), k) {
                    Ok(e) => energy.push(e),
                    Err(e) => failed = Some(e),
                }
            }
            on_step(k, st);
        });
        if let Some(e) = failed {
            return Err(e);
        }
        ran?;
        if let Some(t) = tape {
            // With a tape every state is kept, so the energies can be evaluated afterwards in
            // parallel (the same evaluations, so the same bits).
            energy = (0..steps.count)
                .into_par_iter()
                .map(|i| {
                    let k = steps.first + i;
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
        let adj = grad_last.cloned().unwrap_or_else(|| State::ode_zeros(n));
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
        let seed = |i: usize, adj: &mut State, grad_params: &mut ControlParams| {
            let (g, k) = (&energy_grads[i], tape.first_step + i);
            adj.axpy(1.0, &g.state);
            self.controls()
                .values_reverse(k, 1.0, self.dt, &g.controls, grad_params);
        };
        self.backward_driven(tape, &[], params, adj, seed)
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
