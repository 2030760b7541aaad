//! The symplectic-Euler step on a device: the model's data in device buffers, one submission a
//! step of eight dispatches (clear, count, scan, place and sort the bins, stress, P2G with the
//! grid update, G2P; `step.wgsl`), the state read back at the end of a run. A taped run keeps
//! every state on the device; its reverse recomputes each step's bins, stress and grid from
//! the taped state and runs three more dispatches (`reverse.wgsl`).

use crate::device::{Device, DeviceError};
use crate::precision::Precision;
use crate::tape::GpuTape;
use morph_engine::effects::{Effect, GridForm, GridRule};
use morph_engine::integrator::{RunTape, StepControls};
use morph_engine::material::MaterialModel;
use morph_engine::mpm::model::Model;
use morph_engine::mpm::{ControlForm, Gradients, KernelKind, SimError, State, StateGrad};
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;
use wgpu::util::DeviceExt;

/// Numbers a particle's state takes in the state buffer: x, v, C, F.
pub(crate) const STATE_STRIDE: usize = 24;
/// Invocations per workgroup of the particle and node passes.
const WG: u32 = 64;
/// The entry points of `step.wgsl`, in the order a step dispatches them, then those of
/// `reverse.wgsl`.
const PASSES: [&str; 11] = [
    "clear_bins",
    "count_bins",
    "scan_bins",
    "place_bins",
    "sort_bins",
    "stress",
    "p2g",
    "g2p",
    "rev_advance",
    "rev_grid",
    "rev_particle",
];
/// Where the forward's recomputation ends in [`PASSES`] when a step is reversed (before G2P).
const RECOMPUTE: usize = 7;
/// Numbers per particle of the reverse's own buffer.
const RADJ_STRIDE: usize = 21;

/// Why the device cannot run a model.
pub fn unsupported(model: &Model) -> Option<String> {
    let (material, _, _) = model.material.spec();
    if material != MaterialModel::FixedCorotated {
        return Some(format!(
            "the GPU step runs the fixed-corotated material only, not {material:?}"
        ));
    }
    let on_grid: Vec<_> = grid_effects(model).collect();
    if let Some(e) = on_grid.iter().find(|e| e.grid_rule().is_none()) {
        return Some(format!(
            "the GPU step does not run the grid effect '{}' yet",
            e.name()
        ));
    }
    if on_grid.len() > RULES {
        return Some(format!(
            "the GPU step runs at most {RULES} grid effects, the scene has {}",
            on_grid.len()
        ));
    }
    if !model.controls().is_empty() {
        return Some("the GPU step does not run boundary controls yet".into());
    }
    None
}

/// Whether each of the step's largest buffers (what it holds, bytes) fits the adapter's limits
/// for one buffer bound to a shader: the error names the buffer, its size and the limit.
pub fn fits_on(
    adapter: &str,
    buffers: &[(&str, usize)],
    limits: &wgpu::Limits,
) -> Result<(), String> {
    let limit = u64::from(limits.max_storage_buffer_binding_size).min(limits.max_buffer_size);
    match buffers.iter().find(|(_, bytes)| *bytes as u64 > limit) {
        Some((what, bytes)) => Err(format!(
            "the GPU device ({adapter}) binds at most {:.0} MB a buffer, and {what} needs {:.0} MB: use fewer particles, a coarser grid, or --device cpu",
            limit as f64 / 1e6,
            *bytes as f64 / 1e6
        )),
        None => Ok(()),
    }
}

/// Grid effects the step applies, in the list's order (`step.wgsl`'s `RULES`).
const RULES: usize = 4;
/// Numbers a node takes in the grid buffer: mass, velocity after the effects and before.
const GRID_STRIDE: usize = 7;

/// The effects that act on the Euler step's grid, in list order.
fn grid_effects(model: &Model) -> impl Iterator<Item = &dyn Effect> {
    model
        .effects
        .iter()
        .map(|e| e.as_ref())
        .filter(|e| e.acts_on_grid(GridForm::Step))
}

