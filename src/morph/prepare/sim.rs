//! The integrator a morph runs: the CPU engine's (symplectic Euler or RK4) or the GPU
//! device's Euler step, all behind the engine's `Integrator` trait; code written once for
//! them is called through [`with_sim!`].

use crate::engine::Engine;
use crate::engine::integrator::IntegratorKind;
use crate::engine::mpm::model::Model;
use crate::gpu::{Device, DeviceKind, GpuEuler, Precision};
use crate::morph::api::MorphError;

/// Where a morph's steps run.
#[derive(Debug)]
pub enum Sim {
    Cpu(Engine),
    Gpu(GpuEuler),
}

impl Sim {
    /// `model` on `device` (see [`DeviceKind`]): `Gpu` fails saying what is missing, `Auto`
    /// takes a GPU (not a software driver) where one opens and runs this scene, else the CPU.
    pub fn new(
        model: Model,
        integrator: IntegratorKind,
        device: DeviceKind,
        precision: Precision,
    ) -> Result<Sim, MorphError> {
        let on_gpu = match device {
            DeviceKind::Cpu => false,
            DeviceKind::Gpu => {
                if let Some(why) = crate::gpu::unsupported(&model) {
                    return Err(MorphError::Device(format!(
                        "--device gpu: {why}; use --device cpu"
                    )));
                }
                true
            }
            // A software driver counts as a device when asked for, not as a GPU: the CPU
            // engine is faster than it.
            DeviceKind::Auto => {
                integrator == IntegratorKind::Euler
                    && crate::gpu::unsupported(&model).is_none()
                    && Device::shared().is_ok_and(|d| !d.software)
            }
        };
        if on_gpu {
            let dev = Device::shared().map_err(|e| MorphError::Device(e.to_string()))?;
            let gpu = GpuEuler::with_precision(dev, model, precision)
                .map_err(|e| MorphError::Device(format!("--device gpu: {e}")))?;
            return Ok(Sim::Gpu(gpu));
        }
        Ok(Sim::Cpu(Engine::new(model, integrator)?))
    }

    pub fn model(&self) -> &Model {
        match self {
            Sim::Cpu(e) => e.model(),
            Sim::Gpu(g) => &g.model,
        }
    }

    /// The GPU adapter the steps run on (none: the CPU).
    pub fn device_name(&self) -> Option<&str> {
        match self {
            Sim::Cpu(_) => None,
            Sim::Gpu(g) => Some(g.device().name.as_str()),
        }
    }
}

/// Runs `$body` with `$i` bound to the morph's integrator (a generic call site written once):
/// `with_sim!(&prep.engine, sim => sim.forward(...))`.
macro_rules! with_sim {
    ($sim:expr, $i:ident => $body:expr) => {
        match $sim {
            $crate::morph::prepare::sim::Sim::Cpu($crate::engine::Engine::Euler($i)) => $body,
            $crate::morph::prepare::sim::Sim::Cpu($crate::engine::Engine::Rk4($i)) => $body,
            $crate::morph::prepare::sim::Sim::Gpu($i) => $body,
        }
    };
}

pub(crate) use with_sim;
