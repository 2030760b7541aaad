//! Effects: the optional physics a scene switches on. A scene pays only for the effects it
//! lists; the step itself knows none of them.
//!
//! Both integrators run the same effects, through one hook pair: at every grid node with mass
//! an effect changes the node's motion (`apply_grid`), with its reverse beside it
//! (`reverse_grid`). For the symplectic-Euler step the motion is the node's velocity for the
//! step, after `v_i = p_i / m_i` (gravity `v += dt g`, colliders and walls project it); for
//! the ODE form (RK4) it is the node's velocity and acceleration (gravity `a += g`, drag
//! `a -= c v`, walls project both). The context says which (`GridForm`). Drag under Euler acts
//! on particle momentum before P2G instead (`m v -> (1 - dt drag) m v`, the reference code's
//! form). Effects run in list order (`mpm::effect::GridEffects`, the one sequencing both
//! integrators call); the reverse runs them backwards, each given what it saw as input. The
//! context carries the step and the time, so an effect may change over time; the tapes record
//! the step.
//!
//! Effects may have differentiable parameters (gravity's vector, a control's forces): the
//! reverse pass accumulates their gradients into a slice of length [`Effect::num_params`].

pub mod collider;
mod drag;
mod gravity;
mod walls;

pub use collider::{Collider, ColliderShape};
pub use drag::Drag;
pub use gravity::Gravity;
pub use walls::{WallMode, Walls};

/// The interface, filed with the engine that calls it.
pub use crate::mpm::effect::{Effect, GridContext, GridForm, NodeMotion};
