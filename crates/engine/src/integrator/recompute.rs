//! Forward runs recorded within a memory budget, and their reverse pass.
//!
//! A full tape holds every step of a run, so its memory grows with steps x particles. A
//! [`Checkpointed`] run keeps only the state at the start of each *chunk* of steps; the
//! reverse pass walks the chunks backwards, re-running each one's forward pass with a tape
//! just before reversing it (so a run costs one more forward pass). The forward pass is deterministic, so
//! the recomputed tape is bitwise the one the first pass would have kept, and so are the
//! gradients: the budget changes memory and time, never results.
//!
//! Peak tape memory: the chunk start states plus one chunk's tape. [`ChunkPlan::within`]
//! picks the longest chunk that fits a budget; when the whole tape fits, it is kept and
//! nothing is recomputed.

use super::{Controls, Integrator, RunTape, StepControls, Steps};
use crate::mpm::{Gradients, SimError, State, StateGrad};

/// How a run is cut into chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChunkPlan {
    /// Steps per chunk (a chunk also starts wherever the caller asks, e.g. at control layers).
    pub interval: usize,
}

impl ChunkPlan {
    /// One chunk: the whole tape is kept, nothing is recomputed.
    pub const WHOLE: ChunkPlan = ChunkPlan {
        interval: usize::MAX,
    };

    /// The longest chunk whose run of `steps` steps fits `budget` bytes of tape memory, for
    /// tapes of `step_bytes` a step and states of `state_bytes`, when a chunk also starts
    /// every `cut_every` steps (the caller's restart points). The whole tape when it fits;
    /// the chunk length with the smallest peak when nothing fits.
    pub fn within(
        budget: usize,
        steps: usize,
        step_bytes: usize,
        state_bytes: usize,
        cut_every: usize,
    ) -> ChunkPlan {
        if steps.saturating_mul(step_bytes) <= budget {
            return ChunkPlan::WHOLE;
        }
        let need =
            |interval| ChunkPlan { interval }.peak_bytes(steps, step_bytes, state_bytes, cut_every);
        let interval = (1..steps)
            .rev()
            .find(|&i| need(i) <= budget)
            .unwrap_or_else(|| (1..steps).min_by_key(|&i| need(i)).unwrap_or(1));
        ChunkPlan { interval }
    }

    /// Peak tape bytes of a run under this plan (see [`ChunkPlan::within`]).
    pub fn peak_bytes(
        &self,
        steps: usize,
        step_bytes: usize,
        state_bytes: usize,
        cut_every: usize,
    ) -> usize {
        if self.interval >= steps {
            return steps * step_bytes;
        }
        let starts = (0..steps)
            .filter(|s| s % self.interval == 0 || s % cut_every.max(1) == 0)
            .count();
        // The longest chunk between two starts is at most `interval` steps.
        self.interval * step_bytes + starts * state_bytes
    }
}

/// One chunk of a run: its first global step, the state there, and its tape when kept.
#[derive(Clone, Debug)]
pub struct Chunk<T> {
    pub first_step: usize,
    pub start: State,
    pub tape: Option<T>,
}

/// A forward run recorded as chunks (see the module documentation).
#[derive(Clone, Debug)]
pub struct Checkpointed<T> {
    /// In step order; the first starts where the run started.
    pub chunks: Vec<Chunk<T>>,
    /// The state after the last step.
    pub last: State,
    /// The global step after the last one.
    pub end_step: usize,
}

impl<T: RunTape> Checkpointed<T> {
    /// The global step the run started at.
    pub fn first_step(&self) -> usize {
        self.chunks.first().map_or(self.end_step, |c| c.first_step)
    }

    /// The state at the start of global step `step`, when a chunk starts there.
    pub fn state_at(&self, step: usize) -> Option<&State> {
        if step == self.end_step {
            return Some(&self.last);
        }
        self.chunks
            .iter()
            .find(|c| c.first_step == step)
            .map(|c| &c.start)
    }

    /// Replaces the steps from global step `tail.first_step()` on (a chunk start of this
    /// run) by the run `tail`.
    pub fn splice(&mut self, tail: Checkpointed<T>) {
        let at = tail.first_step();
        debug_assert!(self.state_at(at).is_some(), "splice at a chunk start");
        self.chunks.retain(|c| c.first_step < at);
        // The chunk before the cut ends at `at` now, whatever it held: its tape (if any)
        // still describes the same steps, which did not change.
        self.chunks.extend(tail.chunks);
        self.last = tail.last;
        self.end_step = tail.end_step;
    }

    /// Drops every chunk, keeping the last state (what a result that is not reversed needs).
    pub fn into_last(self) -> State {
        self.last
    }
}