/// The model's step on a device.
pub struct GpuEuler {
    pub(crate) dev: Arc<Device>,
    pub model: Model,
    pub precision: Precision,
    pipelines: Vec<wgpu::ComputePipeline>,
    bind_group: wgpu::BindGroup,
    iparams: wgpu::Buffer,
    fparams: wgpu::Buffer,
    state: wgpu::Buffer,
    ctrl: wgpu::Buffer,
    grid: wgpu::Buffer,
    status: wgpu::Buffer,
    post: wgpu::Buffer,
    adj: wgpu::Buffer,
    gctrl: wgpu::Buffer,
    node_count: usize,
}

fn storage(dev: &Device, label: &str, bytes: usize) -> wgpu::Buffer {
    dev.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(8) as u64,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// The bindings' layout (`step.wgsl`'s and `reverse.wgsl`'s, in binding order) and one
/// pipeline per entry of [`PASSES`].
fn pipelines(
    d: &wgpu::Device,
    precision: Precision,
) -> (wgpu::BindGroupLayout, Vec<wgpu::ComputePipeline>) {
    let module = d.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("step.wgsl"),
        source: wgpu::ShaderSource::Wgsl(precision.shader().into()),
    });
    let read_only = [
        true, true, false, true, true, false, false, false, false, false, false, true, false,
        false, false, false,
    ];
    let entries: Vec<_> = (0..read_only.len())
        .map(|b| layout_entry(b as u32, read_only[b]))
        .collect();
    let bgl = d.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("step"),
        entries: &entries,
    });
    let layout = d.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("step"),
        bind_group_layouts: &[Some(&bgl)],
        immediate_size: 0,
    });
    let pipelines = PASSES
        .iter()
        .map(|entry| {
            d.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        })
        .collect();
    (bgl, pipelines)
}

fn layout_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl std::ops::Deref for GpuEuler {
    type Target = Model;
    fn deref(&self) -> &Model {
        &self.model
    }
}

impl std::fmt::Debug for GpuEuler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GpuEuler on {}", self.dev.name)
    }
}

impl GpuEuler {
    /// The device the steps run on.
    pub fn device(&self) -> &Device {
        &self.dev
    }

    /// The model's constant data on `dev` and the step's pipelines.
    pub fn new(dev: Arc<Device>, model: Model) -> Result<GpuEuler, SimError> {
        GpuEuler::with_precision(dev, model, Precision::F64)
    }

