//! morph's engine on a GPU, through wgpu: the symplectic-Euler step of the CPU engine's
//! model (`morph-engine`) in WGSL compute shaders, in f64, every transfer a gather in a fixed
//! order so that one device gives the same bits every time. What runs here so far is the
//! forward step (docs/engine.md, "The GPU device").

pub mod device;
pub mod euler;

pub use device::{Device, DeviceError, DeviceKind};
pub use euler::{GpuEuler, unsupported};
