//! Integrators behind one trait: symplectic-Euler MLS-MPM ([`crate::mpm::Euler`]) and RK4
//! on the ODE form ([`crate::ode::Rk4`]), both over the same [`Model`]. A caller that
//! optimizes deformation-gradient controls (the morph) is written once against
//! [`Integrator`]; [`crate::Engine`] holds whichever one the settings chose.

use crate::mpm::ControlParams;
use crate::mpm::model::Model;
use crate::mpm::{Euler, Gradients, SimError, State, StateGrad};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

pub mod recompute;

pub use crate::mpm::control::{Controls, StepControl, StepControls};
pub use crate::mpm::model::Steps;

/// A cost on every state along a run: `seed(k, state, adj)` adds to `adj` the adjoint of the
/// cost on the state after global step `k` (see [`Integrator::backward_seeded`]).
pub type SeedAfter<'a> = dyn FnMut(usize, &State, &mut StateGrad) + 'a;

/// What sees the state after every global step `k` of a run: `on_step(k, state)`.
pub type OnStep<'a> = dyn FnMut(usize, &State) + 'a;

/// Which integrator advances the model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IntegratorKind {
    /// Symplectic-Euler MLS-MPM (APIC): one transfer round trip per step, fused and fast.
    #[default]
    Euler,
    /// Classic RK4 on the ODE form `dS/dt = f(S, u, t)`: four evaluations per step, far less
    /// numerical damping (see docs/control.md).
    Rk4,
}

impl IntegratorKind {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [IntegratorKind; 2] = [IntegratorKind::Euler, IntegratorKind::Rk4];
}

/// What the reverse pass needs from a forward run of some steps, and the states it went
/// through (the morph writes its frames from them).
pub trait RunTape: Default + Clone + Send + Sync {
    /// Number of steps recorded.
    fn len(&self) -> usize;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The state at the start of recorded step `k`; `k = len()` gives the final state.
    fn state_at(&self, k: usize) -> Cow<'_, State>;

    /// The state after the last step.
    fn last(&self) -> &State;

    /// Removes the steps from `k` on, with the final state, and returns them as a tape of
    /// their own (a run that started at step `k`).
    fn split_off(&mut self, k: usize) -> Self;

    /// Appends `tail`, a run that started where this tape's steps end.
    fn append(&mut self, tail: Self);

    /// Heap bytes the tape holds.
    fn bytes(&self) -> usize;
}

/// A time integrator over a [`Model`] (which it dereferences to), with a tape and a reverse
/// pass.
pub trait Integrator: std::ops::Deref<Target = Model> + Send + Sync {
    /// What the reverse pass needs from a forward run.
    type Tape: RunTape;

    fn model(&self) -> &Model {
        self
    }

    /// Runs `n_steps` steps from `state` (global steps `first_step..`, which time-dependent
    /// effects read and errors name), recording a tape when given one.
    fn forward(
        &self,
        state: &mut State,
        controls: &StepControls,
        first_step: usize,
        n_steps: usize,
        tape: Option<&mut Self::Tape>,
    ) -> Result<(), SimError> {
        let steps = Steps::new(first_step, n_steps);
        self.forward_observed(state, Controls::of_f(controls), steps, tape, None)
    }

    /// [`Integrator::forward`] with both kinds of control ([`Controls`]), where
    /// `on_step(k, state)`, when given, sees the state after every global step `k`.
    fn forward_observed(
        &self,
        state: &mut State,
        controls: Controls,
        steps: Steps,
        tape: Option<&mut Self::Tape>,
        on_step: Option<&mut OnStep>,
    ) -> Result<(), SimError>;

    /// Bytes a tape holds per step for `particles` particles (what a memory budget plans
    /// with; [`RunTape::bytes`] measures a real one).
    fn tape_bytes_per_step(&self, particles: usize) -> usize;

    /// Reverse pass over a taped run: `grad_last` is dL/d(final state); `controls` must be the
    /// ones the forward pass used.
    fn backward(
        &self,
        tape: &Self::Tape,
        controls: &StepControls,
        grad_last: StateGrad,
    ) -> Gradients {
        self.backward_seeded(tape, Controls::of_f(controls), grad_last, &mut |_, _, _| {})
    }

    /// [`Integrator::backward`] with both kinds of control (the forward's), for a cost on
    /// every state along the run: `seed_after(k, state, adj)` adds to `adj` the adjoint of
    /// the cost on the state after global step `k` (before any control of the next step),
    /// before that step is reversed. With knots, [`Gradients::knots`] holds their gradient.
    fn backward_seeded(
        &self,
        tape: &Self::Tape,
        controls: Controls,
        grad_last: StateGrad,
        seed_after: &mut SeedAfter,
    ) -> Gradients;
}

impl RunTape for crate::mpm::Tape {
    fn len(&self) -> usize {
        self.steps.len()
    }

