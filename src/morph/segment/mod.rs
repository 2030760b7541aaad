//! One segment of a morph: `steps` simulation steps from a start state, with a control layer
//! (one `Fc` per particle) every `stride` steps, scored by the mass loss of its last state
//! and of the states on its way (the [`PathPoint`]s: where the schedule says the body should
//! be at each frame inside the segment).
//!
//! Two optimizers:
//! - [`Optimizer::Adam`]: Adam on all control layers of the segment at once, one forward and
//!   one reverse pass per iteration.
//! - [`Optimizer::LineSearch`]: the reference method (normalized gradient steps with a
//!   backtracking line search, one control layer after another), without its three known
//!   defects: each layer is normalized by its own current gradient norm (the reference used
//!   a stale norm from layer 0), the accepted line-search trial's rollout is kept instead of
//!   re-running an identical forward pass, and a failed line search leaves the last accepted
//!   rollout in place (the reference left the rejected trial's states).

use super::basis::{ControlBasis, ControlResolution};
use super::reach::ReachLoss;
use crate::engine::integrator::recompute::{self, Checkpointed, ChunkPlan};
use crate::engine::integrator::{Controls, Integrator, RunTape, SeedAfter, StepControl, Steps};
use crate::engine::mpm::{SimError, State, StateGrad};
use crate::loss::{FineMassLoss, MassLoss, volume_cost};
use crate::optim::Adam;
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

mod optimize;

/// Which optimizer a segment uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Optimizer {
    /// Adam on all control layers of a segment at once.
    Adam,
    /// The reference: normalized gradient descent with backtracking, layer by layer.
    LineSearch,
}

impl Optimizer {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Optimizer; 2] = [Optimizer::Adam, Optimizer::LineSearch];
}

impl Optimizer {
    /// The step size each optimizer starts from: Adam 0.02 per control entry, the reference
    /// line search 0.1 (its published initial normalized step).
    pub fn default_learning_rate(self) -> f64 {
        match self {
            Optimizer::Adam => 0.02,
            Optimizer::LineSearch => 0.1,
        }
    }
}

/// Optimizer settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OptimizerSettings {
    pub kind: Optimizer,
    /// Forward+reverse evaluations per segment (Adam), or iterations per layer (line search).
    pub iterations: usize,
    /// Adam: step size per control entry. Line search: initial step (reference: 0.1).
    pub learning_rate: f64,
    /// Line search: halvings before giving up on a layer (reference: 15).
    pub line_search_tries: usize,
    /// Line search: stop a layer when |g| < gd_tol |g_0| (reference: 1e-3).
    pub gd_tol: f64,
}

/// Controls of a segment: one `Fc` per particle for each control layer.
pub type Layers = Vec<Vec<Matrix3<f64>>>;

/// What a segment's optimization returns: the best controls found and where they lead.
pub struct SegmentResult {
    pub layers: Layers,
    pub loss: f64,
    pub initial_loss: f64,
    /// The state after the segment's last step under `layers`.
    pub last: State,
    /// Smallest and largest `J = det F` over the states after every step under `layers`.
    pub j_range: (f64, f64),
    /// Norm of the objective's gradient with respect to the optimizer's free values, at the
    /// first and at the last evaluation that took one (NaN when none did).
    pub grad_norms: (f64, f64),
    /// Evaluations (forward passes) spent.
    pub evaluations: usize,
}

/// A point on a segment's scheduled path: the mass loss, against where the schedule puts the
/// body then, of the state after global simulation step `step` (inside the segment, before its
/// last step).
pub struct PathPoint {
    pub step: usize,
    pub loss: MassLoss,
}