    /// [`GpuEuler::new`] in `precision` (f64 needs the adapter's `SHADER_F64`).
    pub fn with_precision(
        dev: Arc<Device>,
        model: Model,
        precision: Precision,
    ) -> Result<GpuEuler, SimError> {
        if precision == Precision::F64 && !dev.has_f64 {
            let adapter = dev.name.clone();
            return Err(SimError::InvalidScene(
                DeviceError::NoF64 { adapter }.to_string(),
            ));
        }
        if let Some(why) = unsupported(&model) {
            return Err(SimError::InvalidScene(why));
        }
        let n = model.num_particles();
        let node_count = model.grid.node_count();
        let largest = [
            ("the particles' state", precision.bytes() * STATE_STRIDE * n),
            (
                "the particles' reverse",
                precision.bytes() * RADJ_STRIDE * n,
            ),
            ("the grid", precision.bytes() * GRID_STRIDE * node_count),
        ];
        fits_on(&dev.name, &largest, &dev.limits).map_err(SimError::InvalidScene)?;
        let d = &dev.device;
        let (bgl, pipelines) = pipelines(d, precision);
        let f64s = |k: usize| k * precision.bytes();
        let dev_ref = &*dev;
        let storage = |label: &str, bytes: usize| storage(dev_ref, label, bytes);
        let iparams = storage("iparams", 32);
        let fparams = storage("fparams", f64s(10 + 4 * RULES));
        let state = storage("state", f64s(STATE_STRIDE * n));
        let pm: Vec<f64> = (0..n)
            .flat_map(|p| [model.mass[p], model.volume[p]])
            .collect();
        let pm = d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("mass and volume"),
            contents: &precision.encode(&pm),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let ctrl = storage("controls", f64s(9 * n));
        let work = storage("work", f64s(18 * n));
        let grid = storage("grid", f64s(GRID_STRIDE * node_count));
        let counts = storage("counts", 4 * 2 * node_count);
        let starts = storage("starts", 4 * (node_count + 1));
        let list = storage("list", 4 * n);
        let status = storage("status", 16);
        let post = storage("post", f64s(STATE_STRIDE * n));
        let adj = storage("adjoint", f64s(STATE_STRIDE * n));
        let radj = storage("reverse", f64s(RADJ_STRIDE * n));
        let ggrid = storage("grid adjoint", f64s(4 * node_count));
        let gctrl = storage("control adjoint", f64s(9 * n));
        let buffers = [
            &iparams, &fparams, &state, &pm, &ctrl, &work, &grid, &counts, &starts, &list, &status,
            &post, &adj, &radj, &ggrid, &gctrl,
        ];
        let bind_entries: Vec<_> = buffers
            .iter()
            .enumerate()
            .map(|(b, buf)| wgpu::BindGroupEntry {
                binding: b as u32,
                resource: buf.as_entire_binding(),
            })
            .collect();
        let bind_group = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("step"),
            layout: &bgl,
            entries: &bind_entries,
        });
        Ok(GpuEuler {
            dev,
            model,
            precision,
            pipelines,
            bind_group,
            iparams,
            fparams,
            state,
            ctrl,
            grid,
            status,
            post,
            adj,
            gctrl,
            node_count,
        })
    }

    /// Runs `n_steps` steps from `state` (global steps `first_step..`) with per-step controls
    /// `Fc` (as the CPU engine's `Integrator::forward`), then reads the state back.
    pub fn forward(
        &self,
        state: &mut State,
        controls: &StepControls,
        first_step: usize,
        n_steps: usize,
    ) -> Result<(), SimError> {
        self.run(state, controls, first_step, n_steps, None, None)
    }

    /// [`GpuEuler::forward`], keeping every state on the device for [`GpuEuler::backward`].
    pub fn forward_taped(
        &self,
        state: &mut State,
        controls: &StepControls,
        first_step: usize,
        n_steps: usize,
    ) -> Result<GpuTape, SimError> {
        let mut tape = GpuTape::default();
        self.run(state, controls, first_step, n_steps, Some(&mut tape), None)?;
        Ok(tape)
    }

    /// The run behind both: with a tape, every state on the device; with `on_step`, the
    /// state read back after every step and shown to it.
    pub(crate) fn run(
        &self,
        state: &mut State,
        controls: &StepControls,
        first_step: usize,
        n_steps: usize,
        mut tape: Option<&mut GpuTape>,
        mut on_step: Option<&mut dyn FnMut(usize, &State)>,
    ) -> Result<(), SimError> {
        let model = &self.model;
        model.check_size(state.len())?;
        model.check_finite_and_cfl(state.first_non_finite(), &state.v, first_step)?;
        let q = &self.dev.queue;
        q.write_buffer(&self.state, 0, &self.precision.encode(&pack(state)));
        q.write_buffer(
            &self.status,
            0,
            bytemuck::cast_slice(&[0u32, u32::MAX, 0, u32::MAX]),
        );
        if let Some(t) = tape.as_deref_mut() {
            t.start(
                &self.dev,
                self.precision,
                first_step,
                self.copy_of(&self.state)?,
            );
        }
        for k in 0..n_steps {
            let step = first_step + k;
            let fc = controls.get(k).and_then(|c| c.as_deref());
            model.check_control(fc, step)?;
            let mode = self.upload_control(fc);
            self.upload_params(step, mode);
            self.submit(0..RECOMPUTE + 1, state.len());
            if let Some(t) = tape.as_deref_mut() {
                t.push(self.copy_of(&self.state)?);
            }
            if let Some(f) = on_step.as_deref_mut() {
                self.read_state(state)?;
                f(step, state);
            }
        }
        self.read_state(state)?;
        if let Some(t) = tape {
            t.last = state.clone();
        }
        Ok(())
    }

    /// The device's state into `state`, and the first error its steps flagged.
    fn read_state(&self, state: &mut State) -> Result<(), SimError> {
        let status: Vec<u32> = self.read(&self.status, 4);
        let out = self.read_reals(&self.state, STATE_STRIDE * state.len());
        unpack(&out, state);
        self.status_error(&status, state)
    }

    /// The first error the steps flagged (see `status` in `step.wgsl`), as the CPU engine
    /// names it: a stencil outside the grid in its step, or a state not finite or too fast
    /// at the start of the next step.
    fn status_error(&self, status: &[u32], state: &State) -> Result<(), SimError> {
        if status[0] != 0 {
            let p = status[1] as usize;
            return Err(SimError::OutsideGrid {
                step: status[0] as usize - 1,
                particle: p,
                position: state.x[p].into(),
            });
        }
        if status[2] != 0 {
            let (step, particle) = (status[2] as usize, status[3] as usize);
            if let Some((particle, field)) = state.first_non_finite() {
                return Err(SimError::NonFinite {
                    step,
                    particle,
                    field,
                });
            }
            let m = &self.model;
            return Err(SimError::CflExceeded {
                step,
                particle,
                cells: state.v[particle].norm() * m.dt / m.grid.dx,
                limit: m.max_cfl,
            });
        }
        Ok(())
    }

    /// The reverse of a taped run: `grad_last` is dL/d(the last state); `controls` are the
    /// forward's. dL/d(the first state) and dL/dFc of every step with a control, as the CPU
    /// engine's `Integrator::backward` gives them.
    pub fn backward(
        &self,
        tape: &GpuTape,
        controls: &StepControls,
        grad_last: &StateGrad,
    ) -> Gradients {
        self.backward_with(tape, controls, grad_last.clone(), None)
    }

    /// [`GpuEuler::backward`] with a cost on every state along the run: `seed_after(k,
    /// state, adj)` adds to `adj` the adjoint of the cost on the state after global step `k`
    /// before that step is reversed (the adjoint and the state then pass through the host).
    pub(crate) fn backward_with(
        &self,
        tape: &GpuTape,
        controls: &StepControls,
        grad_last: StateGrad,
        mut seed_after: Option<&mut dyn FnMut(usize, &State, &mut StateGrad)>,
    ) -> Gradients {
        let n = tape.last.len();
        let q = &self.dev.queue;
        let mut adj = grad_last;
        let mut grad_controls = vec![None; tape.len()];
        let mut on_device = false;
        for k in (0..tape.len()).rev() {
            let step = tape.first_step + k;
            if let Some(seed) = seed_after.as_deref_mut() {
                if on_device {
                    unpack_grad(&self.read_reals(&self.adj, STATE_STRIDE * n), &mut adj);
                }
                let post = tape.state_on_host(k + 1);
                seed(step, &post, &mut adj);
                on_device = false;
            }
            if !on_device {
                q.write_buffer(&self.adj, 0, &self.precision.encode(&pack_grad(&adj)));
                on_device = true;
            }
            let fc = controls.get(k).and_then(|c| c.as_deref());
            let mode = self.upload_control(fc);
            self.upload_params(step, mode);
            let mut enc = self.dev.device.create_command_encoder(&Default::default());
            let bytes = self.state.size();
            enc.copy_buffer_to_buffer(tape.state(k), 0, &self.state, 0, bytes);
            enc.copy_buffer_to_buffer(tape.state(k + 1), 0, &self.post, 0, bytes);
            q.submit([enc.finish()]);
            self.submit(0..RECOMPUTE, n);
            self.submit(RECOMPUTE + 1..PASSES.len(), n);
            if let Some(fc) = fc {
                let g_m = self.read_reals(&self.gctrl, 9 * n);
                grad_controls[k] = Some(self.control_gradient(fc, &g_m));
            }
        }
        if on_device {
            unpack_grad(&self.read_reals(&self.adj, STATE_STRIDE * n), &mut adj);
        }
        Gradients {
            initial: adj,
            controls: grad_controls,
            effect_params: self.model.zero_effect_params(),
            knots: Vec::new(),
        }
    }

    /// dL/dFc from the device's dL/dM (`F^T dL/dFe` for the plastic form, `dL/dFe` for the
    /// additive): the control form's own reverse, given `F = I` so that it takes `dL/dM` as
    /// it is.
    fn control_gradient(&self, fc: &[Matrix3<f64>], g_m: &[f64]) -> Vec<Matrix3<f64>> {
        let form = self.model.control_form;
        fc.iter()
            .zip(g_m.chunks(9))
            .map(|(fc, g)| {
                let g = Matrix3::from_column_slice(g);
                let scale = form.scale(fc);
                form.apply_reverse_scaled(&Matrix3::identity(), fc, scale, &g)
                    .1
            })
            .collect()
    }

    /// A device copy of `buf` (a taped state).
    /// A copy of `buf` on the device (a taped state), or the error saying the device's memory
    /// is full (a tape is planned in the host's memory; the device may hold less).
    fn copy_of(&self, buf: &wgpu::Buffer) -> Result<wgpu::Buffer, SimError> {
        let d = &self.dev.device;
        let scope = d.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let copy = storage(&self.dev, "taped state", buf.size() as usize);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(SimError::InvalidScene(format!(
                "the GPU device ({}) has no memory left for the tape ({e}); lower --memory-limit so that segments keep checkpoints and recompute, or use --device cpu",
                self.dev.name
            )));
        }
        let mut enc = d.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buf, 0, &copy, 0, buf.size());
        self.dev.queue.submit([enc.finish()]);
        Ok(copy)
    }

    /// The nodal masses the last step's P2G made.
    pub fn last_grid_mass(&self) -> Vec<f64> {
        let grid = self.read_reals(&self.grid, GRID_STRIDE * self.node_count);
        grid.chunks(GRID_STRIDE).map(|n| n[0]).collect()
    }

    /// Writes this step's control matrices `M` (`Fe = F M`, or `F + M`); the shader's mode.
    fn upload_control(&self, fc: Option<&[Matrix3<f64>]>) -> u32 {
        let Some(fc) = fc else { return 0 };
        let form = self.model.control_form;
        let m: Vec<f64> = fc
            .iter()
            .flat_map(|fc| {
                let m = match form {
                    ControlForm::Plastic => (Matrix3::identity() + fc) * form.scale(fc),
                    ControlForm::Additive => *fc,
                };
                m.as_slice().to_vec()
            })
            .collect();
        self.dev
            .queue
            .write_buffer(&self.ctrl, 0, &self.precision.encode(&m));
        match form {
            ControlForm::Plastic => 1,
            ControlForm::Additive => 2,
        }
    }

    fn upload_params(&self, step: usize, mode: u32) {
        let m = &self.model;
        let nodes = m.grid.nodes();
        let support = match m.kernel {
            KernelKind::Quadratic => 3,
            KernelKind::Cubic => 4,
        };
        let ip: [u32; 8] = [
            m.num_particles() as u32,
            nodes[0] as u32,
            nodes[1] as u32,
            nodes[2] as u32,
            support,
            mode,
            self.node_count as u32,
            step as u32,
        ];
        let time = step as f64 * m.dt;
        let retention: f64 = m
            .effects
            .iter()
            .map(|e| e.momentum_retention(m.dt, time))
            .product();
        let o = m.grid.origin;
        let mut fp: Vec<f64> = vec![
            o[0],
            o[1],
            o[2],
            m.grid.dx,
            m.dt,
            m.inv_d(),
            retention,
            m.material.spec().1,
            m.material.spec().2,
            m.max_cfl * m.grid.dx / m.dt,
        ];
        fp.resize(10 + 4 * RULES, 0.0);
        for (r, e) in grid_effects(m).enumerate() {
            let rule = &mut fp[10 + 4 * r..14 + 4 * r];
            match e.grid_rule().expect("checked by `unsupported`") {
                GridRule::Gravity(g) => rule.copy_from_slice(&[1.0, g[0], g[1], g[2]]),
                GridRule::Walls { sticky, thickness } => {
                    rule[0] = if sticky { 2.0 } else { 3.0 };
                    rule[1] = thickness as f64;
                }
            }
        }
        let q = &self.dev.queue;
        q.write_buffer(&self.iparams, 0, bytemuck::cast_slice(&ip));
        q.write_buffer(&self.fparams, 0, &self.precision.encode(&fp));
    }

    /// The dispatches `passes` of [`PASSES`] in one submission.
    fn submit(&self, passes: std::ops::Range<usize>, n: usize) {
        let groups = |k: usize| (k as u32).div_ceil(WG);
        let (particles, nodes) = (groups(n), groups(self.node_count));
        let sizes = [
            nodes, particles, 1, particles, nodes, particles, nodes, particles, particles, nodes,
            particles,
        ];
        let mut enc = self.dev.device.create_command_encoder(&Default::default());
        for k in passes {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.pipelines[k]);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.dispatch_workgroups(sizes[k], 1, 1);
        }
        self.dev.queue.submit([enc.finish()]);
    }

    pub(crate) fn read<T: bytemuck::Pod>(&self, buf: &wgpu::Buffer, count: usize) -> Vec<T> {
        self.dev.read(buf, count)
    }

    /// `count` reals of `buf`, in f64 whatever the device's precision.
    fn read_reals(&self, buf: &wgpu::Buffer, count: usize) -> Vec<f64> {
        let bytes = self.dev.read_bytes(buf, count * self.precision.bytes());
        self.precision.decode(&bytes)
    }

    /// Bytes of one particle's taped state on the device.
    pub(crate) fn state_bytes(&self) -> usize {
        STATE_STRIDE * self.precision.bytes()
    }
}