    fn state_at(&self, k: usize) -> Cow<'_, State> {
        Cow::Borrowed(self.steps.get(k).map_or(&self.last, |s| &s.pre))
    }

    fn last(&self) -> &State {
        &self.last
    }

    fn split_off(&mut self, k: usize) -> Self {
        crate::mpm::Tape {
            steps: self.steps.split_off(k),
            last: std::mem::take(&mut self.last),
        }
    }

    fn append(&mut self, tail: Self) {
        self.steps.extend(tail.steps);
        self.last = tail.last;
    }

    fn bytes(&self) -> usize {
        self.steps.iter().map(|s| s.bytes()).sum::<usize>() + self.last.bytes()
    }
}

impl Integrator for Euler {
    type Tape = crate::mpm::Tape;

    fn forward_observed(
        &self,
        state: &mut State,
        controls: Controls,
        steps: Steps,
        tape: Option<&mut Self::Tape>,
        mut on_step: Option<&mut OnStep>,
    ) -> Result<(), SimError> {
        let (f, knots) = (controls.f, controls.knots);
        self.forward_driven(state, f, knots, steps, tape, |k, s| {
            if let Some(f) = on_step.as_deref_mut() {
                f(k, s)
            }
        })
    }

    fn tape_bytes_per_step(&self, particles: usize) -> usize {
        crate::mpm::StepTape::bytes_for(
            particles,
            self.grid.node_count(),
            self.material.kept_per_particle(),
        )
    }

    fn backward_seeded(
        &self,
        tape: &Self::Tape,
        controls: Controls,
        grad_last: StateGrad,
        seed_after: &mut SeedAfter,
    ) -> Gradients {
        let (grads, knots) =
            self.backward_driven(tape, controls.f, controls.knots, grad_last, seed_after);
        Gradients { knots, ..grads }
    }
}

/// dL/d(inputs) of a controlled run: initial state, control knots, effect parameters.
#[derive(Clone, Debug)]
pub struct ControlGradient {
    pub initial: StateGrad,
    pub params: ControlParams,
    pub effect_params: Vec<Vec<f64>>,
}

/// Runs driven by the model's boundary controls (body forces, prescribed velocities or
/// positions, see [`crate::mpm::boundary`]) and the active-damping cost: the kinetic energy
/// of the motion summed over the steps. What the rope's controllers need, with either
/// integrator.
pub trait Controlled: Integrator {
    /// Runs `n_steps` steps from `state` (global steps `first_step..`) with the control knots
    /// `params`, recording a tape when given one. Returns the kinetic energy of the motion
    /// after each step; `on_step(k, state)` sees the state after global step `k`.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &self,
        state: &mut State,
        params: &ControlParams,
        steps: Steps,
        tape: Option<&mut Self::Tape>,
        on_step: &mut dyn FnMut(usize, &State),
    ) -> Result<Vec<f64>, SimError>;

    /// Gradient of `weight * sum_k KE(S_{k+1}) + <grad_last, S_last>` over a taped run.
    fn kinetic_cost_gradient(
        &self,
        tape: &Self::Tape,
        params: &ControlParams,
        weight: f64,
        grad_last: Option<&StateGrad>,
    ) -> ControlGradient;

    /// Kinetic energy of the particle velocities `1/2 sum m |v|^2` after global step `step`
    /// (clamped particles at their prescribed velocity).
    fn particle_energy(&self, state: &State, params: &ControlParams, step: usize) -> f64;
}

/// Kinetic energy `1/2 sum m |v|^2` of velocities `v`.
fn kinetic(mass: &[f64], v: &[nalgebra::Vector3<f64>]) -> f64 {
    v.iter()
        .zip(mass)
        .map(|(v, m)| 0.5 * m * v.norm_squared())
        .sum()
}

/// The Euler step moves each particle with its state velocity (the grid's, or the prescribed
/// one), so the motion's kinetic energy is that of the state's velocities.
impl Controlled for Euler {
    fn run(
        &self,
        state: &mut State,
        params: &ControlParams,
        steps: Steps,
        tape: Option<&mut Self::Tape>,
        on_step: &mut dyn FnMut(usize, &State),
    ) -> Result<Vec<f64>, SimError> {
        let mut energy = Vec::with_capacity(steps.count);
        self.forward_driven(state, &[], Some(params), steps, tape, |k, s| {
            energy.push(kinetic(&self.mass, &s.v));
            on_step(k, s);
        })?;
        Ok(energy)
    }

    fn kinetic_cost_gradient(
        &self,
        tape: &Self::Tape,
        params: &ControlParams,
        weight: f64,
        grad_last: Option<&StateGrad>,
    ) -> ControlGradient {
        let n = tape.last.len();
        let seed = grad_last.cloned().unwrap_or_else(|| StateGrad::zeros(n));
        let (g, params) = self.backward_driven(tape, &[], Some(params), seed, |_, post, adj| {
            for (p, a) in adj.v.iter_mut().enumerate() {
                *a += (weight * self.mass[p]) * post.v[p];
            }
        });
        ControlGradient {
            initial: g.initial,
            params,
            effect_params: g.effect_params,
        }
    }

    fn particle_energy(&self, state: &State, _: &ControlParams, _: usize) -> f64 {
        kinetic(&self.mass, &state.v)
    }
}