/// A segment to optimize, with either integrator.
pub struct Segment<'a, I: Integrator> {
    pub sim: &'a I,
    pub loss: &'a MassLoss,
    /// The mass loss on a finer grid, added when given.
    pub fine_loss: Option<&'a FineMassLoss>,
    /// The reach cost on the segment's last state, added when given.
    pub reach: Option<&'a ReachLoss>,
    pub start: &'a State,
    /// Global index of the segment's first step (for error messages).
    pub first_step: usize,
    pub steps: usize,
    pub stride: usize,
    /// Weight of the kinetic energy left at the segment's end, `w * sum 1/2 m |v|^2`, added
    /// to the mass loss so the body arrives instead of flying through the target.
    pub arrival_weight: f64,
    /// Weight of the volume cost, `w` times the mean over the segment's steps of
    /// [`crate::loss::volume_cost`] on the state after each step, so
    /// the optimizer keeps the body at its volume all along, not only at the segment's end.
    pub volume_weight: f64,
    /// The scheduled path inside the segment, and its weight: `w` times the mean of the
    /// points' mass losses is added to the objective, so the body follows the easing curve
    /// from frame to frame and not only at the segment's end (none: the end alone).
    pub path: &'a [PathPoint],
    pub path_weight: f64,
    /// Ends of earlier segments inside this one, each scored by its mass loss times
    /// `waypoint_weight`: a look-ahead window (segments k..k+n optimized as one, segment k's
    /// controls kept) passes through segment k's target on its way (none: a single segment).
    pub waypoints: &'a [PathPoint],
    pub waypoint_weight: f64,
    /// Weight of the controls' continuity in time, `w` times the mean over particles of
    /// `sum_l 1/2 |Fc_l - Fc_(l-1)|^2`, layer 0 against `anchor` (the last layer before the
    /// segment; zero at the start of the shot): a jump in the flow the controls ask for is
    /// what makes the elastic body surge and ease at every layer and segment boundary.
    pub smoothing: f64,
    pub anchor: Option<&'a [Matrix3<f64>]>,
    /// Where Adam's free control values live (see [`ControlBasis`]); the line search always
    /// works per particle, as the reference does.
    pub resolution: ControlResolution,
    /// Bytes the tapes of one rollout may hold: beyond it, the rollout keeps checkpoints and
    /// the reverse pass recomputes (see [`crate::engine::integrator::recompute`]); `usize::MAX`
    /// keeps every step.
    pub tape_budget: usize,
}

/// What the objective and the report need from the state after one step.
#[derive(Clone, Copy, Debug)]
struct AfterStep {
    /// The volume cost (0 when it is off).
    volume: f64,
    /// The mass loss against the path point at this step (0 where there is none).
    path: f64,
    /// The mass loss against the waypoint at this step (0 where there is none).
    waypoint: f64,
    min_j: f64,
    max_j: f64,
}

/// One evaluated control set: its objective and its run, recorded for the reverse pass.
struct Rollout<T> {
    loss: f64,
    run: Checkpointed<T>,
    /// Per step of the run, from its first.
    after: Vec<AfterStep>,
}

impl<T: RunTape> Rollout<T> {
    /// Replaces the run from segment-local step `from_step` on by `tail`, which starts there.
    fn splice(&mut self, tail: Rollout<T>, from_step: usize) {
        self.run.splice(tail.run);
        self.after.truncate(from_step);
        self.after.extend(tail.after);
        self.loss = tail.loss;
    }

    /// The rollout without its chunks: what is kept of a result that will not be reversed.
    fn settled(mut self) -> Rollout<T> {
        self.run.chunks.clear();
        self
    }

    fn j_range(&self) -> (f64, f64) {
        self.after
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), a| {
                (lo.min(a.min_j), hi.max(a.max_j))
            })
    }
}

