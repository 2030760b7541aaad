//! How much memory a morph may use, and how its segments' tapes fit in it.
//!
//! The tape of a segment's rollout is what grows with steps x particles; everything else (the
//! model, the loss grids, the controls of every segment, the optimizer's moments, a few
//! states) is fixed by the particle count. A [`MemoryLimit`] caps the whole process: what is
//! left after the fixed part is the tape budget, and the segment keeps checkpoints and
//! recomputes instead of holding every step when its tape would not fit
//! ([`crate::integrator::recompute`]). The budget never changes results, only memory and time.

use super::{MorphError, Prepared};
use crate::integrator::Integrator;
use crate::integrator::recompute::ChunkPlan;
use crate::mpm::State;
use nalgebra::Matrix3;
use serde::Serialize;
use std::str::FromStr;

/// A cap on the process's peak memory.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MemoryLimit {
    /// A quarter of the machine's physical memory (farm nodes run several jobs), or
    /// [`FALLBACK_AUTO_BYTES`] where it cannot be read.
    #[default]
    Auto,
    Bytes(u64),
}

/// Memory the allocator holds beyond the tapes it was asked for, as a share of them: tapes
/// of tens of megabytes a step, freed and recomputed chunk after chunk, fragment the heap
/// (measured: 9% of the planned tape at 321,189 particles with glibc's allocator).
pub const ALLOCATOR_SLACK: f64 = 0.10;

/// The automatic limit where the machine's memory cannot be read.
pub const FALLBACK_AUTO_BYTES: u64 = 2 << 30;

impl FromStr for MemoryLimit {
    type Err = String;

    /// `auto`, or a size: a number with an optional unit `K`, `M`, `G` or `T` (powers of
    /// 1024; `KB`, `MiB`... read the same), e.g. `150M`, `1.5G`, `4000000000`.
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("auto") {
            return Ok(MemoryLimit::Auto);
        }
        let split = t
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(t.len());
        let (number, unit) = t.split_at(split);
        let scale: u64 = match unit.trim().to_ascii_uppercase().as_str() {
            "" | "B" => 1,
            "K" | "KB" | "KIB" => 1 << 10,
            "M" | "MB" | "MIB" => 1 << 20,
            "G" | "GB" | "GIB" => 1 << 30,
            "T" | "TB" | "TIB" => 1 << 40,
            _ => return Err(format!("'{s}' is not a size: use e.g. 150M, 4G or auto")),
        };
        match number.parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 => Ok(MemoryLimit::Bytes((v * scale as f64) as u64)),
            _ => Err(format!("'{s}' is not a size: use e.g. 150M, 4G or auto")),
        }
    }
}

impl MemoryLimit {
    /// The limit in bytes.
    pub fn bytes(self) -> u64 {
        match self {
            MemoryLimit::Bytes(b) => b,
            MemoryLimit::Auto => physical_memory().map_or(FALLBACK_AUTO_BYTES, |m| m / 4),
        }
    }
}

/// How a morph's memory is planned (written to the manifest).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct MemoryPlan {
    /// The cap, in bytes.
    pub limit: u64,
    /// Estimated bytes of everything but the tapes.
    pub fixed: u64,
    /// Bytes the tape of one rollout may hold.
    pub tape_budget: u64,
    /// Steps per recomputed chunk (`null`: the whole tape is kept, nothing recomputed).
    pub chunk_steps: Option<usize>,
    /// Estimated peak bytes of the tapes under this plan.
    pub tape_peak: u64,
    /// Bytes one step's tape holds.
    pub step_tape_bytes: u64,
}

