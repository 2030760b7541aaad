//! Effects: the optional physics a scene switches on. A scene pays only for the effects it
//! lists; the step itself knows none of them.
//!
//! Both integrators run the same effects. For the symplectic-Euler step an effect acts at one
//! of two hook points, each with its reverse pass beside it:
//! - on particle momentum before P2G (drag: `m v -> (1 - dt drag) m v`);
//! - on grid velocities after `v_i = p_i / m_i` (gravity, colliders, walls).
//!
//! For the ODE form (RK4) an effect states its part of the grid rates instead: at each node
//! with mass it may change the velocity `v_i` and the acceleration `a_i` (gravity `a += g`,
//! drag `a -= c v`, walls project both). Effects run in list order; the reverse passes run
//! them backwards, each given what it saw as input. The context carries the step and the
//! time, so an effect may change over time; the tapes record the step.
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
pub use crate::mpm::effect::{Effect, GridContext};