impl<I: Integrator> Segment<'_, I> {
    /// The path point on the state after global step `k`, if any.
    fn path_point(&self, k: usize) -> Option<&PathPoint> {
        self.path.iter().find(|p| p.step == k)
    }

    /// The waypoint on the state after global step `k`, if any.
    fn waypoint(&self, k: usize) -> Option<&PathPoint> {
        self.waypoints.iter().find(|p| p.step == k)
    }

    /// The layer before layer `l` (layer 0's: the anchor, or none for zero).
    fn previous<'b>(
        &'b self,
        layers: &'b [Vec<Matrix3<f64>>],
        l: usize,
    ) -> Option<&'b [Matrix3<f64>]> {
        if l == 0 {
            self.anchor
        } else {
            Some(&layers[l - 1])
        }
    }

    /// The continuity cost of `layers` (see [`Segment::smoothing`]).
    fn smoothness(&self, layers: &[Vec<Matrix3<f64>>]) -> f64 {
        if self.smoothing == 0.0 {
            return 0.0;
        }
        let mut sum = 0.0;
        for (l, layer) in layers.iter().enumerate() {
            sum += match self.previous(layers, l) {
                Some(prev) => layer
                    .iter()
                    .zip(prev)
                    .map(|(a, b)| (a - b).norm_squared())
                    .sum(),
                None => layer.iter().map(|a| a.norm_squared()).sum::<f64>(),
            };
        }
        0.5 * self.smoothing * sum / particles_of(layers)
    }

    /// Adds the continuity cost's gradient to `grads`, which hold layers `from..`.
    fn smoothness_reverse(&self, layers: &[Vec<Matrix3<f64>>], from: usize, grads: &mut Layers) {
        if self.smoothing == 0.0 {
            return;
        }
        let w = self.smoothing / particles_of(layers);
        for l in from..layers.len() {
            let grad = &mut grads[l - from];
            // Its own difference to the layer before, and the next layer's difference to it.
            match self.previous(layers, l) {
                Some(prev) => {
                    for ((g, a), b) in grad.iter_mut().zip(&layers[l]).zip(prev) {
                        *g += w * (a - b);
                    }
                }
                None => {
                    for (g, a) in grad.iter_mut().zip(&layers[l]) {
                        *g += w * a;
                    }
                }
            }
            if let Some(next) = layers.get(l + 1) {
                for ((g, a), b) in grad.iter_mut().zip(&layers[l]).zip(next) {
                    *g += w * (a - b);
                }
            }
        }
    }

    pub fn num_layers(&self) -> usize {
        self.steps.div_ceil(self.stride)
    }

    /// Per-step controls from layer `from` on: layer `l` acts in equal parts `Fc / stride`
    /// on each of its steps `l * stride ..`. (Applied whole on its first step, every layer
    /// kicked the body at the layers' period, a frame-to-frame wobble a viewer sees.)
    /// The steps of a layer share one copy of its values.
    fn schedule(&self, layers: &[Vec<Matrix3<f64>>], from: usize) -> Vec<Option<StepControl>> {
        let share = 1.0 / self.stride as f64;
        let mut out = Vec::with_capacity(self.steps - from * self.stride);
        for layer in &layers[from..] {
            let part: StepControl = layer.iter().map(|c| c * share).collect();
            let steps = self.stride.min(self.steps - from * self.stride - out.len());
            for _ in 0..steps {
                out.push(Some(part.clone()));
            }
        }
        out
    }

    /// How a rollout is cut into chunks within [`Segment::tape_budget`].
    pub fn chunk_plan(&self) -> ChunkPlan {
        let n = self.start.len();
        ChunkPlan::within(
            self.tape_budget,
            self.steps,
            step_bytes(self.sim, n),
            State::bytes_for(n),
            self.stride,
        )
    }

    /// Forward from the start of layer `from` (state `start`) to the end of the segment.
    /// `before` holds the costs of the steps before `from` (empty when `from` is 0), so that
    /// objectives of partial rollouts compare with whole ones.
    fn rollout(
        &self,
        start: &State,
        layers: &[Vec<Matrix3<f64>>],
        from: usize,
        before: &[AfterStep],
    ) -> Result<Rollout<I::Tape>, SimError> {
        let schedule = self.schedule(layers, from);
        let first = self.first_step + from * self.stride;
        let n_steps = self.steps - from * self.stride;
        let mut after = Vec::with_capacity(n_steps);
        let mut inverted = None;
        let mut outside = None;
        let with_volume = self.volume_weight > 0.0;
        let model = self.sim.model();
        // Chunks start at every control layer too: the line search restarts there.
        let (seg_first, stride) = (self.first_step, self.stride);
        let cut = move |k: usize| (k - seg_first).is_multiple_of(stride);
        let run = recompute::record(
            self.sim,
            start.clone(),
            &schedule,
            first,
            n_steps,
            self.chunk_plan(),
            &cut,
            &mut |k, state| {
                let (min_j, max_j) = j_range(&state.f);
                let volume = match with_volume.then(|| volume_cost(&state.f)) {
                    Some(Ok((cost, _))) => cost,
                    Some(Err(particle)) => {
                        inverted.get_or_insert(SimError::Inverted {
                            step: k + 1,
                            particle,
                            j: state.f[particle].determinant(),
                        });
                        0.0
                    }
                    None => 0.0,
                };
                let mut scored =
                    |point: Option<&PathPoint>| match point.map(|p| path_loss(model, p, state)) {
                        Some(Ok(value)) => value,
                        Some(Err(e)) => {
                            outside.get_or_insert(e);
                            0.0
                        }
                        None => 0.0,
                    };
                let path = scored(self.path_point(k));
                let waypoint = scored(self.waypoint(k));
                after.push(AfterStep {
                    volume,
                    path,
                    waypoint,
                    min_j,
                    max_j,
                });
            },
        )?;
        // An inverted particle is an error when the volume cost is on (it is undefined there).
        if let Some(e) = inverted.or(outside) {
            return Err(e);
        }
        let state = &run.last;
        let mass = model.mass_grid(&state.x)?;
        let (loss, _) = self.loss.value_and_grad(&mass);
        let mut loss = loss + self.arrival_weight * state.kinetic_energy(&model.mass);
        if let Some(fine) = self.fine_loss {
            loss += fine.value(&state.x, &model.mass)?;
        }
        if let Some(reach) = self.reach {
            loss += reach.value(&state.x);
        }
        let all = || before.iter().chain(&after);
        if with_volume {
            let sum: f64 = all().map(|a| a.volume).sum();
            loss += self.volume_weight * sum / self.steps as f64;
        }
        if !self.path.is_empty() {
            let sum: f64 = all().map(|a| a.path).sum();
            loss += self.path_weight * sum / self.path.len() as f64;
        }
        if !self.waypoints.is_empty() {
            loss += self.waypoint_weight * all().map(|a| a.waypoint).sum::<f64>();
        }
        loss += self.smoothness(layers);
        Ok(Rollout { loss, run, after })
    }

    /// dL/d(the segment's last state `last`): its mass losses (the simulation grid's, the
    /// fine grid's), the reach cost, and the arrival term on its velocities.
    fn final_seed(&self, last: &State) -> Result<State, SimError> {
        let model = self.sim.model();
        let mass = model.mass_grid(&last.x)?;
        let (_, grad_m) = self.loss.value_and_grad(&mass);
        let mut seed = State::zeros(last.len());
        seed.x = model.mass_grid_reverse(&last.x, &grad_m);
        if let Some(fine) = self.fine_loss {
            for (g, f) in seed
                .x
                .iter_mut()
                .zip(fine.value_and_grad(&last.x, &model.mass)?.1)
            {
                *g += f;
            }
        }
        if let Some(reach) = self.reach {
            for (g, r) in seed.x.iter_mut().zip(reach.value_and_grad(&last.x).1) {
                *g += r;
            }
        }
        for (p, g) in seed.v.iter_mut().enumerate() {
            *g = self.arrival_weight * model.mass[p] * last.v[p];
        }
        Ok(seed)
    }

    /// dL/dFc for the layers from `from` on, through a rollout of the whole segment.
    fn gradient(
        &self,
        rollout: &Rollout<I::Tape>,
        layers: &[Vec<Matrix3<f64>>],
        from: usize,
    ) -> Result<Layers, SimError> {
        let model = self.sim.model();
        let seed = self.final_seed(&rollout.run.last)?;
        let schedule = self.schedule(layers, from);
        let at = self.first_step + from * self.stride;
        let volume_weight = self.volume_weight / self.steps as f64;
        let path_weight = self.path_weight / self.path.len().max(1) as f64;
        // The forward pass checked every J > 0 and every path state inside the grid, so the
        // costs are defined on every state.
        let mut costs_seed = |k: usize, state: &State, adj: &mut StateGrad| {
            if volume_weight > 0.0
                && let Ok((_, grad)) = volume_cost(&state.f)
            {
                for (a, g) in adj.f.iter_mut().zip(grad) {
                    *a += volume_weight * g;
                }
            }
            let points = [
                (self.path_point(k), path_weight),
                (self.waypoint(k), self.waypoint_weight),
            ];
            for (point, weight) in points {
                if let Some(point) = point
                    && let Ok(mass) = model.mass_grid(&state.x)
                {
                    let (_, grad_m) = point.loss.value_and_grad(&mass);
                    let grad_x = model.mass_grid_reverse(&state.x, &grad_m);
                    for (a, g) in adj.x.iter_mut().zip(grad_x) {
                        *a += weight * g;
                    }
                }
            }
        };
        let seed_after: Option<&mut SeedAfter> = (self.volume_weight > 0.0
            || (self.path_weight > 0.0 && !self.path.is_empty())
            || !self.waypoints.is_empty())
        .then_some(&mut costs_seed);
        // A layer's gradient is the sum of its steps' over `stride` (the reverse of
        // `schedule`), in step order. Chunks arrive last first and may cut a layer, so its
        // steps wait until the layer is whole (at most one layer's steps at a time).
        let share = 1.0 / self.stride as f64;
        let n_steps = self.steps - from * self.stride;
        let mut layer_grads: Layers = vec![Vec::new(); layers.len() - from];
        let mut pending: Vec<(usize, Vec<Matrix3<f64>>)> = Vec::new();
        let mut on_control = |k: usize, grad: Vec<Matrix3<f64>>| {
            let local = k - at;
            let l = local / self.stride;
            pending.push((local, grad));
            let in_layer = self.stride.min(n_steps - l * self.stride);
            if pending.iter().filter(|(s, _)| s / self.stride == l).count() < in_layer {
                return;
            }
            let (mut mine, rest): (Vec<_>, Vec<_>) =
                pending.drain(..).partition(|(s, _)| s / self.stride == l);
            pending = rest;
            mine.sort_by_key(|(s, _)| *s);
            let mut steps = mine.into_iter().map(|(_, g)| g);
            let mut sum = steps.next().expect("a layer has a step");
            for g in steps {
                sum.iter_mut().zip(g).for_each(|(a, b)| *a += b);
            }
            sum.iter_mut().for_each(|g| *g *= share);
            layer_grads[l] = sum;
        };
        recompute::reverse(
            self.sim,
            &rollout.run,
            &schedule,
            at,
            at,
            seed,
            seed_after,
            &mut on_control,
        )?;
        self.smoothness_reverse(layers, from, &mut layer_grads);
        Ok(layer_grads)
    }

    /// The segment objective (mass loss + arrival term) for `layers`, and its gradient with
    /// respect to every layer: what the optimizers use, exposed for finite-difference tests.
    pub fn objective_and_gradient(
        &self,
        layers: &[Vec<Matrix3<f64>>],
    ) -> Result<(f64, Layers), SimError> {
        let r = self.rollout(self.start, layers, 0, &[])?;
        let g = self.gradient(&r, layers, 0)?;
        Ok((r.loss, g))
    }

    /// The objective alone.
    pub fn objective(&self, layers: &[Vec<Matrix3<f64>>]) -> Result<f64, SimError> {
        Ok(self.rollout(self.start, layers, 0, &[])?.loss)
    }

    /// Runs the segment under `layers` again, without a tape: `on_step(k, state)` sees the
    /// state after every global step `k` (how the chain writes the frames of a result).
    /// Returns the last state, bitwise the one the optimization saw.
    pub fn replay(
        &self,
        layers: &[Vec<Matrix3<f64>>],
        on_step: &mut dyn FnMut(usize, &State),
    ) -> Result<State, SimError> {
        let mut state = self.start.clone();
        let schedule = self.schedule(layers, 0);
        self.sim.forward_observed(
            &mut state,
            Controls::of_f(&schedule),
            Steps::new(self.first_step, self.steps),
            None,
            Some(on_step),
        )?;
        Ok(state)
    }
}

