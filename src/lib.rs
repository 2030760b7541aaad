//! morph: shape morphing with a differentiable Material Point Method.
//!
//! Layout: [`material`] (constitutive models, 3x3 SVD), [`mpm`] (the engine: one file per
//! stage, forward and reverse side by side), [`effects`] (optional physics a scene switches
//! on), [`scene`] (serde scene description), [`loss`] (nodal mass losses), [`bench`] (the
//! reference benchmark workload).

pub mod bench;
pub mod control;
pub mod effects;
pub mod geometry;
pub mod io;
pub mod loss;
pub mod material;
pub mod morph;
pub mod mpm;
pub mod ode;
pub mod scene;
