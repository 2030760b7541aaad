//! The simulator: a scene's fixed data plus the step, its tape and its reverse pass.

use super::advance::{advance, advance_reverse};
use super::control::ControlForm;
use super::effect::GridForm;
use super::error::SimError;
use super::grid::{Bins, SharedMut};
use super::kernel::{Cached, KernelKind, Stencil};
use super::model::{Model, Steps};
use super::pipeline;
use super::profile::{Laps, Stage, StageClock};
use super::scratch::GridScratch;
use super::stages::{self, Parallel};
use super::state::{State, StateGrad, par_copy};
use super::stress::StressInputs;
use super::transfer::{self, Affine};
use crate::mpm::ControlParams;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

mod pass;
mod reverse;

use pass::{ParticleScratch, StepPass};

/// The symplectic-Euler MLS-MPM integrator over a [`Model`] (which it dereferences to).
#[derive(Debug)]
pub struct Euler {
    pub model: Model,
    /// Per-stage timings, when attached (`morph bench`); `None` takes none.
    pub clock: Option<Arc<StageClock>>,
}

impl std::ops::Deref for Euler {
    type Target = Model;
    fn deref(&self) -> &Model {
        &self.model
    }
}

impl std::ops::DerefMut for Euler {
    fn deref_mut(&mut self) -> &mut Model {
        &mut self.model
    }
}

impl From<Model> for Euler {
    fn from(model: Model) -> Self {
        Euler { model, clock: None }
    }
}

/// Scratch buffers reused across steps, forward and reverse: the grid's (one momentum
/// field a node) and the particles'.
#[derive(Default)]
pub struct Workspace {
    bins: Bins,
    grid: GridScratch<1>,
    particles: ParticleScratch,
}

/// One step of the reverse pass for the model's kernel ([`Euler::reverse_impl`]).
type ReverseStep = fn(
    &Euler,
    &StepTape,
    &State,
    Option<&[Matrix3<f64>]>,
    Option<&[Vector3<f64>]>,
    &mut StateGrad,
    &mut [Vec<f64>],
    &mut Workspace,
) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>);

/// Particle `p`'s kept control volume factor (1 where none is kept: the additive form).
#[inline(always)]
fn scale_of(scale: &[f64], p: usize) -> f64 {
    scale.get(p).copied().unwrap_or(1.0)
}

/// What the reverse pass needs from one forward step.
#[derive(Clone, Debug)]
pub struct StepTape {
    /// Particle state at the start of the step.
    pub pre: State,
    bins: Bins,
    /// Affine momentum `A` of each particle (saves recomputing the stress in reverse).
    affine: Vec<Matrix3<f64>>,
    /// What the stress stage kept for the reverse pass, per particle (fixed-corotated: the
    /// eigen-decomposition behind its SVD; see `ConstitutiveModel::kept_per_particle`).
    kept: Vec<f64>,
    /// The plastic control's volume factor per particle (empty for other forms).
    scale: Vec<f64>,
    grid_mass: Vec<f64>,
    /// Grid velocity `p / m`, before grid effects.
    grid_v: Vec<Vector3<f64>>,
    /// The global step index: the reverse pass gives time-dependent effects the same
    /// context the forward pass did.
    step: usize,
}

impl StepTape {
    /// Bytes one step's tape holds for `particles` particles on a grid of `nodes` nodes, with
    /// a material that keeps `kept` numbers a particle (and the plastic control's factor).
    pub fn bytes_for(particles: usize, nodes: usize, kept: usize) -> usize {
        State::bytes_for(particles)
            + particles
                * (size_of::<u32>() + size_of::<Matrix3<f64>>() + (kept + 1) * size_of::<f64>())
            + nodes * (size_of::<f64>() + size_of::<Vector3<f64>>())
    }

    /// Heap bytes this step's tape holds (the block lists, a few per thousand particles,
    /// left out).
    pub fn bytes(&self) -> usize {
        self.pre.bytes()
            + self.bins.order.len() * size_of::<u32>()
            + self.affine.len() * size_of::<Matrix3<f64>>()
            + self.kept.len() * size_of::<f64>()
            + self.scale.len() * size_of::<f64>()
            + self.grid_mass.len() * size_of::<f64>()
            + self.grid_v.len() * size_of::<Vector3<f64>>()
    }
}

impl StepTape {
    /// What the stress stage kept for `particles` (`keep` numbers each; none when nothing
    /// was kept).
    fn kept_of(&self, particles: std::ops::Range<usize>, keep: usize) -> &[f64] {
        match self.kept.is_empty() {
            true => &[],
            false => &self.kept[particles.start * keep..particles.end * keep],
        }
    }
}

