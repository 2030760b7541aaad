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
use crate::mpm::effect::GridForm;
use crate::mpm::grid::{Bins, SharedMut, Tile};
use crate::mpm::kernel::{Cached, KernelKind, Stencil};
use crate::mpm::model::Model;
use crate::mpm::pipeline::{self, Form, Forward, GridView, Reverse};
use crate::mpm::profile::Laps;
use crate::mpm::scratch::{GridScratch, Pool};
use crate::mpm::stages::{self, Parallel};
use crate::mpm::stress::StressInputs;
use crate::mpm::transfer::{self, Affine, Node, ScatterGrad};
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

    /// The forward pass of one evaluation, in buffers from the pool: only the region's grid
    /// nodes (see [`crate::mpm::grid`]) are touched, so the cost follows the particles and
    /// not the domain's size.
    fn forward_grid<'a, const N: usize>(
        &'a self,
        s: &'a State,
        at: &'a At<'a>,
    ) -> Result<Evaluation<'a>, SimError>
    where
        Stencil<N>: Cached,
    {
        let mut pass = RatePass {
            rk4: self,
            s,
            at,
            body: self.body_accelerations(at.values),
            stress_force: Vec::new(),
            gathered: Vec::new(),
        };
        let (mut bins, mut buf) = (Bins::default(), self.pool.take());
        let mut laps = Laps::start(None);
        pipeline::forward::<N, 2, _>(&self.model, &mut pass, &mut bins, &mut buf, &mut laps)?;
        Ok(Evaluation { bins, pass, buf })
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
                let g = &fw.pass.gathered[p];
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

    /// The reverse of [`Rk4::rhs`]: the forward evaluation replayed, then the pipeline's
    /// reverse pass in the ODE form ([`RateReverse`]).
    fn rhs_reverse_impl<const N: usize>(&self, s: &State, at: &At, grad_out: &State) -> RhsGrad
    where
        Stencil<N>: Cached,
    {
        let mut fw = self
            .forward_grid::<N>(s, at)
            .expect("reverse pass replays a forward evaluation that succeeded");
        let n = s.len();
        let mut grad = State::ode_zeros(n);
        // dL/d(clamp velocity) and dL/d(body acceleration) per particle, summed per control
        // afterwards (in particle order, so the result does not depend on the thread count).
        let (mut grad_u, mut grad_body) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
        let mut effect_params = self.zero_effect_params();
        let State { x, v, f, .. } = &mut grad;
        let mut rev = RateReverse {
            pass: &fw.pass,
            grad_out,
            grad: [SharedMut::new(x), SharedMut::new(v)],
            grad_f: SharedMut::new(f),
            grad_u: SharedMut::new(&mut grad_u),
            grad_body: SharedMut::new(&mut grad_body),
        };
        let mut laps = Laps::start(None);
        let (model, bins) = (&self.model, &fw.bins);
        let grad_held = pipeline::reverse::<N, 2, _>(
            model,
            &mut rev,
            bins,
            &mut fw.buf,
            &mut effect_params,
            &mut laps,
        );
        self.pool.put(fw.buf);
        let mut controls = self.control_value_grads(&grad_u, &grad_body);
        for (g, held) in controls.iter_mut().zip(&grad_held) {
            *g += held;
        }
        RhsGrad {
            state: grad,
            controls,
            effect_params,
        }
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

/// What the gather returns for one particle.
#[derive(Clone, Copy, Debug)]
struct Gathered {
    velocity: Vector3<f64>,
    acceleration: Vector3<f64>,
    /// Velocity gradient `B_p`.
    grad_v: Matrix3<f64>,
}

/// One forward evaluation: its bins, its form's results and its grid.
struct Evaluation<'a> {
    bins: Bins,
    pass: RatePass<'a>,
    buf: Scratch,
}

/// The ODE form as a [`Form`] of the one pipeline (see [`crate::mpm::pipeline`]): two fields
/// a node (momentum `m v~`; force `m b + K (x_i - x_p)`, `K` the stress), the effects as
/// rates, and a gather of each particle's velocity, acceleration and velocity gradient.
struct RatePass<'a> {
    rk4: &'a Rk4,
    s: &'a State,
    at: &'a At<'a>,
    body: Vec<Vector3<f64>>,
    stress_force: Vec<Matrix3<f64>>,
    gathered: Vec<Gathered>,
}

impl Form<2> for RatePass<'_> {
    const GRID: GridForm = GridForm::Rate;

    fn positions(&self) -> &[Vector3<f64>] {
        &self.s.x
    }
    fn step(&self) -> usize {
        self.at.step
    }
    fn time(&self) -> f64 {
        (self.at.step as f64 + self.at.theta) * self.rk4.dt
    }
    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        self.rk4.stress_inputs(p)
    }
    fn fields(&self, p: usize) -> [Affine; 2] {
        let (values, force) = (self.at.values, &self.stress_force);
        self.rk4
            .scatter_fields(self.s, values, force, &self.body, p)
    }
    fn control_values(&self) -> Option<&[Vector3<f64>]> {
        Some(self.at.values)
    }
}

