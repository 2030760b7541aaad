//! The differentiable MLS-MPM engine.
//!
//! One step runs the stages P1 (stress) -> P2G -> G (grid velocity + effects) -> G2P -> P2
//! (particle update); the reverse pass runs their adjoints in the opposite order. Each stage
//! has its own file with the forward and reverse pass side by side; [`step`] strings them
//! together and records what the reverse pass needs.

pub mod advance;
pub mod boundary;
pub mod control;
pub mod effect;
pub mod error;
pub mod grid;
pub mod grid_update;
pub mod kernel;
pub mod model;
pub mod pipeline;
pub mod profile;
pub mod scratch;
pub mod stages;
pub mod state;
pub mod step;
pub mod stress;
pub mod transfer;

pub use boundary::{
    ControlEffect, ControlKind, ControlParams, ControlPlan, ControlSchedule, Interpolation,
};
pub use control::ControlForm;
pub use error::SimError;
pub use grid::GridSpec;
pub use kernel::KernelKind;
pub use state::{State, StateGrad};
pub use step::{Euler, Gradients, StepTape, Tape, Workspace};
