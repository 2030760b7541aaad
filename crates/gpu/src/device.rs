//! Opening a compute device through wgpu: the adapter, the features the engine needs (f64 in
//! shaders) and the limits it asks for, and what the adapter is (a GPU, or a software driver
//! such as Mesa's lavapipe, which counts as a device but is not a GPU).

use std::fmt;
use std::sync::{Arc, OnceLock};

/// Why no device could be opened: one line each, naming what is missing.
#[derive(Clone, Debug, PartialEq)]
pub enum DeviceError {
    /// No adapter at all (no Vulkan, Metal or DX12 driver answered).
    NoAdapter(String),
    /// The adapter has no 64-bit floats in shaders.
    NoF64 { adapter: String },
    /// The adapter has fewer storage buffers per shader stage than the step binds.
    Limits { adapter: String, what: String },
    /// The adapter refused the device.
    Refused { adapter: String, why: String },
}

impl fmt::Display for DeviceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DeviceError::NoAdapter(why) => write!(
                f,
                "no GPU adapter found ({why}); install a Vulkan, Metal or DX12 driver (on Linux without a GPU, Mesa's lavapipe: Debian package mesa-vulkan-drivers), or use --device cpu"
            ),
            DeviceError::NoF64 { adapter } => write!(
                f,
                "the GPU adapter '{adapter}' has no 64-bit floats in shaders (SHADER_F64), which the f64 step needs; use --precision f32"
            ),
            DeviceError::Limits { adapter, what } => {
                write!(f, "the GPU adapter '{adapter}' is too small: {what}")
            }
            DeviceError::Refused { adapter, why } => {
                write!(f, "the GPU adapter '{adapter}' refused a device: {why}")
            }
        }
    }
}

impl std::error::Error for DeviceError {}

/// Storage buffers the step and its reverse bind.
pub const STORAGE_BUFFERS: u32 = 16;

/// An open compute device.
pub struct Device {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// The adapter's name and driver, as the summary reports it.
    pub name: String,
    /// Whether the adapter is a software driver on the CPU (lavapipe, WARP, SwiftShader).
    pub software: bool,
    /// Whether its shaders have 64-bit floats (`SHADER_F64`).
    pub has_f64: bool,
    pub limits: wgpu::Limits,
}

impl Device {
    /// The process's device, opened on first use (an adapter is opened once: later calls get
    /// the same device, or the same error).
    pub fn shared() -> Result<Arc<Device>, DeviceError> {
        static SHARED: OnceLock<Result<Arc<Device>, DeviceError>> = OnceLock::new();
        SHARED.get_or_init(|| Device::open().map(Arc::new)).clone()
    }

    /// The first high-performance adapter.
    pub fn open() -> Result<Device, DeviceError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::PRIMARY,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            ..Default::default()
        };
        let adapter = pollster::block_on(instance.request_adapter(&options))
            .map_err(|e| DeviceError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let name = format!("{} ({:?}, {})", info.name, info.backend, info.driver);
        let has_f64 = adapter.features().contains(wgpu::Features::SHADER_F64);
        let have = adapter.limits();
        if have.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS {
            return Err(DeviceError::Limits {
                adapter: name,
                what: format!(
                    "{} storage buffers per shader stage, the step binds {STORAGE_BUFFERS}",
                    have.max_storage_buffers_per_shader_stage
                ),
            });
        }
        // Ask for what the adapter has: the buffers grow with the particles and the grid.
        let limits = wgpu::Limits {
            max_storage_buffers_per_shader_stage: STORAGE_BUFFERS,
            max_storage_buffer_binding_size: have.max_storage_buffer_binding_size,
            max_buffer_size: have.max_buffer_size,
            max_compute_workgroups_per_dimension: have.max_compute_workgroups_per_dimension,
            ..wgpu::Limits::default()
        };
        let desc = wgpu::DeviceDescriptor {
            label: Some("morph"),
            required_features: match has_f64 {
                true => wgpu::Features::SHADER_F64,
                false => wgpu::Features::empty(),
            },
            required_limits: limits.clone(),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc)).map_err(|e| {
            DeviceError::Refused {
                adapter: name.clone(),
                why: e.to_string(),
            }
        })?;
        Ok(Device {
            device,
            queue,
            name,
            software: info.device_type == wgpu::DeviceType::Cpu,
            has_f64,
            limits,
        })
    }
}

impl Device {
    /// Copies `count` values of `buf` back to the host.
    pub fn read<T: bytemuck::Pod>(&self, buf: &wgpu::Buffer, count: usize) -> Vec<T> {
        bytemuck::pod_collect_to_vec(&self.read_bytes(buf, count * std::mem::size_of::<T>()))
    }

    /// Copies the first `bytes` bytes of `buf` back to the host.
    pub fn read_bytes(&self, buf: &wgpu::Buffer, bytes: usize) -> Vec<u8> {
        let bytes = bytes as u64;
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buf, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        let slice = staging.slice(..);
        slice.map_async(wgpu::MapMode::Read, |r| r.expect("a device buffer maps"));
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .expect("the device finishes its work");
        let view = slice.get_mapped_range().expect("a mapped buffer's range");
        view.to_vec()
    }
}

/// Where the engine runs (`--device`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceKind {
    /// The CPU engine (`morph-engine`).
    #[default]
    Cpu,
    /// A GPU (or a software Vulkan driver), or an error saying what is missing.
    Gpu,
    /// A GPU (not a software driver) where one opens, else the CPU.
    Auto,
}

impl DeviceKind {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [DeviceKind; 3] = [DeviceKind::Cpu, DeviceKind::Gpu, DeviceKind::Auto];
}
