//! The ODE form of the simulator, `dS/dt = f(S, u, t)` on S = {x, v, F}, integrated with
//! classic RK4, with controls (body forces, prescribed boundary velocities) and a reverse pass
//! for every part: [`rhs`] (the right-hand side and its vector-Jacobian product, built on
//! [`crate::mpm::transfer`]), [`rk4`] (the integrator and its reverse), [`rollout`] (multi-step
//! runs with a kinetic-energy cost and its gradient). The controls (body forces, prescribed
//! boundary velocities) are the model's, in [`crate::mpm::boundary`], shared with the Euler step.

pub mod rhs;
pub mod rk4;
pub mod rollout;

pub use rhs::{At, Rk4};
pub use rk4::Rk4Tape;
