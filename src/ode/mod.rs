//! The ODE form of the simulator, `dS/dt = f(S, u, t)` on S = {x, v, F}, integrated with
//! classic RK4, with controls (body forces, prescribed boundary velocities) and a reverse pass
//! for every part: [`rhs`] (the right-hand side and its vector-Jacobian product, built on
//! [`crate::mpm::transfer`]), [`rk4`] (the integrator and its reverse), [`controls`] (control effects and
//! their schedules), [`rollout`] (multi-step runs with a kinetic-energy cost and its gradient).

pub mod controls;
pub mod rhs;
pub mod rk4;
pub mod rollout;
pub mod state;

pub use controls::{
    ControlEffect, ControlKind, ControlParams, ControlPlan, Interpolation, Schedule,
};
pub use rhs::{At, OdeSystem};
pub use rk4::Rk4Tape;
pub use state::OdeState;
