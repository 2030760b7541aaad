//! The right-hand side `dS/dt = f(S, u, t)` of the ODE form and its reverse (a
//! vector-Jacobian product), for S = {x, v, F}:
//!
//! - P2G: `m_i = sum w m_p`, `p_i = sum w m_p v~_p`, `f_i = sum w (K_p (x_i - x_p) + m_p b_p)`;
//! - grid: `v_i = p_i / m_i`, `a_i = f_i / m_i`, then the model's effects (gravity `a += g`,
//!   drag, walls; see [`crate::effects`]);
//! - G2P: `dx_p/dt = sum w v_i`, `dv_p/dt = sum w a_i`, `dF_p/dt = B_p F_p`.
//!
//! Particles of a prescribed-velocity control use `v~_p = u(t)`, `dx_p/dt = u(t)` and
//! `dv_p/dt = 0`. With the same MLS gradient in the force and in `B_p`, the semi-discrete
//! system conserves kinetic + elastic + gravitational energy exactly: the only losses left are
//! the integrator's (see docs/control.md).

use crate::mpm::SimError;
use crate::mpm::State;
use crate::mpm::effect::{GridContext, GridEffects, GridForm, NodeMotion};
use crate::mpm::grid::{Bins, SharedMut};
use crate::mpm::kernel::{Cached, KernelKind, Stencil, StencilCache};
use crate::mpm::model::Model;
use crate::mpm::stages::{self, CHUNK};
use crate::mpm::stress::StressInputs;
use crate::mpm::transfer::{self, Affine, AxisField, AxisNodes, Node};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// The RK4 integrator of the ODE form over a [`Model`] (which it dereferences to), with the
/// declared controls.
#[derive(Debug)]
pub struct Rk4 {
    pub model: Model,
    pool: BufferPool,
}

impl std::ops::Deref for Rk4 {
    type Target = Model;
    fn deref(&self) -> &Model {
        &self.model
    }
}

/// Where and with what one right-hand side is evaluated: the controls' values and the time
/// (step and fraction of the step).
#[derive(Clone, Copy, Debug)]
pub struct At<'a> {
    pub values: &'a [Vector3<f64>],
    pub step: usize,
    pub theta: f64,
}

impl<'a> At<'a> {
    /// The end of step `step` (where the motion's energy is measured).
    pub fn end_of_step(values: &'a [Vector3<f64>], step: usize) -> At<'a> {
        At {
            values,
            step,
            theta: 1.0,
        }
    }
}

/// dL/d(inputs) of one right-hand-side evaluation.
pub struct RhsGrad {
    pub state: State,
    /// dL/d(control values) at the evaluation time, one per control.
    pub controls: Vec<Vector3<f64>>,
    /// dL/d(effect parameters), in model order.
    pub effect_params: Vec<Vec<f64>>,
}

impl Rk4 {
    /// The RK4 integrator of `model` (with the boundary controls it declares). RK4's
    /// stability region on the imaginary axis (|h w| < 2.8) leaves a margin above the
    /// model's elastic bound.
    pub fn new(model: Model) -> Result<Rk4, SimError> {
        Ok(Rk4 {
            model,
            pool: BufferPool::default(),
        })
    }

    /// Elastic wave speed `sqrt(modulus / density)` of the densest particle.
    pub fn wave_speed(&self) -> f64 {
        self.stable_dt().1
    }

    /// The velocity particle `p` carries to the grid given the control values.
    #[inline]
    pub fn transfer_velocity(&self, s: &State, values: &[Vector3<f64>], p: usize) -> Vector3<f64> {
        self.prescribed_velocity(values, p).unwrap_or(s.v[p])
    }

    /// Kinetic energy of the particle velocities `1/2 sum m |v~|^2` (clamped particles at their
    /// prescribed velocity). Unlike [`Rk4::motion_energy`] it includes the velocity modes
    /// the grid cannot see; the report gives both.
    pub fn kinetic_energy(&self, s: &State, values: &[Vector3<f64>]) -> f64 {
        (0..s.len())
            .map(|p| 0.5 * self.mass[p] * self.transfer_velocity(s, values, p).norm_squared())
            .sum()
    }