/// Runs `n_steps` steps from `state` (global steps `first_step..`) with `controls` (indexed
/// from `first_step`), cutting a chunk every `plan.interval` steps of the run and wherever
/// `cut(global_step)` says. Keeps every chunk's tape under [`ChunkPlan::WHOLE`], none
/// otherwise. `on_step(k, state)` sees the state after every global step `k`.
#[allow(clippy::too_many_arguments)]
pub fn record<I: Integrator>(
    sim: &I,
    mut state: State,
    controls: &StepControls,
    first_step: usize,
    n_steps: usize,
    plan: ChunkPlan,
    cut: &dyn Fn(usize) -> bool,
    on_step: &mut super::OnStep,
) -> Result<Checkpointed<I::Tape>, SimError> {
    // Chunk starts (local steps).
    let mut starts = vec![0];
    for s in 1..n_steps {
        if s % plan.interval == 0 || cut(first_step + s) {
            starts.push(s);
        }
    }
    let mut chunks = Vec::with_capacity(starts.len());
    for (i, &a) in starts.iter().enumerate() {
        let b = starts.get(i + 1).copied().unwrap_or(n_steps);
        let keep = plan == ChunkPlan::WHOLE;
        let mut tape = keep.then(I::Tape::default);
        let start = state.clone();
        let ctrl = controls.get(a..).unwrap_or(&[]);
        sim.forward_observed(
            &mut state,
            Controls::of_f(ctrl),
            Steps::new(first_step + a, b - a),
            tape.as_mut(),
            Some(on_step),
        )?;
        chunks.push(Chunk {
            first_step: first_step + a,
            start,
            tape,
        });
    }
    Ok(Checkpointed {
        chunks,
        last: state,
        end_step: first_step + n_steps,
    })
}

/// The reverse pass of `run` from its end down to global step `down_to` (a chunk start):
/// `controls` are the ones the forward pass used, indexed from global step `controls_from`
/// (at most `down_to`); `seed_after`, when given, seeds a cost on every state (see
/// [`Integrator::backward_seeded`]). Each chunk without a tape is re-run with one first.
/// `on_control(k, g)` receives dL/dFc of every controlled global step `k` as its chunk is
/// reversed, so that no more than one chunk's are held at once. Returns the gradients with
/// respect to the state at `down_to` (`initial`) and the effects' parameters (`controls` is
/// empty).
#[allow(clippy::too_many_arguments)]
pub fn reverse<I: Integrator>(
    sim: &I,
    run: &Checkpointed<I::Tape>,
    controls: &StepControls,
    controls_from: usize,
    down_to: usize,
    grad_last: StateGrad,
    mut seed_after: Option<&mut super::SeedAfter>,
    on_control: &mut dyn FnMut(usize, Vec<nalgebra::Matrix3<f64>>),
) -> Result<Gradients, SimError> {
    debug_assert!(controls_from <= down_to && run.state_at(down_to).is_some());
    let mut adj = grad_last;
    let mut effect_params: Option<Vec<Vec<f64>>> = None;
    let mut end = run.end_step;
    for chunk in run.chunks.iter().rev() {
        if chunk.first_step < down_to {
            break;
        }
        let ctrl = controls
            .get(chunk.first_step - controls_from..end - controls_from)
            .unwrap_or(&[]);
        let recomputed;
        let tape = match &chunk.tape {
            Some(t) => t,
            None => {
                let mut t = I::Tape::default();
                let mut s = chunk.start.clone();
                sim.forward(
                    &mut s,
                    ctrl,
                    chunk.first_step,
                    end - chunk.first_step,
                    Some(&mut t),
                )?;
                recomputed = t;
                &recomputed
            }
        };
        let g = match seed_after.as_deref_mut() {
            Some(seed) => sim.backward_seeded(tape, Controls::of_f(ctrl), adj, seed),
            None => sim.backward(tape, ctrl, adj),
        };
        adj = g.initial;
        for (k, grad) in g.controls.into_iter().enumerate() {
            if let Some(grad) = grad {
                on_control(chunk.first_step + k, grad);
            }
        }
        match &mut effect_params {
            None => effect_params = Some(g.effect_params),
            Some(acc) => {
                for (a, e) in acc.iter_mut().zip(&g.effect_params) {
                    for (a, b) in a.iter_mut().zip(e) {
                        *a += b;
                    }
                }
            }
        }
        end = chunk.first_step;
    }
    Ok(Gradients {
        initial: adj,
        controls: Vec::new(),
        effect_params: effect_params.unwrap_or_default(),
        knots: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_keeps_the_whole_tape_when_it_fits() {
        assert_eq!(ChunkPlan::within(300, 30, 10, 5, 30), ChunkPlan::WHOLE);
        let p = ChunkPlan::within(299, 30, 10, 5, 30);
        assert!(p.interval < 30);
        assert!(p.peak_bytes(30, 10, 5, 30) <= 299);
    }

    #[test]
    fn plan_picks_the_longest_chunk_in_the_budget() {
        // 30 steps of 10 bytes, states of 5: interval i needs 10 i + 5 ceil(30 / i).
        let p = ChunkPlan::within(150, 30, 10, 5, 30);
        assert_eq!(p.interval, 13); // 130 + 15 = 145; 14 gives 140 + 15
        // Restart points every 10 steps add starts at 10 and 20.
        assert_eq!(
            ChunkPlan { interval: 12 }.peak_bytes(30, 10, 5, 10),
            120 + 5 * 5
        );
        // Nothing fits: the smallest peak, 10 i + 5 ceil(30 / i), is 80 at i = 3, 4 and 5;
        // the shortest chunk comes first.
        assert_eq!(ChunkPlan::within(1, 30, 10, 5, 30).interval, 3);
    }
}