/// Bytes one simulation step of a segment holds while it is reversed: its tape, and the
/// gradient of its control (every step of a spread layer is controlled).
pub fn step_bytes<I: Integrator>(sim: &I, particles: usize) -> usize {
    sim.tape_bytes_per_step(particles) + particles * size_of::<Matrix3<f64>>()
}

/// The mass loss of `state` against a path point.
fn path_loss(
    model: &crate::engine::mpm::model::Model,
    point: &PathPoint,
    state: &State,
) -> Result<f64, SimError> {
    Ok(point.loss.value_and_grad(&model.mass_grid(&state.x)?).0)
}

/// Smallest and largest determinant of `f`.
fn j_range(f: &[Matrix3<f64>]) -> (f64, f64) {
    f.iter()
        .map(|f| f.determinant())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), j| {
            (lo.min(j), hi.max(j))
        })
}

/// All control entries in one flat vector (layer, particle, matrix entry), for [`Adam`].
fn flatten(layers: &[Vec<Matrix3<f64>>]) -> Vec<f64> {
    layers
        .iter()
        .flat_map(|l| l.iter().flat_map(|m| m.iter().copied()))
        .collect()
}

/// The inverse of [`flatten`], into layers of the right shape.
fn unflatten(flat: &[f64], layers: &mut [Vec<Matrix3<f64>>]) {
    let mut values = flat.iter();
    for m in layers.iter_mut().flatten() {
        for x in m.iter_mut() {
            *x = *values.next().expect("as many values as entries");
        }
    }
}

/// The particle count of `layers`, which the continuity cost is a mean over.
fn particles_of(layers: &[Vec<Matrix3<f64>>]) -> f64 {
    layers.first().map_or(1, |l| l.len().max(1)) as f64
}

/// Errors a too-large control step causes (the trial is rejected, not the morph).
fn blew_up(e: &SimError) -> bool {
    matches!(
        e,
        SimError::CflExceeded { .. }
            | SimError::NonFinite { .. }
            | SimError::OutsideGrid { .. }
            | SimError::DegenerateControl { .. }
            | SimError::Inverted { .. }
    )
}
