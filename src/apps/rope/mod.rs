//! Control of deformable objects with the ODE form: the rope scene ([`scene`]), the gradient
//! controller ([`gradient`], Adam over inner batches) and the MPPI baseline ([`mppi`]), and
//! the three-way comparison `morph rope` runs ([`compare`]).
//!
//! Both controllers are *online*: they plan a window starting at the current state, commit
//! its first steps, carry the state over and move on, so each committed step has a compute
//! time at which it was decided (the "energy against compute time" curves). Both use the same
//! control knots, bounds and cost (kinetic energy summed over steps, times dt).

pub mod compare;
pub mod gradient;
pub mod mppi;
pub mod scene;

use crate::engine::mpm::{ControlParams, ControlSchedule, Interpolation, State};
use serde::Serialize;
use std::ops::Range;
use std::time::Instant;

/// Knots a window of steps `[a, b)` may change without touching steps before `a`
/// (`a` and `b` on interval boundaries): a linear schedule's knot at `a` is shared with the
/// interval before it, so it stays frozen once that interval has been committed.
pub fn free_knots(schedule: &ControlSchedule, a: usize, b: usize) -> Range<usize> {
    let spi = schedule.steps_per_interval;
    let (ia, ib) = (a / spi, b.div_ceil(spi));
    match schedule.interpolation {
        Interpolation::Constant => ia..ib,
        Interpolation::Linear => (ia + usize::from(a > 0))..(ib + 1),
    }
}

/// A committed step of an online controller: when it was decided and its kinetic energy.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Committed {
    pub step: usize,
    pub compute_s: f64,
    pub energy: f64,
}

/// The result of an online controller.
#[derive(Clone, Debug)]
pub struct ControllerRun {
    pub params: ControlParams,
    /// Wall seconds spent deciding the controls.
    pub compute_s: f64,
    pub committed: Vec<Committed>,
    /// Cost of every evaluation, in order, with the compute time at which it finished.
    pub evaluations: Vec<(f64, f64)>,
    /// RK4 steps simulated (forward), a machine-independent measure of work.
    pub simulated_steps: usize,
}

/// What an online controller carries from window to window, the same for both: the control
/// knots, the state its committed steps reached, and the record [`ControllerRun`] reports.
/// Each controller plans a window its own way and hands the result here.
pub(crate) struct Online {
    started: Instant,
    pub params: ControlParams,
    pub state: State,
    committed: Vec<Committed>,
    evaluations: Vec<(f64, f64)>,
    /// RK4 steps simulated so far (each controller adds what it runs).
    pub simulated_steps: usize,
}

impl Online {
    /// A run of `total` steps from `init`, the knots at `params`; its compute clock starts.
    pub fn start(params: ControlParams, init: &State, total: usize) -> Online {
        Online {
            started: Instant::now(),
            params,
            state: init.clone(),
            committed: Vec::with_capacity(total),
            evaluations: Vec::new(),
            simulated_steps: 0,
        }
    }

    /// Seconds of compute since the start.
    pub fn seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Records an evaluation's cost, at the compute time it finished.
    pub fn evaluated(&mut self, cost: f64) {
        let now = self.seconds();
        self.evaluations.push((now, cost));
    }

    /// Commits the window's steps `first..` (their kinetic energies, the state already
    /// carried to their end) as decided now, and reports the window to `on_event`.
    pub fn commit(
        &mut self,
        method: &'static str,
        first: usize,
        energy: &[f64],
        total: usize,
        cost: f64,
        on_event: &mut impl FnMut(ControlEvent),
    ) {
        let now = self.seconds();
        self.committed
            .extend(energy.iter().enumerate().map(|(i, &e)| Committed {
                step: first + i,
                compute_s: now,
                energy: e,
            }));
        on_event(ControlEvent::Window {
            method,
            step: first + energy.len(),
            of: total,
            cost,
            compute_s: now,
        });
    }

    pub fn finish(self) -> ControllerRun {
        ControllerRun {
            compute_s: self.seconds(),
            params: self.params,
            committed: self.committed,
            evaluations: self.evaluations,
            simulated_steps: self.simulated_steps,
        }
    }
}

/// Progress reports of the controllers (for progress bars and `--json`).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum ControlEvent {
    /// A window was planned and its first steps committed.
    Window {
        method: &'static str,
        step: usize,
        of: usize,
        cost: f64,
        compute_s: f64,
    },
}