    /// Kinetic energy of the motion, `1/2 sum m_p |dx_p/dt|^2` with `dx_p/dt = sum w v_i` the
    /// velocity particles actually move with (the prescribed one for clamped particles). The
    /// state's `v_p` may also hold modes the grid cannot see (FLIP's null space): they move
    /// nothing and no grid force can remove them, so they are not counted as motion.
    pub fn motion_energy(
        &self,
        s: &State,
        values: &[Vector3<f64>],
        step: usize,
    ) -> Result<f64, SimError> {
        let mut d = State::ode_zeros(0);
        let at = At::end_of_step(values, step);
        self.rhs(s, &at, &mut d)?;
        Ok(d.x
            .iter()
            .zip(&self.mass)
            .map(|(v, m)| 0.5 * m * v.norm_squared())
            .sum())
    }

    /// Reverse of [`Rk4::motion_energy`] scaled by `weight`.
    pub fn motion_energy_reverse(
        &self,
        s: &State,
        values: &[Vector3<f64>],
        step: usize,
        weight: f64,
    ) -> RhsGrad {
        let mut d = State::ode_zeros(0);
        let at = At::end_of_step(values, step);
        self.rhs(s, &at, &mut d)
            .expect("reverse pass replays a forward evaluation that succeeded");
        let n = s.len();
        let seed = State {
            x: d.x
                .iter()
                .zip(&self.mass)
                .map(|(v, m)| weight * m * v)
                .collect(),
            v: vec![Vector3::zeros(); n],
            c: Vec::new(),
            f: vec![Matrix3::zeros(); n],
        };
        self.rhs_reverse(s, &at, &seed)
    }

    /// Elastic energy `sum V psi(F)`.
    pub fn elastic_energy(&self, s: &State) -> f64 {
        s.f.iter()
            .zip(&self.volume)
            .map(|(f, v)| v * self.material.energy_density(f))
            .sum()
    }

    /// Potential energy of the conservative effects (gravity `-sum m g . x`).
    pub fn potential_energy(&self, s: &State) -> f64 {
        self.model.potential_energy(&s.x)
    }

    /// The two fields particle `p` scatters: momentum `m v~` and force
    /// `m b + K (x_i - x_p)`.
    #[inline]
    fn scatter_fields(
        &self,
        s: &State,
        values: &[Vector3<f64>],
        stress_force: &[Matrix3<f64>],
        body: &[Vector3<f64>],
        p: usize,
    ) -> [Affine; 2] {
        let m = self.mass[p];
        [
            Affine {
                value: m * self.transfer_velocity(s, values, p),
                slope: Matrix3::zeros(),
            },
            Affine {
                value: m * body[p],
                slope: stress_force[p],
            },
        ]
    }

    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        // With dt = 1 and mass = 0 the engine's affine momentum is exactly K_p.
        StressInputs {
            model: self.material.as_ref(),
            mass: 0.0,
            volume: self.volume[p],
            dt: 1.0,
            inv_d: self.inv_d(),
        }
    }

    /// Evaluates `f(S, u, t)` into `out` (`at.step` also labels errors).
    pub fn rhs(&self, s: &State, at: &At, out: &mut State) -> Result<(), SimError> {
        match self.kernel {
            KernelKind::Quadratic => self.rhs_impl::<3>(s, at, out),
            KernelKind::Cubic => self.rhs_impl::<4>(s, at, out),
        }
    }

    /// Reverse of [`Rk4::rhs`] at state `s`: `grad_out` is dL/d(dS/dt).
    pub fn rhs_reverse(&self, s: &State, at: &At, grad_out: &State) -> RhsGrad {
        match self.kernel {
            KernelKind::Quadratic => self.rhs_reverse_impl::<3>(s, at, grad_out),
            KernelKind::Cubic => self.rhs_reverse_impl::<4>(s, at, grad_out),
        }
    }

    /// The context the effects see at evaluation `at`.
    fn grid_context<'a>(&'a self, mass: &'a [f64], at: &At) -> GridContext<'a> {
        GridContext {
            form: GridForm::Rate,
            spec: &self.grid,
            mass,
            dt: self.dt,
            step: at.step,
            time: (at.step as f64 + at.theta) * self.dt,
        }
    }

