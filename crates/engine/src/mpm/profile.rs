//! Wall time per stage of the Euler step and its reverse pass, summed over the steps a
//! [`super::Euler`] runs while a [`StageClock`] is attached (`morph bench` reads it for
//! the per-stage table and the roofline). Without a clock the step takes no timings.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// The stages timed, forward then reverse.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Sorting particles into blocks.
    Bins,
    /// P1: control, stress (batched SVDs), affine momentum.
    Stress,
    /// P2G: the tiled scatter of mass and momentum.
    P2g,
    /// G: grid velocity, grid effects, clamps.
    Grid,
    /// Copying what the reverse pass needs into the tape.
    Tape,
    /// G2P and P2: the gather and the particle update.
    G2p,
    /// Reverse set-up: the elastic gradients and the grid effects replayed.
    RevSetup,
    /// Reverse of P2 and G2P: the tiled scatter of the grid velocity adjoint.
    RevG2p,
    /// Reverse of G: effects backwards, then `v = p / m`.
    RevGrid,
    /// Reverse of P2G and P1: the gather of node adjoints and the stress differential.
    RevP2gStress,
}

impl Stage {
    pub const ALL: [Stage; 10] = [
        Stage::Bins,
        Stage::Stress,
        Stage::P2g,
        Stage::Grid,
        Stage::Tape,
        Stage::G2p,
        Stage::RevSetup,
        Stage::RevG2p,
        Stage::RevGrid,
        Stage::RevP2gStress,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Bins => "bins",
            Stage::Stress => "stress",
            Stage::P2g => "p2g",
            Stage::Grid => "grid",
            Stage::Tape => "tape",
            Stage::G2p => "g2p",
            Stage::RevSetup => "rev_setup",
            Stage::RevG2p => "rev_g2p",
            Stage::RevGrid => "rev_grid",
            Stage::RevP2gStress => "rev_p2g_stress",
        }
    }
}

/// Nanoseconds spent per stage (shared: the clock is read while no step runs).
#[derive(Debug, Default)]
pub struct StageClock {
    nanos: [AtomicU64; Stage::ALL.len()],
}

impl StageClock {
    pub fn add(&self, stage: Stage, nanos: u64) {
        self.nanos[stage as usize].fetch_add(nanos, Ordering::Relaxed);
    }

    /// Seconds per stage so far, in [`Stage::ALL`] order.
    pub fn seconds(&self) -> Vec<(Stage, f64)> {
        Stage::ALL
            .iter()
            .map(|&s| {
                (
                    s,
                    self.nanos[s as usize].load(Ordering::Relaxed) as f64 * 1e-9,
                )
            })
            .collect()
    }

    pub fn reset(&self) {
        for n in &self.nanos {
            n.store(0, Ordering::Relaxed);
        }
    }
}

/// A stopwatch over consecutive stages: `lap(stage)` charges the time since the last lap to
/// `stage`. Does nothing without a clock.
pub struct Laps<'a> {
    clock: Option<&'a StageClock>,
    since: Option<Instant>,
}

impl<'a> Laps<'a> {
    pub fn start(clock: Option<&'a StageClock>) -> Self {
        Laps {
            clock,
            since: clock.map(|_| Instant::now()),
        }
    }

    #[inline]
    pub fn lap(&mut self, stage: Stage) {
        if let (Some(clock), Some(since)) = (self.clock, self.since) {
            let now = Instant::now();
            clock.add(stage, (now - since).as_nanos() as u64);
            self.since = Some(now);
        }
    }
}
