//! morph's engine: a differentiable MLS-MPM with a hand-written reverse pass for every stage.
//!
//! It knows nothing of meshes, morphs or files: what it needs of a shape (a collider's solid)
//! comes in through the [`effects::Solid`] trait the layer above implements.
//!
//! Layout, bottom up:
//! - [`lanes`]: vector lanes, the same per-particle arithmetic on many particles at once, run
//!   with the widest instruction set the CPU has and the bits of the scalar code;
//! - [`material`]: constitutive models behind a trait, the 3x3 SVD, the stress differential;
//! - [`mpm`]: the model, the state, the kernels and transfers, and symplectic-Euler MLS-MPM
//!   with a tape: one file per stage, forward and reverse side by side;
//! - [`effects`]: optional physics a scene switches on (drag, gravity, walls, colliders), run
//!   by both integrators;
//! - [`ode`]: the same physics as an ODE `dS/dt = f(S, u, t)` with RK4 and its reverse, and
//!   controls (body forces, prescribed clamp position or velocity);
//! - [`integrator`]: the [`integrator::Integrator`] trait both integrators implement, and
//!   [`Engine`], the one a run chose;
//! - [`scene`]: the serde scene description that builds a model.

pub mod effects;
mod engine;
pub mod integrator;
pub mod lanes;
pub mod material;
pub mod mpm;
pub mod ode;
pub mod scene;

pub use engine::{Engine, with_integrator};