/// A state's (or its adjoint's) four fields, as the state buffer lays them out.
type Fields<'a> = (
    &'a [Vector3<f64>],
    &'a [Vector3<f64>],
    &'a [Matrix3<f64>],
    &'a [Matrix3<f64>],
);
type FieldsMut<'a> = (
    &'a mut [Vector3<f64>],
    &'a mut [Vector3<f64>],
    &'a mut [Matrix3<f64>],
    &'a mut [Matrix3<f64>],
);

/// The fields as the state buffer holds them (x, v, C, F per particle, matrices
/// column-major).
fn pack_fields((x, v, c, f): Fields) -> Vec<f64> {
    let mut out = Vec::with_capacity(STATE_STRIDE * x.len());
    for p in 0..x.len() {
        out.extend_from_slice(x[p].as_slice());
        out.extend_from_slice(v[p].as_slice());
        out.extend_from_slice(c[p].as_slice());
        out.extend_from_slice(f[p].as_slice());
    }
    out
}

fn unpack_fields(buf: &[f64], (x, v, c, f): FieldsMut) {
    for (p, row) in buf.chunks(STATE_STRIDE).enumerate() {
        x[p] = Vector3::from_column_slice(&row[0..3]);
        v[p] = Vector3::from_column_slice(&row[3..6]);
        c[p] = Matrix3::from_column_slice(&row[6..15]);
        f[p] = Matrix3::from_column_slice(&row[15..24]);
    }
}