    /// Forward pieces shared by the evaluation and its reverse. Only the grid nodes inside
    /// some particle's stencil (the active nodes) are touched, in dense buffers borrowed from
    /// the pool, so the cost follows the particles and not the domain's size.
    fn forward_grid<const N: usize>(&self, s: &State, at: &At) -> Result<Forward, SimError>
    where
        Stencil<N>: Cached,
    {
        let (values, step) = (at.values, at.step);
        let n = s.len();
        let (strides, origin, dx) = (self.grid.strides(), self.grid.origin_vec(), self.grid.dx);
        let bins = Bins::build(&self.grid, &s.x, N, step)?;
        let mut buf = self.pool.take(self.grid.node_count());
        let par = n >= PARALLEL_MIN;
        // Every particle's stencil, built once for this evaluation's transfers (and, kept
        // with the buffers, for its reverse).
        let mut cache = std::mem::take(&mut buf.stencils);
        stages::stencils::<N>(self.simd, &s.x, &origin, dx, PARALLEL_MIN, &mut cache);
        let stencils = &*cache.sized::<N>(n);
        buf.mark_active(stencils, &strides);
        let body = self.body_accelerations(values);
        let mut stress_force = vec![Matrix3::zeros(); n];
        stages::stress(
            self.material.as_ref(),
            self.simd,
            &s.f,
            None,
            |p| self.stress_inputs(p),
            PARALLEL_MIN,
            &mut stress_force,
            &mut [],
        );
        {
            let Buffers {
                nodes, node_axes, ..
            } = &mut buf;
            stages::p2g(
                self.simd,
                &bins,
                stencils,
                &self.mass,
                par,
                |p| self.scatter_fields(s, values, &stress_force, &body, p),
                node_axes,
                nodes,
                self.grid.node_count(),
            );
        }
        self.grid_rates(at, &mut buf);
        let inv_d = self.inv_d();
        buf.grid_v_axes.set_from(&buf.grid_v);
        let grid_axes = &buf.grid_v_axes;
        let gathered: Vec<Gathered> = stencils
            .par_iter()
            .with_min_len(PARALLEL_MIN)
            .map(|st| {
                let (velocity, grad_v) =
                    transfer::gather_affine(self.simd, st, &strides, grid_axes, inv_d);
                Gathered {
                    velocity,
                    acceleration: transfer::interpolate(st, &strides, &buf.grid_a),
                    grad_v,
                }
            })
            .collect();
        buf.stencils = cache;
        Ok(Forward {
            bins,
            body,
            stress_force,
            buf,
            gathered,
        })
    }

    /// The grid stage of an evaluation, on the active nodes: the nodal masses, then each
    /// node's velocity `p / m` and acceleration `f / m` through the effects.
    fn grid_rates(&self, at: &At, buf: &mut Buffers) {
        let Buffers {
            nodes,
            grid_mass,
            grid_v,
            grid_a,
            active,
            ..
        } = buf;
        let (gm, gv, ga) = (
            SharedMut::new(grid_mass),
            SharedMut::new(grid_v),
            SharedMut::new(grid_a),
        );
        active.par_iter().with_min_len(1024).for_each(|&i| {
            // SAFETY: active node indices are distinct.
            unsafe { *gm.get(i as usize) = nodes[i as usize].mass };
        });
        let ctx = self.grid_context(grid_mass, at);
        let effects = GridEffects::new(&self.effects, GridForm::Rate);
        active.par_iter().with_min_len(1024).for_each(|&i| {
            let i = i as usize;
            let [v, a] = transfer::quotient(&nodes[i]);
            let mut motion = NodeMotion { v, a };
            if nodes[i].mass > 0.0 {
                effects.apply(&ctx, i, &mut motion);
            }
            // SAFETY: active node indices are distinct.
            unsafe {
                *gv.get(i) = motion.v;
                *ga.get(i) = motion.a;
            }
        });
    }

    fn rhs_impl<const N: usize>(&self, s: &State, at: &At, out: &mut State) -> Result<(), SimError>
    where
        Stencil<N>: Cached,
    {
        let values = at.values;
        let fw = self.forward_grid::<N>(s, at)?;
        let n = s.len();
        out.x.resize(n, Vector3::zeros());
        out.v.resize(n, Vector3::zeros());
        out.f.resize(n, Matrix3::zeros());
        (
            out.x.par_iter_mut(),
            out.v.par_iter_mut(),
            out.f.par_iter_mut(),
        )
            .into_par_iter()
            .with_min_len(PARALLEL_MIN)
            .enumerate()
            .for_each(|(p, (dx, dv, df))| {
                let g = &fw.gathered[p];
                match self.prescribed_velocity(values, p) {
                    None => {
                        *dx = g.velocity;
                        *dv = g.acceleration;
                    }
                    Some(u) => {
                        *dx = u;
                        *dv = Vector3::zeros();
                    }
                }
                *df = g.grad_v * s.f[p];
            });
        self.pool.put(fw.buf);
        Ok(())
    }

