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
use crate::mpm::effect::{GridContext, GridEffects, GridForm};
use crate::mpm::grid::{Bins, SharedMut};
use crate::mpm::grid_update::{apply_grid_effects, grid_quotients, grid_update_reverse};
use crate::mpm::kernel::{Cached, KernelKind, Stencil};
use crate::mpm::model::Model;
use crate::mpm::scratch::{GridScratch, Pool};
use crate::mpm::stages::{self, CHUNK, Parallel};
use crate::mpm::stress::StressInputs;
use crate::mpm::transfer::{self, Affine, AxisField};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// The RK4 integrator of the ODE form over a [`Model`] (which it dereferences to), with the
/// declared controls.
#[derive(Debug)]
pub struct Rk4 {
    pub model: Model,
    pool: Pool<Scratch>,
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
            pool: Pool::default(),
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

    /// Forward pieces shared by the evaluation and its reverse. Only the region's grid nodes
    /// (see [`crate::mpm::grid`]) are touched, in dense buffers borrowed from the pool, so the
    /// cost follows the particles and not the domain's size.
    fn forward_grid<const N: usize>(&self, s: &State, at: &At) -> Result<Forward, SimError>
    where
        Stencil<N>: Cached,
    {
        let (values, step) = (at.values, at.step);
        let n = s.len();
        let (strides, origin, dx) = (self.grid.strides(), self.grid.origin_vec(), self.grid.dx);
        let bins = Bins::build(&self.grid, &s.x, N, step)?;
        let mut buf = self.pool.take();
        let par = Parallel::for_particles(n);
        // Every particle's stencil, built once for this evaluation's transfers (and, kept
        // with the buffers, for its reverse).
        let mut cache = std::mem::take(&mut buf.stencils);
        stages::stencils::<N>(self.simd, &s.x, &origin, dx, par, &mut cache);
        let stencils = &*cache.sized::<N>(n);
        let body = self.body_accelerations(values);
        let mut stress_force = vec![Matrix3::zeros(); n];
        stages::stress(
            self.material.as_ref(),
            self.simd,
            &s.f,
            None,
            |p| self.stress_inputs(p),
            par,
            &mut stress_force,
            &mut [],
        );
        {
            let GridScratch {
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
        self.grid_rates(at, &bins, par, &mut buf);
        let inv_d = self.inv_d();
        buf.velocity_axes.set_from(&buf.fields[0], &bins, par.on);
        let (grid_axes, grid_a) = (&buf.velocity_axes, &buf.fields[1]);
        let gathered: Vec<Gathered> = stencils
            .par_iter()
            .with_min_len(par.min_len())
            .map(|st| {
                let (velocity, grad_v) =
                    transfer::gather_affine(self.simd, st, &strides, grid_axes, inv_d);
                Gathered {
                    velocity,
                    acceleration: transfer::interpolate(st, &strides, grid_a),
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

    /// The grid stage of an evaluation, on the region: the nodal masses, then each node's
    /// velocity `p / m` and acceleration `f / m` through the effects.
    fn grid_rates(&self, at: &At, bins: &Bins, par: Parallel, buf: &mut Scratch) {
        let GridScratch {
            nodes,
            mass: grid_mass,
            fields: [grid_v, grid_a],
            ..
        } = buf;
        grid_quotients(bins, par, nodes, grid_mass, [grid_v, grid_a]);
        let ctx = self.grid_context(grid_mass, at);
        let effects = GridEffects::new(&self.effects, GridForm::Rate);
        apply_grid_effects(
            bins,
            par,
            &effects,
            &ctx,
            [&mut grid_v[..], &mut grid_a[..]],
        );
    }

    fn rhs_impl<const N: usize>(&self, s: &State, at: &At, out: &mut State) -> Result<(), SimError>
    where
        Stencil<N>: Cached,
    {
        let values = at.values;
        let fw = self.forward_grid::<N>(s, at)?;
        let n = s.len();
        let par = Parallel::for_particles(n);
        out.x.resize(n, Vector3::zeros());
        out.v.resize(n, Vector3::zeros());
        out.f.resize(n, Matrix3::zeros());
        (
            out.x.par_iter_mut(),
            out.v.par_iter_mut(),
            out.f.par_iter_mut(),
        )
            .into_par_iter()
            .with_min_len(par.min_len())
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
        let effect_params = self.grid_rate_reverse(at, &fw.bins, &mut fw.buf);
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

    /// G2P and dF/dt reverse: a scatter into the grid adjoints (`fw.buf.grad_fields`),
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
        let par = Parallel::for_particles(s.len());
        let strides = self.grid.strides();
        let inv_d = self.inv_d();
        let GridScratch {
            fields: [grid_v, grid_a],
            grad_fields: [grad_v, grad_a],
            velocity_axes: grid_axes,
            grad_axes: [grad_axes, grad_a_axes],
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
            par.on,
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
        grad_axes.write_vectors(grad_v, bins, par.on);
        grad_a_axes.write_vectors(grad_a, bins, par.on);
    }

    /// Grid reverse: the effects backwards (each given its inputs, replayed from the
    /// quotient), then v = p / m, a = f / m, into `buf.grad_nodes`, on the region (see
    /// [`grid_update_reverse`]).
    fn grid_rate_reverse(&self, at: &At, bins: &Bins, buf: &mut Scratch) -> Vec<Vec<f64>> {
        let mut effect_params = self.zero_effect_params();
        let GridScratch {
            nodes,
            mass: grid_mass,
            grad_fields: [grad_v, grad_a],
            grad_nodes,
            ..
        } = buf;
        let ctx = self.grid_context(grid_mass, at);
        let effects = GridEffects::new(&self.effects, GridForm::Rate);
        grid_update_reverse(
            bins,
            Parallel::for_particles(bins.order.len()),
            &effects,
            &ctx,
            |i| transfer::quotient(&nodes[i]),
            |i| [grad_v[i], grad_a[i]],
            grad_nodes,
            &mut effect_params,
        );
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
        let par = Parallel::for_particles(n);
        fw.buf
            .grad_node_axes
            .set_from(&fw.buf.grad_nodes, &fw.bins, par.on);
        let grad_nodes = &fw.buf.grad_node_axes;
        (
            grad.x.par_chunks_mut(CHUNK),
            grad.v.par_chunks_mut(CHUNK),
            grad.f.par_chunks_mut(CHUNK),
            grad_u.par_chunks_mut(CHUNK),
            grad_body.par_chunks_mut(CHUNK),
        )
            .into_par_iter()
            .with_min_len(par.min_batches())
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

/// The grid buffers of one evaluation: momentum and force a node.
type Scratch = GridScratch<2>;

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
    buf: Scratch,
    gathered: Vec<Gathered>,
}