impl Forward<2> for RatePass<'_> {
    fn stress(&mut self, par: Parallel) {
        let rk4 = self.rk4;
        self.stress_force.resize(self.s.len(), Matrix3::zeros());
        stages::stress(
            rk4.material.as_ref(),
            rk4.simd,
            &self.s.f,
            None,
            |p| rk4.stress_inputs(p),
            par,
            &mut self.stress_force,
            &mut [],
        );
    }

    fn gather<const N: usize>(&mut self, grid: GridView<N, 2>, par: Parallel) {
        let rk4 = self.rk4;
        let (strides, inv_d) = (rk4.grid.strides(), rk4.inv_d());
        let (grid_axes, grid_a) = (grid.velocity, &grid.fields[1]);
        self.gathered = grid
            .stencils
            .par_iter()
            .with_min_len(par.min_len())
            .map(|st| {
                let (velocity, grad_v) =
                    transfer::gather_affine(rk4.simd, st, &strides, grid_axes, inv_d);
                Gathered {
                    velocity,
                    acceleration: transfer::interpolate(st, &strides, grid_a),
                    grad_v,
                }
            })
            .collect();
    }
}

/// The reverse of one evaluation from its forward: reads dL/d(dS/dt) (`grad_out`) and keeps
/// every particle's adjoints (each written by its own particle's calls alone).
struct RateReverse<'a> {
    pass: &'a RatePass<'a>,
    grad_out: &'a State,
    /// dL/dx, dL/dv; dL/dF.
    grad: [SharedMut<'a, Vector3<f64>>; 2],
    grad_f: SharedMut<'a, Matrix3<f64>>,
    grad_u: SharedMut<'a, Vector3<f64>>,
    grad_body: SharedMut<'a, Vector3<f64>>,
}

impl Form<2> for RateReverse<'_> {
    const GRID: GridForm = GridForm::Rate;

    fn positions(&self) -> &[Vector3<f64>] {
        self.pass.positions()
    }
    fn step(&self) -> usize {
        self.pass.step()
    }
    fn time(&self) -> f64 {
        self.pass.time()
    }
    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        self.pass.stress_inputs(p)
    }
    fn fields(&self, p: usize) -> [Affine; 2] {
        self.pass.fields(p)
    }
    fn control_values(&self) -> Option<&[Vector3<f64>]> {
        self.pass.control_values()
    }
}

impl Reverse<2> for RateReverse<'_> {
    /// G2P and dF/dt reverse: channels 0-2 dL/dv's axes, 3-5 dL/da's. A clamped particle's
    /// rates are its control's: their adjoints go to `grad_u`.
    fn gather_reverse<const N: usize>(&self, p: usize, grid: &GridView<N, 2>, tile: &mut Tile) {
        let (rk4, s, grad_out) = (self.pass.rk4, self.pass.s, self.grad_out);
        let (strides, inv_d) = (rk4.grid.strides(), rk4.inv_d());
        let (g_out, st) = (&self.pass.gathered[p], &grid.stencils[p]);
        let g_df = grad_out.f[p];
        let mut g = Gathered {
            velocity: grad_out.x[p],
            acceleration: grad_out.v[p],
            grad_v: g_df * s.f[p].transpose(),
        };
        if rk4.is_clamped(p) {
            // SAFETY: each particle is visited exactly once.
            unsafe { *self.grad_u.get(p) += g.velocity };
            g.velocity = Vector3::zeros();
            g.acceleration = Vector3::zeros();
        }
        let d = transfer::gather_affine_reverse(
            rk4.simd,
            st,
            &strides,
            grid.velocity,
            inv_d,
            &g.velocity,
            &g.grad_v,
            &g_out.velocity,
            tile,
        ) + transfer::interpolate_reverse(
            st,
            &strides,
            &grid.fields[1],
            &g.acceleration,
            tile,
            3,
        );
        // SAFETY: as above.
        unsafe {
            *self.grad[0].get(p) += d;
            *self.grad_f.get(p) += g_out.grad_v.transpose() * g_df;
        }
    }

    fn grid_input(&self, nodes: &[Node<2>], i: usize) -> [Vector3<f64>; 2] {
        transfer::quotient(&nodes[i])
    }

    /// Momentum field `m v~`, force field `m b + K (x_i - x_p)`.
    fn scatter_reverse(&self, p: usize, g: &ScatterGrad<2>) -> Matrix3<f64> {
        let rk4 = self.pass.rk4;
        let m = rk4.mass[p];
        // SAFETY: each particle is visited exactly once.
        unsafe {
            *self.grad[0].get(p) += g.x;
            match rk4.is_clamped(p) {
                false => *self.grad[1].get(p) += m * g.value[0],
                true => *self.grad_u.get(p) += m * g.value[0],
            }
            *self.grad_body.get(p) = m * g.value[1];
        }
        g.slope[1]
    }

    fn elastic(&self, range: std::ops::Range<usize>) -> (&[Matrix3<f64>], &[f64]) {
        (&self.pass.s.f[range], &[])
    }

    fn stress_reverse(&self, p: usize, _grad_c: Matrix3<f64>, grad_fe: Matrix3<f64>) {
        // SAFETY: each particle is visited exactly once.
        unsafe { *self.grad_f.get(p) += grad_fe };
    }
}
