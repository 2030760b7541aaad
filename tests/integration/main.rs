//! The integration tests, one binary: each module was a test binary of its own, and each
//! linked the whole crate and its dependencies (17 links of ~5 s each on 2 cores, and every
//! module's tests waited for the slowest of its own before the next started). Filter by
//! module: `cargo test --release --test integration safety::`.

mod common;

mod determinism;
mod docs;
mod end_to_end;
mod energy;
mod errors;
mod fuzz;
mod geometry;
mod gpu;
mod gradients;
mod hard_cases;
mod library;
mod motion;
mod ode;
mod physics;
mod rope;
mod safety;
mod scenes;
mod study;
mod surfaces;
mod thin_parts;