impl Prepared {
    /// Plans the tapes of this morph within `limit` and sets [`Prepared::tape_budget`]. A
    /// limit below what the morph needs with one-step chunks is an error that says how much
    /// it needs.
    pub fn plan_memory(&mut self, limit: MemoryLimit) -> Result<MemoryPlan, MorphError> {
        let n = self.initial.len();
        let state = State::bytes_for(n);
        let step = crate::with_integrator!(&self.engine, sim => sim.tape_bytes_per_step(n));
        let steps = self.max_sim_segment_steps();
        let fixed = resident_bytes().unwrap_or(0) + self.working_bytes();
        let limit_bytes = limit.bytes();
        let tape_budget =
            (limit_bytes.saturating_sub(fixed) as f64 / (1.0 + ALLOCATOR_SLACK)) as usize;
        let stride = self.sim_control_stride();
        let plan = self.chunk_plan_within(tape_budget);
        let peak = plan.peak_bytes(steps, step, state, stride);
        if peak > tape_budget {
            let need = fixed as f64 + peak as f64 * (1.0 + ALLOCATOR_SLACK);
            return Err(MorphError::Settings(format!(
                "--memory-limit {} is below the {} this morph needs at least ({n} particles); raise it, or lower --resolution or --particles",
                show_bytes(limit_bytes),
                show_bytes((need as u64).div_ceil(1 << 20) * (1 << 20)),
            )));
        }
        self.tape_budget = tape_budget;
        Ok(MemoryPlan {
            limit: limit_bytes,
            fixed,
            tape_budget: tape_budget as u64,
            chunk_steps: (plan != ChunkPlan::WHOLE).then_some(plan.interval),
            tape_peak: peak as u64,
            step_tape_bytes: step as u64,
        })
    }

    /// How each segment's rollout is cut into chunks under [`Prepared::tape_budget`] (what
    /// [`crate::morph::segment::Segment::chunk_plan`] decides for this morph's segments).
    pub fn segment_chunk_plan(&self) -> ChunkPlan {
        self.chunk_plan_within(self.tape_budget)
    }

    fn chunk_plan_within(&self, budget: usize) -> ChunkPlan {
        let n = self.initial.len();
        let step = crate::with_integrator!(&self.engine, sim => sim.tape_bytes_per_step(n));
        ChunkPlan::within(
            budget,
            self.max_sim_segment_steps(),
            step,
            State::bytes_for(n),
            self.sim_control_stride(),
        )
    }

    /// Estimated bytes the run needs besides the tapes and what is allocated already: the
    /// controls of the passes before the last (kept for the next) and the optimizer's copies
    /// of one segment's, Adam's moments and saved values, and the states a segment holds at
    /// once (start, the one advancing, last, best, adjoints, the reverse step's scratch).
    fn working_bytes(&self) -> u64 {
        let s = &self.settings;
        let n = self.initial.len();
        let layers = self.segment_layers().into_iter().max().unwrap_or(0);
        let layer = n * size_of::<Matrix3<f64>>();
        let kept = if s.passes > 1 { s.segments } else { 0 };
        let controls = (kept + 6) * layers * layer;
        let free = layers * 9 * n;
        let adam = 5 * free * size_of::<f64>();
        (controls + adam + 6 * State::bytes_for(n)) as u64
    }
}

/// A size as people read it: `150 MB`, `4.0 GB` (powers of 1024).
pub fn show_bytes(b: u64) -> String {
    let b = b as f64;
    if b >= (1u64 << 30) as f64 {
        format!("{:.1} GB", b / (1u64 << 30) as f64)
    } else {
        format!("{:.0} MB", b / (1u64 << 20) as f64)
    }
}

/// The process's resident memory now (Linux; `None` elsewhere). Read from `/proc` rather
/// than through a crate: one line of one file.
pub fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

/// The machine's physical memory (Linux; `None` elsewhere).
pub fn physical_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_units() {
        let b = |s: &str| s.parse::<MemoryLimit>().unwrap();
        assert_eq!(b("auto"), MemoryLimit::Auto);
        assert_eq!(b("150M"), MemoryLimit::Bytes(150 << 20));
        assert_eq!(b("4G"), MemoryLimit::Bytes(4 << 30));
        assert_eq!(b("1.5GB"), MemoryLimit::Bytes(3 << 29));
        assert_eq!(b("2048"), MemoryLimit::Bytes(2048));
        for bad in ["", "M", "-1G", "12Q", "0", "nan"] {
            assert!(bad.parse::<MemoryLimit>().is_err(), "{bad}");
        }
    }
}
