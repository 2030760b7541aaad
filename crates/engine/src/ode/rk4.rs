//! Classic RK4 on the ODE form, with its reverse pass.
//!
//! Forward: `k1 = f(S)`, `k2 = f(S + h/2 k1)`, `k3 = f(S + h/2 k2)`, `k4 = f(S + h k3)`,
//! `S' = S + h/6 (k1 + 2 k2 + 2 k3 + k4)`, controls read at the stage times (fractions 0,
//! 1/2, 1/2, 1 of the step). The tape keeps the four stage inputs; the reverse pass replays
//! each stage's evaluation and runs the stages backwards:
//! `gk4 = h/6 gS'`, `gk3 = h/3 gS' + h gS4`, `gk2 = h/3 gS' + h/2 gS3`, `gk1 = h/6 gS' + h/2 gS2`,
//! `gS = gS' + gS1 + gS2 + gS3 + gS4` with `gSi = f_rev(Si, gki)`.

use super::rhs::{At, Rk4};
use crate::integrator::{Controls, Integrator, OnStep, RunTape, SeedAfter, StepControls, Steps};
use crate::mpm::ControlParams;
use crate::mpm::SimError;
use crate::mpm::{Gradients, State, StateGrad};
use nalgebra::Matrix3;
use std::borrow::Cow;

/// Stage fractions of the step at which RK4 evaluates `f`.
pub const STAGE_THETA: [f64; 4] = [0.0, 0.5, 0.5, 1.0];

/// Where RK4's stage `i` of step `step` evaluates the right-hand side.
fn stage_at(values: &[nalgebra::Vector3<f64>], step: usize, i: usize) -> At<'_> {
    At {
        values,
        step,
        theta: STAGE_THETA[i],
    }
}

/// The four stage inputs of one step.
pub type StepStages = [State; 4];

impl Rk4 {
    /// Advances `s` by one RK4 step (global index `step`, used for the control schedule and
    /// to label errors). Returns the stage inputs when asked (for the tape).
    pub fn rk4_step(
        &self,
        s: &mut State,
        params: &ControlParams,
        step: usize,
        record: bool,
    ) -> Result<Option<StepStages>, SimError> {
        let h = self.dt;
        let n = s.len();
        let mut k = [
            State::ode_zeros(n),
            State::ode_zeros(n),
            State::ode_zeros(n),
            State::ode_zeros(n),
        ];
        let mut stage = s.clone();
        let mut stages: Vec<State> = Vec::with_capacity(if record { 4 } else { 0 });
        let scale = [0.5 * h, 0.5 * h, h];
        for i in 0..4 {
            if i > 0 {
                s.combine_into(scale[i - 1], &k[i - 1], &mut stage);
            }
            let values = self.control_values(params, step, STAGE_THETA[i]);
            let at = stage_at(&values, step, i);
            self.rhs(&stage, &at, &mut k[i])?;
            if record {
                stages.push(stage.clone());
            }
        }
        s.axpy(h / 6.0, &k[0]);
        s.axpy(h / 3.0, &k[1]);
        s.axpy(h / 3.0, &k[2]);
        s.axpy(h / 6.0, &k[3]);
        self.check_step(s, step)?;
        Ok(record.then(|| stages.try_into().expect("four stages")))
    }

    /// Rejects a non-finite state or a particle moving more than `max_cfl` cells per step.
    fn check_step(&self, s: &State, step: usize) -> Result<(), SimError> {
        self.check_finite_and_cfl(s.first_non_finite(), &s.v, step)
    }

    /// Reverse of one RK4 step: turns `adj` from dL/d(S') into dL/d(S), and adds the control
    /// knots' gradients into `grad_params` and the effects' into `grad_effects`.
    pub fn rk4_step_reverse(
        &self,
        stages: &StepStages,
        params: &ControlParams,
        step: usize,
        adj: &mut State,
        grad_params: &mut ControlParams,
        grad_effects: &mut [Vec<f64>],
    ) {
        let h = self.dt;
        let weight = [h / 6.0, h / 3.0, h / 3.0, h / 6.0];
        // dL/d(S_i) passed on to stage i-1's k (S_i = S + scale_i k_{i-1}).
        let scale = [0.0, 0.5 * h, 0.5 * h, h];
        let out = adj.clone();
        let mut carried: Option<State> = None;
        for i in (0..4).rev() {
            let mut gk = out.clone();
            // gk_i = w_i gS' + scale_{i+1} gS_{i+1}
            for v in gk.x.iter_mut() {
                *v *= weight[i];
            }
            for v in gk.v.iter_mut() {
                *v *= weight[i];
            }
            for v in gk.f.iter_mut() {
                *v *= weight[i];
            }
            if let Some(g_next) = carried.take() {
                gk.axpy(scale[i + 1], &g_next);
            }
            let values = self.control_values(params, step, STAGE_THETA[i]);
            let at = stage_at(&values, step, i);
            let g = self.rhs_reverse(&stages[i], &at, &gk);
            self.controls()
                .values_reverse(step, STAGE_THETA[i], self.dt, &g.controls, grad_params);
            for (acc, e) in grad_effects.iter_mut().zip(&g.effect_params) {
                for (a, b) in acc.iter_mut().zip(e) {
                    *a += b;
                }
            }

            adj.axpy(1.0, &g.state);
            carried = Some(g.state);
        }
    }
}