    /// The reverse of [`Rk4::rhs`]: the forward evaluation replayed, then its stages
    /// backwards (G2P with dF/dt, the grid, P2G with the stress).
    fn rhs_reverse_impl<const N: usize>(&self, s: &State, at: &At, grad_out: &State) -> RhsGrad
    where
        Stencil<N>: Cached,
    {
        let mut fw = self
            .forward_grid::<N>(s, at)
            .expect("reverse pass replays a forward evaluation that succeeded");
        let n = s.len();
        let mut grad = State::ode_zeros(n);
        // The forward evaluation's stencils (put back with the buffers at the end).
        let mut cache = std::mem::take(&mut fw.buf.stencils);
        let stencils = &*cache.sized::<N>(n);
        // dL/d(clamp velocity) per particle, summed per control afterwards (in particle order,
        // so the result does not depend on the thread count).
        let mut grad_u = vec![Vector3::zeros(); n];
        self.g2p_rate_reverse::<N>(s, grad_out, &mut fw, stencils, &mut grad, &mut grad_u);
        let effect_params = self.grid_rate_reverse(at, &mut fw.buf);
        let grad_body =
            self.p2g_rate_reverse::<N>(s, at.values, &mut fw, stencils, &mut grad, &mut grad_u);
        fw.buf.stencils = cache;
        self.pool.put(fw.buf);
        let controls = self.control_value_grads(&grad_u, &grad_body);
        RhsGrad {
            state: grad,
            controls,
            effect_params,
        }
    }

    /// G2P and dF/dt reverse: a scatter into the grid adjoints (`fw.buf.grad_v`, `grad_a`),
    /// into `grad.x`, `grad.f` and the clamped particles' `grad_u`.
    fn g2p_rate_reverse<const N: usize>(
        &self,
        s: &State,
        grad_out: &State,
        fw: &mut Forward,
        stencils: &[Stencil<N>],
        grad: &mut State,
        grad_u: &mut [Vector3<f64>],
    ) where
        Stencil<N>: Cached,
    {
        let par = s.len() >= PARALLEL_MIN;
        let strides = self.grid.strides();
        let inv_d = self.inv_d();
        let Buffers {
            grid_v,
            grid_a,
            grad_v,
            grad_a,
            grid_v_axes: grid_axes,
            grad_v_axes: grad_axes,
            grad_a_axes,
            ..
        } = &mut fw.buf;
        let gx = SharedMut::new(&mut grad.x);
        let gf = SharedMut::new(&mut grad.f);
        let gu = SharedMut::new(grad_u);
        let gathered = &fw.gathered;
        let bins = &fw.bins;
        // Tile channels 0-2: dL/dv's axes; 3-5: dL/da's.
        let nodes = grid_v.len();
        let AxisField { axes: gv, tiles } = grad_axes;
        let ga = &mut grad_a_axes.axes;
        for axis in gv.iter_mut().chain(ga.iter_mut()) {
            axis.resize(nodes, 0.0);
        }
        let [gv0, gv1, gv2] = gv;
        let [ga0, ga1, ga2] = ga;
        bins.scatter(
            par,
            tiles,
            &mut [gv0, gv1, gv2, ga0, ga1, ga2],
            |tile, p| {
                let g_out = &gathered[p];
                let g_df = grad_out.f[p];
                let mut g = Gathered {
                    velocity: grad_out.x[p],
                    acceleration: grad_out.v[p],
                    grad_v: g_df * s.f[p].transpose(),
                };
                if self.is_clamped(p) {
                    // SAFETY: each particle is visited exactly once.
                    unsafe { *gu.get(p) += g.velocity };
                    g.velocity = Vector3::zeros();
                    g.acceleration = Vector3::zeros();
                }
                let st = &stencils[p];
                let d = transfer::gather_affine_reverse(
                    self.simd,
                    st,
                    &strides,
                    grid_axes,
                    inv_d,
                    &g.velocity,
                    &g.grad_v,
                    &g_out.velocity,
                    tile,
                ) + transfer::interpolate_reverse(
                    st,
                    &strides,
                    grid_a,
                    &g.acceleration,
                    tile,
                    3,
                );
                // SAFETY: each particle is visited exactly once.
                unsafe {
                    *gx.get(p) += d;
                    *gf.get(p) += g_out.grad_v.transpose() * g_df;
                }
            },
        );
        grad_axes.write_vectors(grad_v);
        grad_a_axes.write_vectors(grad_a);
    }

