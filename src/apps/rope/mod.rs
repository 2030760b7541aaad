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

use crate::mpm::{ControlSchedule, Interpolation};
use serde::Serialize;
use std::ops::Range;

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

/// Records steps `first..` of a window as committed at compute time `now`.
pub(crate) fn commit(out: &mut Vec<Committed>, first: usize, now: f64, energy: &[f64]) {
    out.extend(energy.iter().enumerate().map(|(i, &e)| Committed {
        step: first + i,
        compute_s: now,
        energy: e,
    }));
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