/// A taped RK4 run: the stage inputs of every step, the first step's global index
/// (time-dependent effects and controls read it in reverse too) and the final state (as
/// [`State`], whose APIC matrix `c` the ODE form does not use: zero).
#[derive(Clone, Debug, Default)]
pub struct Rk4Tape {
    pub first_step: usize,
    pub steps: Vec<StepStages>,
    /// Per step, the deformation gradients before a control `Fc` was added at its start
    /// (`None` for steps without a control): the state the step started from.
    pub pre_control_f: Vec<Option<Vec<Matrix3<f64>>>>,
    pub last: State,
}

impl Integrator for Rk4 {
    type Tape = Rk4Tape;

    fn forward_observed(
        &self,
        state: &mut State,
        controls: Controls,
        steps: Steps,
        tape: Option<&mut Rk4Tape>,
        mut on_step: Option<&mut OnStep>,
    ) -> Result<(), SimError> {
        let zero = self.controls().zero_params();
        let params = controls.knots.unwrap_or(&zero);
        let mut s = state.ode_part();
        self.forward_driven(&mut s, controls.f, params, steps, tape, |k, st| {
            if let Some(f) = on_step.as_deref_mut() {
                f(k, &st.clone().with_affine());
            }
        })?;
        *state = s.with_affine();
        Ok(())
    }

    fn tape_bytes_per_step(&self, particles: usize) -> usize {
        // Four stage states (x, v, F) and the F before a control.
        particles * (4 * State::ODE_BYTES_PER_PARTICLE + size_of::<Matrix3<f64>>())
    }

    fn backward(&self, tape: &Rk4Tape, controls: &StepControls, grad_last: StateGrad) -> Gradients {
        self.reverse_run(tape, Controls::of_f(controls), grad_last, None)
    }

    fn backward_seeded(
        &self,
        tape: &Rk4Tape,
        controls: Controls,
        grad_last: StateGrad,
        seed_after: &mut SeedAfter,
    ) -> Gradients {
        self.reverse_run(tape, controls, grad_last, Some(seed_after))
    }
}

impl Rk4 {
    /// The reverse pass of a taped run; `seed_after`, when given, seeds a cost on the state
    /// after every step (without one, no intermediate state is rebuilt from the tape).
    fn reverse_run(
        &self,
        tape: &Rk4Tape,
        controls: Controls,
        grad_last: StateGrad,
        mut seed_after: Option<&mut SeedAfter>,
    ) -> Gradients {
        let zero = self.controls().zero_params();
        let params = controls.knots.unwrap_or(&zero);
        let seed = |i: usize, adj: &mut State, _: &mut ControlParams| {
            let Some(seed_after) = seed_after.as_deref_mut() else {
                return;
            };
            let mut seed = StateGrad::zeros(adj.x.len());
            seed_after(tape.first_step + i, &tape.state_at(i + 1), &mut seed);
            for (a, g) in adj.x.iter_mut().zip(&seed.x) {
                *a += g;
            }
            for (a, g) in adj.v.iter_mut().zip(&seed.v) {
                *a += g;
            }
            for (a, g) in adj.f.iter_mut().zip(&seed.f) {
                *a += g;
            }
        };
        let g = self.backward_driven(tape, controls.f, params, grad_last.ode_part(), seed);
        Gradients {
            initial: g.initial.with_affine(),
            controls: g.controls,
            effect_params: g.effect_params,
            knots: if controls.knots.is_some() {
                g.params
            } else {
                Vec::new()
            },
        }
    }
}

impl RunTape for Rk4Tape {
    fn len(&self) -> usize {
        self.steps.len()
    }

    fn state_at(&self, k: usize) -> Cow<'_, State> {
        match self.steps.get(k) {
            Some(st) => {
                let mut s = st[0].clone().with_affine();
                if let Some(Some(f)) = self.pre_control_f.get(k) {
                    s.f = f.clone();
                }
                Cow::Owned(s)
            }
            None => Cow::Borrowed(&self.last),
        }
    }

    fn last(&self) -> &State {
        &self.last
    }

    fn split_off(&mut self, k: usize) -> Self {
        Rk4Tape {
            first_step: self.first_step + k,
            steps: self.steps.split_off(k),
            pre_control_f: self
                .pre_control_f
                .split_off(k.min(self.pre_control_f.len())),
            last: std::mem::take(&mut self.last),
        }
    }

    fn append(&mut self, tail: Self) {
        self.steps.extend(tail.steps);
        self.pre_control_f.extend(tail.pre_control_f);
        self.last = tail.last;
    }

    fn bytes(&self) -> usize {
        let stages: usize = self.steps.iter().flatten().map(|s| s.bytes()).sum();
        let pre: usize = self.pre_control_f.iter().flatten().map(|f| f.len()).sum();
        stages + pre * size_of::<Matrix3<f64>>() + self.last.bytes()
    }
}