    /// Grid reverse: the effects backwards (each given its inputs, replayed from the
    /// quotient), then v = p / m, a = f / m, into `buf.grad_nodes`. Parameter gradients are
    /// summed over nodes in the order of the active list, so they do not depend on the
    /// thread count.
    fn grid_rate_reverse(&self, at: &At, buf: &mut Buffers) -> Vec<Vec<f64>> {
        let mut effect_params = self.zero_effect_params();
        let Buffers {
            nodes,
            grid_mass,
            grad_v,
            grad_a,
            grad_nodes,
            active,
            ..
        } = buf;
        let ctx = self.grid_context(grid_mass, at);
        let effects = GridEffects::new(&self.effects, GridForm::Rate);
        let width = effects.width();
        let mut node_params = vec![0.0; active.len() * width];
        let gn = SharedMut::new(grad_nodes);
        let reverse_node = |i: usize, params: &mut [f64]| {
            let [v, a] = transfer::quotient(&nodes[i]);
            let mut grad = NodeMotion {
                v: grad_v[i],
                a: grad_a[i],
            };
            if nodes[i].mass > 0.0 {
                effects.reverse(&ctx, i, &NodeMotion { v, a }, &mut grad, params);
            }
            // SAFETY: active node indices are distinct.
            unsafe {
                *gn.get(i) = transfer::quotient_reverse(nodes[i].mass, &[v, a], &[grad.v, grad.a])
            };
        };
        if width > 0 {
            active
                .par_iter()
                .zip(node_params.par_chunks_mut(width))
                .with_min_len(1024)
                .for_each(|(&i, params)| reverse_node(i as usize, params));
            effects.add_rows(&node_params, &mut effect_params);
        } else {
            active
                .par_iter()
                .with_min_len(1024)
                .for_each(|&i| reverse_node(i as usize, &mut []));
        }
        effect_params
    }

    /// P2G reverse (a gather) and the stress reverse, into `grad` and the clamped particles'
    /// `grad_u`; returns dL/d(body acceleration) per particle.
    fn p2g_rate_reverse<const N: usize>(
        &self,
        s: &State,
        values: &[Vector3<f64>],
        fw: &mut Forward,
        stencils: &[Stencil<N>],
        grad: &mut State,
        grad_u: &mut [Vector3<f64>],
    ) -> Vec<Vector3<f64>>
    where
        Stencil<N>: Cached,
    {
        let n = s.len();
        let strides = self.grid.strides();
        let mut grad_body = vec![Vector3::zeros(); n];
        fw.buf.grad_node_axes.set_from(&fw.buf.grad_nodes);
        let grad_nodes = &fw.buf.grad_node_axes;
        (
            grad.x.par_chunks_mut(CHUNK),
            grad.v.par_chunks_mut(CHUNK),
            grad.f.par_chunks_mut(CHUNK),
            grad_u.par_chunks_mut(CHUNK),
            grad_body.par_chunks_mut(CHUNK),
        )
            .into_par_iter()
            .with_min_len(PARALLEL_MIN / CHUNK)
            .enumerate()
            .for_each(|(k, (gx, gv, gf, gu, gb))| {
                let p0 = k * CHUNK;
                let len = gx.len();
                // dL/d(the force field's slope K_p), for the stress stage's reverse.
                let mut grad_k = [Matrix3::zeros(); CHUNK];
                for i in 0..len {
                    let p = p0 + i;
                    let fields = self.scatter_fields(s, values, &fw.stress_force, &fw.body, p);
                    let m = self.mass[p];
                    let g = transfer::scatter_reverse(
                        self.simd,
                        &stencils[p],
                        &strides,
                        m,
                        &fields,
                        grad_nodes,
                    );
                    gx[i] += g.x;
                    // Momentum field m v~, force field m b + K (x_i - x_p).
                    match self.is_clamped(p) {
                        false => gv[i] += m * g.value[0],
                        true => gu[i] += m * g.value[0],
                    }
                    gb[i] = m * g.value[1];
                    grad_k[i] = g.slope[1];
                }
                stages::stress_reverse(
                    self.material.as_ref(),
                    self.simd,
                    p0,
                    &s.f[p0..p0 + len],
                    &[],
                    |p| self.stress_inputs(p),
                    &grad_k[..len],
                    |i, _, g_f| gf[i] += g_f,
                );
            });
        grad_body
    }

