//! The integrator a run chose: symplectic Euler (`mpm`) or RK4 (`ode`), over one `Model`.
//! Code written once for both takes the `Integrator` trait and is called through
//! [`with_integrator!`].

use crate::integrator::IntegratorKind;
use crate::lanes::SimdLevel;
use crate::mpm::model::Model;
use crate::mpm::{Euler, SimError};
use crate::ode::Rk4;

/// The integrator a run uses, chosen at run time.
#[derive(Debug)]
pub enum Engine {
    Euler(Euler),
    Rk4(Rk4),
}

impl Engine {
    /// `model` advanced by the integrator `kind`.
    pub fn new(model: Model, kind: IntegratorKind) -> Result<Engine, SimError> {
        Ok(match kind {
            IntegratorKind::Euler => Engine::Euler(Euler::from(model)),
            IntegratorKind::Rk4 => Engine::Rk4(Rk4::new(model)?),
        })
    }

    pub fn kind(&self) -> IntegratorKind {
        match self {
            Engine::Euler(_) => IntegratorKind::Euler,
            Engine::Rk4(_) => IntegratorKind::Rk4,
        }
    }

    /// The engine running its lane kernels at `simd` (the bits do not change, the speed
    /// does: [`crate::lanes`]).
    pub fn with_simd(mut self, simd: SimdLevel) -> Engine {
        match &mut self {
            Engine::Euler(s) => s.model.simd = simd,
            Engine::Rk4(s) => s.model.simd = simd,
        }
        self
    }

    /// The model, given back by its integrator.
    pub fn into_model(self) -> Model {
        match self {
            Engine::Euler(s) => s.model,
            Engine::Rk4(s) => s.model,
        }
    }

    pub fn model(&self) -> &Model {
        match self {
            Engine::Euler(s) => &s.model,
            Engine::Rk4(s) => &s.model,
        }
    }
}

/// Runs `$body` with `$i` bound to the engine's integrator (a generic call site written once).
#[doc(hidden)]
#[macro_export]
macro_rules! __with_integrator {
    ($engine:expr, $i:ident => $body:expr) => {
        match $engine {
            $crate::Engine::Euler($i) => $body,
            $crate::Engine::Rk4($i) => $body,
        }
    };
}

/// Runs `$body` with `$i` bound to the engine's integrator (a generic call site written once):
/// `with_integrator!(&engine, sim => sim.forward(...))`.
pub use crate::__with_integrator as with_integrator;