fn pack(s: &State) -> Vec<f64> {
    pack_fields((&s.x, &s.v, &s.c, &s.f))
}

pub(crate) fn unpack(buf: &[f64], s: &mut State) {
    unpack_fields(buf, (&mut s.x, &mut s.v, &mut s.c, &mut s.f));
}

fn pack_grad(g: &StateGrad) -> Vec<f64> {
    pack_fields((&g.x, &g.v, &g.c, &g.f))
}

fn unpack_grad(buf: &[f64], g: &mut StateGrad) {
    unpack_fields(buf, (&mut g.x, &mut g.v, &mut g.c, &mut g.f));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A buffer past the adapter's binding limit is refused, naming it, its size and the limit.
    #[test]
    fn a_buffer_past_the_adapters_limit_is_refused_by_name() {
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: 128 << 20,
            ..wgpu::Limits::default()
        };
        let small = [("the grid", 1 << 20), ("the particles' state", 100 << 20)];
        assert_eq!(fits_on("a GPU", &small, &limits), Ok(()));
        let large = [("the grid", 1 << 20), ("the particles' state", 200 << 20)];
        let e = fits_on("a GPU", &large, &limits).unwrap_err();
        assert!(
            e.contains("the particles' state needs 210 MB") && e.contains("134 MB"),
            "{e}"
        );
    }
}