    /// Checks a state before integrating it.
    pub fn check_state(&self, s: &State, step: usize) -> Result<(), SimError> {
        if s.v.len() != s.len() || s.f.len() != s.len() {
            return Err(SimError::InvalidScene(
                "state fields differ in length".into(),
            ));
        }
        self.check_size(s.len())?;
        self.check_finite_and_cfl(s.first_non_finite(), &[], step)
    }
}

/// Below this many particles the stages run on the calling thread: the work is too small to
/// pay for a fork-join (and the controllers parallelize over rollouts instead). Results are
/// bitwise the same either way.
const PARALLEL_MIN: usize = 2048;

/// Dense grid buffers of one evaluation; only active nodes hold meaningful values.
#[derive(Default)]
struct Buffers {
    nodes: Vec<Node<2>>,
    grid_mass: Vec<f64>,
    grid_v: Vec<Vector3<f64>>,
    grid_a: Vec<Vector3<f64>>,
    grad_v: Vec<Vector3<f64>>,
    grad_a: Vec<Vector3<f64>>,
    grad_nodes: Vec<Node<2>>,
    /// The same grids stored by axis, for the transfers on stencil rows (kept with the
    /// buffers, so an evaluation does not allocate them again).
    node_axes: AxisNodes<2>,
    grid_v_axes: AxisField,
    grad_v_axes: AxisField,
    grad_a_axes: AxisField,
    grad_node_axes: AxisNodes<2>,
    /// Every particle's stencil, built once an evaluation.
    stencils: StencilCache,
    /// `mark[i] == generation` when node i is active in the current evaluation.
    mark: Vec<u32>,
    generation: u32,
    active: Vec<u32>,
}

impl Buffers {
    fn sized(nodes: usize) -> Buffers {
        Buffers {
            nodes: vec![Node::ZERO; nodes],
            grid_mass: vec![0.0; nodes],
            grid_v: vec![Vector3::zeros(); nodes],
            grid_a: vec![Vector3::zeros(); nodes],
            grad_v: vec![Vector3::zeros(); nodes],
            grad_a: vec![Vector3::zeros(); nodes],
            grad_nodes: vec![Node::ZERO; nodes],
            node_axes: AxisNodes::default(),
            grid_v_axes: AxisField::default(),
            grad_v_axes: AxisField::default(),
            grad_a_axes: AxisField::default(),
            grad_node_axes: AxisNodes::default(),
            stencils: StencilCache::default(),
            mark: vec![0; nodes],
            generation: 0,
            active: Vec::new(),
        }
    }

    /// Lists the nodes inside any particle's stencil (positions already checked by Bins).
    fn mark_active<const N: usize>(&mut self, stencils: &[Stencil<N>], strides: &[usize; 3]) {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.generation = 1;
        }
        self.active.clear();
        for st in stencils {
            let i0 = st.base_index(strides);
            for a in 0..N {
                for b in 0..N {
                    let row = i0 + a * strides[0] + b * strides[1];
                    for c in 0..N {
                        let i = row + c;
                        if self.mark[i] != self.generation {
                            self.mark[i] = self.generation;
                            self.active.push(i as u32);
                        }
                    }
                }
            }
        }
    }
}

/// Reusable grid buffers, shared by concurrent evaluations (rollouts run in parallel, and a
/// work-stealing thread may start a second evaluation while one is in flight, so a
/// thread-local buffer would not do).
#[derive(Default)]
pub(crate) struct BufferPool {
    free: std::sync::Mutex<Vec<Buffers>>,
}

impl std::fmt::Debug for BufferPool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BufferPool")
    }
}

impl BufferPool {
    fn take(&self, nodes: usize) -> Buffers {
        let found = self.free.lock().map(|mut v| v.pop()).unwrap_or(None);
        match found {
            Some(b) if b.nodes.len() == nodes => b,
            _ => Buffers::sized(nodes),
        }
    }

    fn put(&self, b: Buffers) {
        if let Ok(mut v) = self.free.lock() {
            v.push(b);
        }
    }
}

/// Intermediate results of one forward evaluation.
/// What the gather returns for one particle.
#[derive(Clone, Copy, Debug)]
struct Gathered {
    velocity: Vector3<f64>,
    acceleration: Vector3<f64>,
    /// Velocity gradient `B_p`.
    grad_v: Matrix3<f64>,
}

struct Forward {
    bins: Bins,
    body: Vec<Vector3<f64>>,
    stress_force: Vec<Matrix3<f64>>,
    buf: Buffers,
    gathered: Vec<Gathered>,
}
