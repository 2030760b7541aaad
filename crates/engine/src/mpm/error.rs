//! Typed simulation errors: every failure names the step and the particle.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum SimError {
    #[error(
        "step {step}: particle {particle} at ({:.4}, {:.4}, {:.4}) is outside the grid (its kernel stencil leaves the domain); enlarge the domain or reduce the motion",
        position[0], position[1], position[2]
    )]
    OutsideGrid {
        step: usize,
        particle: usize,
        position: [f64; 3],
    },

    #[error("step {step}: particle {particle} has a non-finite {field}")]
    NonFinite {
        step: usize,
        particle: usize,
        field: &'static str,
    },

    #[error(
        "time step {dt:.4e} s exceeds the stable bound {limit:.4e} s (elastic wave speed {wave_speed:.4e} over dx {dx:.4e}); use dt <= {limit:.4e}"
    )]
    UnstableTimeStep {
        dt: f64,
        limit: f64,
        wave_speed: f64,
        dx: f64,
    },

    #[error(
        "step {step}: particle {particle} moved {cells:.3} cells in one step (CFL limit {limit}); the simulation is unstable, reduce dt or the controls"
    )]
    CflExceeded {
        step: usize,
        particle: usize,
        cells: f64,
        limit: f64,
    },

    #[error(
        "step {step}: particle {particle}'s control factor I + Fc has determinant {det:.3e}; a rest-shape control must keep it positive"
    )]
    DegenerateControl {
        step: usize,
        particle: usize,
        det: f64,
    },

    #[error(
        "step {step}: particle {particle} is turned inside out (J = {j:.3e}); reduce the controls"
    )]
    Inverted {
        step: usize,
        particle: usize,
        j: f64,
    },

    #[error("invalid scene: {0}")]
    InvalidScene(String),
}
