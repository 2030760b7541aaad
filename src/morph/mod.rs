//! The morph: a chain of segments, each optimized so the body flows toward the target,
//! refined over several passes (design.md section 4).
//!
//! A pass runs the segments in order, each starting from the full particle state where the
//! previous one ended. Later passes start every segment from the previous pass's controls
//! and re-optimize them from the (now different) state the chain reaches. Frames come from
//! the accepted rollouts of the last pass.

mod api;
pub mod basis;
mod chain;
pub mod checkpoint;
pub mod farm;
pub mod inbetween;
pub mod levels;
pub mod memory;
pub mod metrics;
pub mod motion;
pub mod output;
mod prepare;
pub mod progress;
pub mod quality;
pub mod reach;
pub mod scene_file;
pub mod segment;
pub mod settings;
pub mod sizing;
pub mod usage;

pub use api::*;
pub use chain::*;
pub use output::sinks::{self, FrameRecord, FrameSink, SinkFrame};
pub use prepare::*;
pub use settings::{CheckedSettings, MorphSettings, Preset};
