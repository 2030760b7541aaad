//! morph's engine on a GPU, through wgpu: the symplectic-Euler step of the CPU engine's
//! model (`morph-engine`) in WGSL compute shaders, in f64, forward and reverse, every
//! transfer a gather in a fixed order so that one device gives the same bits every time. It
//! is one more `Integrator` (docs/engine.md, "The GPU device").

pub mod device;
pub mod euler;
mod integrator;
pub mod precision;
pub mod tape;

pub use device::{Device, DeviceError, DeviceKind};
pub use euler::{GpuEuler, unsupported};
pub use precision::Precision;
pub use tape::GpuTape;
