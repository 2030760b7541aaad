//! A taped run on the device: every state it went through stays in device memory (each one
//! written once and then only read, so tapes share them), the last one also on the host.

use crate::device::Device;
use crate::precision::Precision;
use morph_engine::integrator::RunTape;
use morph_engine::mpm::State;
use nalgebra::Vector3;
use std::borrow::Cow;
use std::sync::Arc;

#[derive(Clone, Default)]
pub struct GpuTape {
    dev: Option<Arc<Device>>,
    precision: Precision,
    /// The global step the run started at.
    pub first_step: usize,
    /// The states, the first one included (`len() + 1` of them once started).
    states: Vec<Arc<wgpu::Buffer>>,
    pub last: State,
}

impl GpuTape {
    /// A new record from `first`, the state at global step `first_step`.
    pub(crate) fn start(
        &mut self,
        dev: &Arc<Device>,
        precision: Precision,
        first_step: usize,
        first: wgpu::Buffer,
    ) {
        self.dev = Some(dev.clone());
        self.precision = precision;
        self.first_step = first_step;
        self.states = vec![Arc::new(first)];
    }

    pub(crate) fn push(&mut self, state: wgpu::Buffer) {
        self.states.push(Arc::new(state));
    }

    /// The device buffer of the state at the start of recorded step `k`.
    pub(crate) fn state(&self, k: usize) -> &wgpu::Buffer {
        &self.states[k]
    }

    /// The state at the start of recorded step `k`, read back (`len()`: the last, at hand).
    pub(crate) fn state_on_host(&self, k: usize) -> State {
        if k == self.len() {
            return self.last.clone();
        }
        let dev = self.dev.as_ref().expect("a started tape has its device");
        let n = self.last.len();
        let stride = crate::euler::STATE_STRIDE;
        let bytes = dev.read_bytes(&self.states[k], stride * n * self.precision.bytes());
        let raw = self.precision.decode(&bytes);
        let mut s = State::at_rest(vec![Vector3::zeros(); n]);
        crate::euler::unpack(&raw, &mut s);
        s
    }
}

impl RunTape for GpuTape {
    fn len(&self) -> usize {
        self.states.len().saturating_sub(1)
    }

    fn state_at(&self, k: usize) -> Cow<'_, State> {
        match k == self.len() {
            true => Cow::Borrowed(&self.last),
            false => Cow::Owned(self.state_on_host(k)),
        }
    }

    fn last(&self) -> &State {
        &self.last
    }

    fn split_off(&mut self, k: usize) -> Self {
        let tail = GpuTape {
            dev: self.dev.clone(),
            precision: self.precision,
            first_step: self.first_step + k,
            states: self.states[k..].to_vec(),
            last: std::mem::take(&mut self.last),
        };
        self.states.truncate(k + 1);
        self.last = tail.state_on_host(0);
        tail
    }

    fn append(&mut self, tail: Self) {
        self.states.pop();
        self.states.extend(tail.states);
        self.last = tail.last;
    }

    /// Device bytes (the states) and the last state's on the host.
    fn bytes(&self) -> usize {
        let n = self.last.len();
        let per_particle = crate::euler::STATE_STRIDE * self.precision.bytes();
        self.states.len() * per_particle * n + self.last.bytes()
    }
}