/// Recorded forward steps of a rollout, and the state after the last one.
#[derive(Clone, Debug, Default)]
pub struct Tape {
    pub steps: Vec<StepTape>,
    pub last: State,
}

/// Result of [`Euler::backward`].
#[derive(Clone, Debug)]
pub struct Gradients {
    /// dL/d(initial state).
    pub initial: StateGrad,
    /// dL/dFc per step, for the steps whose control was given.
    pub controls: Vec<Option<Vec<Matrix3<f64>>>>,
    /// dL/d(parameters) of each effect, in scene order.
    pub effect_params: Vec<Vec<f64>>,
    /// dL/d(the boundary controls' knots), when the run was given knots (else empty).
    pub knots: ControlParams,
}

/// Where in each step the Euler integrator reads the boundary controls: the middle, so a
/// clamped particle moves by exactly `dt u(t + dt/2)`, the step's mean for linear `u`.
pub const CONTROL_THETA: f64 = 0.5;

/// Control `Fc` for local step `s`, if any.
fn control_at(controls: &super::control::StepControls, s: usize) -> Option<&[Matrix3<f64>]> {
    controls.get(s).and_then(|c| c.as_deref())
}

impl Euler {
    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        StressInputs {
            model: self.material.as_ref(),
            mass: self.mass[p],
            volume: self.volume[p],
            dt: self.dt,
            inv_d: self.inv_d(),
        }
    }

    /// Product of the effects' momentum factors in global step `step` (1 when no drag is on).
    fn momentum_retention(&self, step: usize) -> f64 {
        let time = step as f64 * self.dt;
        self.effects
            .iter()
            .map(|e| e.momentum_retention(self.dt, time))
            .product()
    }

    fn check_state(&self, state: &State, step: usize) -> Result<(), SimError> {
        self.check_size(state.len())?;
        self.check_finite_and_cfl(state.first_non_finite(), &state.v, step)
    }

    /// Advances `state` by one step with optional controls `fc` (per particle, applied to `F`
    /// by the model's [`crate::mpm::ControlForm`]).
    /// `step` is the global step index (time-dependent effects read it; errors name it).
    pub fn step(
        &self,
        state: &mut State,
        fc: Option<&[Matrix3<f64>]>,
        step: usize,
        ws: &mut Workspace,
    ) -> Result<(), SimError> {
        match self.kernel {
            KernelKind::Quadratic => self.step_impl::<3>(state, fc, None, step, ws, None),
            KernelKind::Cubic => self.step_impl::<4>(state, fc, None, step, ws, None),
        }
    }

    /// Runs `n_steps` steps from `state`; `controls[s]` (if present and `Some`) is the `Fc` of
    /// local step `s`. Records a tape for [`Euler::backward`] when `tape` is given.
    pub fn forward(
        &self,
        state: &mut State,
        controls: &super::control::StepControls,
        first_step: usize,
        n_steps: usize,
        tape: Option<&mut Tape>,
    ) -> Result<(), SimError> {
        let steps = Steps::new(first_step, n_steps);
        self.forward_driven(state, controls, None, steps, tape, |_, _| {})
    }

    /// [`Euler::forward`] with the model's boundary controls driven by the knots
    /// `params` (read at the middle of each step: a clamped particle moves by exactly
    /// `dt u(t + dt/2)`, a body force acts as `m b dt` on the momentum). `on_step(k, state)`
    /// sees the state after every global step `k`.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_driven(
        &self,
        state: &mut State,
        controls: &super::control::StepControls,
        params: Option<&ControlParams>,
        steps: Steps,
        mut tape: Option<&mut Tape>,
        mut on_step: impl FnMut(usize, &State),
    ) -> Result<(), SimError> {
        let Steps {
            first: first_step,
            count: n_steps,
        } = steps;
        let mut ws = Workspace::default();
        if let Some(t) = tape.as_deref_mut() {
            t.steps.clear();
        }
        self.check_state(state, first_step)?;
        if let Some(params) = params {
            self.controls().check_params(params)?;
        }
        for s in 0..n_steps {
            let k = first_step + s;
            let fc = control_at(controls, s);
            let values = params.map(|p| self.control_values(p, k, CONTROL_THETA));
            let values = values.as_deref();
            let rec = tape.as_deref_mut().map(|t| &mut t.steps);
            match self.kernel {
                KernelKind::Quadratic => self.step_impl::<3>(state, fc, values, k, &mut ws, rec)?,
                KernelKind::Cubic => self.step_impl::<4>(state, fc, values, k, &mut ws, rec)?,
            }
            on_step(k, state);
        }
        if let Some(t) = tape {
            t.last = state.clone();
        }
        Ok(())
    }

    /// One step: a forward pass of the pipeline in the Euler step's form ([`StepPass`]:
    /// P1 the stress, P2G, G the grid update, G2P with P2 the particle update), and what
    /// the reverse pass needs pushed onto `tape`.
    #[allow(clippy::too_many_arguments)]
    fn step_impl<const N: usize>(
        &self,
        state: &mut State,
        fc: Option<&[Matrix3<f64>]>,
        values: Option<&[Vector3<f64>]>,
        step: usize,
        ws: &mut Workspace,
        tape: Option<&mut Vec<StepTape>>,
    ) -> Result<(), SimError>
    where
        Stencil<N>: Cached,
    {
        self.check_size(state.len())?;
        self.check_control(fc, step)?;
        let mut laps = Laps::start(self.clock.as_deref());
        let Workspace {
            bins,
            grid,
            particles,
        } = ws;
        let mut pass = StepPass {
            euler: self,
            state,
            fc,
            values,
            body: values.map(|v| self.body_accelerations(v)),
            retention: self.momentum_retention(step),
            step,
            buf: particles,
            tape,
            taped_grid: Default::default(),
        };
        pipeline::forward::<N, 1, _>(&self.model, &mut pass, bins, grid, &mut laps)?;
        let state = pass.state;
        self.check_finite_and_cfl(state.first_non_finite(), &state.v, step)
    }

    /// Reverse pass over a taped rollout. `grad_last` is dL/d(state after the last step);
    /// `controls` must be the ones the forward pass used.
    pub fn backward(
        &self,
        tape: &Tape,
        controls: &super::control::StepControls,
        grad_last: StateGrad,
    ) -> Gradients {
        self.backward_driven(tape, controls, None, grad_last, |_, _, _| {})
            .0
    }

    /// Reverse of [`Euler::forward_driven`]: also returns dL/d(control knots) (empty
    /// without `params`). `seed_after(k, state, adj)` may add to `adj` the adjoint of a cost
    /// on the state after global step `k` before that step is reversed.
    pub fn backward_driven(
        &self,
        tape: &Tape,
        controls: &super::control::StepControls,
        params: Option<&ControlParams>,
        grad_last: StateGrad,
        mut seed_after: impl FnMut(usize, &State, &mut StateGrad),
    ) -> (Gradients, ControlParams) {
        let mut adj = grad_last;
        let mut grad_controls = vec![None; tape.steps.len()];
        let mut effect_params = self.zero_effect_params();
        let mut grad_params = match params {
            Some(_) => self.controls().zero_params(),
            None => Vec::new(),
        };
        let mut rws = Workspace::default();
        let reverse: ReverseStep = match self.kernel {
            KernelKind::Quadratic => Self::reverse_impl::<3>,
            KernelKind::Cubic => Self::reverse_impl::<4>,
        };
        for s in (0..tape.steps.len()).rev() {
            let post = if s + 1 < tape.steps.len() {
                &tape.steps[s + 1].pre
            } else {
                &tape.last
            };
            let step = &tape.steps[s];
            seed_after(step.step, post, &mut adj);
            let fc = control_at(controls, s);
            let values = params.map(|p| self.control_values(p, step.step, CONTROL_THETA));
            let values = values.as_deref();
            let (g, g_values) = reverse(
                self,
                step,
                post,
                fc,
                values,
                &mut adj,
                &mut effect_params,
                &mut rws,
            );
            if fc.is_some() {
                grad_controls[s] = Some(g);
            }
            if values.is_some() {
                self.controls().values_reverse(
                    step.step,
                    CONTROL_THETA,
                    self.dt,
                    &g_values,
                    &mut grad_params,
                );
            }
        }
        let grads = Gradients {
            initial: adj,
            controls: grad_controls,
            effect_params,
            knots: Vec::new(),
        };
        (grads, grad_params)
    }

    /// The momentum particle `p` scatters: its prescribed velocity's, or `m v` after drag
    /// plus the body force's impulse `m b dt`.
    #[inline]
    fn particle_momentum(
        &self,
        state: &State,
        values: Option<&[Vector3<f64>]>,
        body: Option<&[Vector3<f64>]>,
        retention: f64,
        p: usize,
    ) -> Vector3<f64> {
        let m = self.mass[p];
        if let Some(u) = values.and_then(|v| self.prescribed_velocity(v, p)) {
            return m * u;
        }
        let momentum = (retention * m) * state.v[p];
        match body {
            Some(b) => momentum + (self.dt * m) * b[p],
            None => momentum,
        }
    }
}
