//! morph: shape morphing with a differentiable Material Point Method.
//!
//! Layout:
//! - [`material`]: constitutive models behind a trait, the 3x3 SVD, the stress differential;
//! - [`mpm`]: the engine, symplectic-Euler MLS-MPM with a tape: one file per stage, forward
//!   and reverse side by side;
//! - [`ode`]: the same physics as an ODE `dS/dt = f(S, u, t)` with RK4 and its reverse, and
//!   controls (body forces, prescribed clamp position or velocity);
//! - [`integrator`]: the [`integrator::Integrator`] trait both integrators implement, and
//!   [`engine::Engine`], the one a run chose;
//! - [`effects`]: optional physics a scene switches on (drag, gravity, walls), run by both
//!   integrators;
//! - [`scene`]: the serde scene description that builds a simulator;
//! - [`loss`]: nodal mass losses;
//! - [`geometry`]: meshes in (OBJ/PLY, validation, welding, winding-number voxelization,
//!   placement) and surfaces out;
//! - the morph itself at the crate root (its folder `src/morph/`, a private module whose
//!   items the root re-exports, so a caller writes `morph::Job`, `morph::settings::limits`,
//!   `morph::output::morph_to_folder`): the segment optimizers, the chained multi-pass
//!   driver with its [`Observer`], checkpoints, the output folder writer;
//! - [`apps`]: what is built on the engine besides the morph: the rope (control of deformable
//!   objects: gradient control, MPPI), `morph study` (what accuracy costs in time) and the
//!   benchmark workloads;
//! - [`io`]: frame, mass-grid and image files, and the guarded output folder;
//! - [`optim`]: Adam, shared by the morph and the gradient controller;
//! - [`lanes`]: vector lanes, the same per-particle arithmetic on many particles at once, run
//!   with the widest instruction set the CPU has and the bits of the scalar code.
//!
//! The `morph` binary (`src/cli/`, one file per subcommand) only parses and reports.
//!
//! A program drives a morph through [`run`]: a [`Job`] (source and target as files or meshes
//! in memory, and [`MorphSettings`]) and an [`Observer`] that receives events and frames in
//! world units and may cancel. `examples/library.rs` shows one.

pub mod apps;
pub use morph_engine as engine;
pub use morph_gpu as gpu;
pub mod files;
pub mod geometry;
pub mod io;
pub mod loss;
mod morph;
pub mod optim;

pub use morph::*;

/// Runs `job`: loads and places the meshes, optimizes the morph, and hands every event and
/// exported frame (world units) to `observer`, which may cancel it
/// ([`MorphError::Interrupted`]). Returns the prepared morph and its result.
pub fn run(job: &Job, observer: &mut dyn Observer) -> Result<(Prepared, MorphResult), MorphError> {
    job.run(observer)
}
