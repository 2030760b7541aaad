//! The reverse of one Euler step: the forward's grid replayed from the tape, then the
//! pipeline's reverse pass in the Euler step's form ([`StepReverse`]; see
//! [`crate::mpm::pipeline`]): G2P with the particle update, the grid update (the clamped
//! nodes' adjoints to their controls), P2G with the stress.

use super::*;
use crate::mpm::grid::Tile;
use crate::mpm::pipeline::{Form, GridView, Reverse};
use crate::mpm::transfer::{Node, ScatterGrad};

/// The reverse of one taped step: reads the tape and `post` (the state after the step), and
/// keeps every particle's adjoints (each written by its own particle's calls alone).
struct StepReverse<'a> {
    euler: &'a Euler,
    tape: &'a StepTape,
    post: &'a State,
    fc: Option<&'a [Matrix3<f64>]>,
    values: Option<&'a [Vector3<f64>]>,
    body: Option<Vec<Vector3<f64>>>,
    retention: f64,
    fe: &'a [Matrix3<f64>],
    /// dL/d(state): dL/d(post) in, dL/d(pre) out.
    adj: [SharedMut<'a, Vector3<f64>>; 2],
    adj_m: [SharedMut<'a, Matrix3<f64>>; 2],
    grad_fe: SharedMut<'a, Matrix3<f64>>,
    grad_fc: SharedMut<'a, Matrix3<f64>>,
    /// dL/d(prescribed velocity) and dL/d(scattered momentum) per particle (with controls).
    grad_u: SharedMut<'a, Vector3<f64>>,
    grad_mom: SharedMut<'a, Vector3<f64>>,
}

impl StepReverse<'_> {
    fn clamped(&self, p: usize) -> bool {
        self.values.is_some() && self.euler.is_clamped(p)
    }
}

impl Form<1> for StepReverse<'_> {
    const GRID: GridForm = GridForm::Step;

    fn positions(&self) -> &[Vector3<f64>] {
        &self.tape.pre.x
    }
    fn step(&self) -> usize {
        self.tape.step
    }
    fn time(&self) -> f64 {
        self.tape.step as f64 * self.euler.dt
    }
    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        self.euler.stress_inputs(p)
    }
    fn fields(&self, p: usize) -> [Affine; 1] {
        let (e, pre, body) = (self.euler, &self.tape.pre, self.body.as_deref());
        [Affine {
            value: e.particle_momentum(pre, self.values, body, self.retention, p),
            slope: self.tape.affine[p],
        }]
    }
    fn grid_masses<'g>(&'g self, _scattered: &'g [f64]) -> &'g [f64] {
        &self.tape.grid_mass
    }
    fn control_values(&self) -> Option<&[Vector3<f64>]> {
        self.values
    }
}

impl Reverse<1> for StepReverse<'_> {
    /// P2 reverse and G2P reverse, fused per particle. A clamped particle's velocity is its
    /// prescribed one: its adjoint goes to the control (`grad_u`), not to the gather.
    fn gather_reverse<const N: usize>(&self, p: usize, grid: &GridView<N, 1>, tile: &mut Tile) {
        let (e, post, s) = (self.euler, self.post, &grid.stencils[p]);
        let (dt, inv_d, strides) = (e.dt, e.inv_d(), e.grid.strides());
        // SAFETY: each particle is visited exactly once.
        let (x_adj, fe_adj) = unsafe { (self.adj[0].get(p), self.grad_fe.get(p)) };
        let (av, ac, af) = unsafe {
            (
                *self.adj[1].get(p),
                *self.adj_m[0].get(p),
                *self.adj_m[1].get(p),
            )
        };
        let g = advance_reverse(&self.fe[p], &post.c[p], dt, x_adj, &av, &ac, &af);
        *fe_adj = g.fe;
        // The gather's own velocity (a clamped particle's state holds the prescribed one
        // instead).
        let (grad_vel, gathered) = if self.clamped(p) {
            // SAFETY: as above.
            unsafe { *self.grad_u.get(p) = av + dt * *x_adj };
            let v = transfer::gather_affine(e.simd, s, &strides, grid.velocity, inv_d).0;
            (Vector3::zeros(), v)
        } else {
            (g.vel, post.v[p])
        };
        *x_adj += transfer::gather_affine_reverse(
            e.simd,
            s,
            &strides,
            grid.velocity,
            inv_d,
            &grad_vel,
            &g.c,
            &gathered,
            tile,
        );
    }

    fn grid_input(&self, _nodes: &[Node<1>], i: usize) -> [Vector3<f64>; 1] {
        [self.tape.grid_v[i]]
    }

    fn scatter_reverse(&self, p: usize, g: &ScatterGrad<1>) -> Matrix3<f64> {
        let m = self.euler.mass[p];
        // SAFETY: each particle is visited exactly once.
        unsafe {
            *self.adj[0].get(p) += g.x;
            *self.adj[1].get(p) = match self.clamped(p) {
                true => Vector3::zeros(),
                false => (self.retention * m) * g.value[0],
            };
            if self.values.is_some() {
                *self.grad_mom.get(p) = g.value[0];
            }
        }
        g.slope[0]
    }

    fn elastic(&self, range: std::ops::Range<usize>) -> (&[Matrix3<f64>], &[f64]) {
        let keep = self.euler.material.kept_per_particle();
        (&self.fe[range.clone()], self.tape.kept_of(range, keep))
    }

    fn stress_reverse(&self, p: usize, grad_c: Matrix3<f64>, grad_fe: Matrix3<f64>) {
        // SAFETY: each particle is visited exactly once.
        unsafe {
            *self.adj_m[0].get(p) = grad_c;
            let total_fe = *self.grad_fe.get(p) + grad_fe;
            let (g_f, g_fc) = self.euler.control_reverse(self.tape, self.fc, p, &total_fe);
            *self.adj_m[1].get(p) = g_f;
            *self.grad_fc.get(p) = g_fc;
        }
    }
}

impl Euler {
    /// Reverse of one step: turns `adj` from dL/d(post) into dL/d(pre) and returns dL/dFc.
    /// Also returns dL/d(control values) when `values` (the forward pass's) are given.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn reverse_impl<const N: usize>(
        &self,
        tape: &StepTape,
        post: &State,
        fc: Option<&[Matrix3<f64>]>,
        values: Option<&[Vector3<f64>]>,
        adj: &mut StateGrad,
        effect_params: &mut [Vec<f64>],
        rws: &mut Workspace,
    ) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>)
    where
        Stencil<N>: Cached,
    {
        let mut laps = Laps::start(self.clock.as_deref());
        let n = tape.pre.len();
        let par = Parallel::for_particles(n);
        self.replay::<N>(tape, fc, rws);
        let with_values = if values.is_some() { n } else { 0 };
        let (mut grad_u, mut grad_mom) = (
            vec![Vector3::zeros(); with_values],
            vec![Vector3::zeros(); with_values],
        );
        let mut grad_fc = vec![Matrix3::zeros(); n];
        let Workspace {
            grid, particles, ..
        } = rws;
        particles.grad_fe.resize(n, Matrix3::zeros());
        let StateGrad { x, v, c, f } = adj;
        let mut form = StepReverse {
            euler: self,
            tape,
            post,
            fc,
            values,
            body: values.map(|v| self.body_accelerations(v)),
            retention: self.momentum_retention(tape.step),
            fe: &particles.fe,
            adj: [SharedMut::new(x), SharedMut::new(v)],
            adj_m: [SharedMut::new(c), SharedMut::new(f)],
            grad_fe: SharedMut::new(&mut particles.grad_fe),
            grad_fc: SharedMut::new(&mut grad_fc),
            grad_u: SharedMut::new(&mut grad_u),
            grad_mom: SharedMut::new(&mut grad_mom),
        };
        pipeline::effects_and_boundary::<N, 1, _>(&self.model, &mut form, &tape.bins, par, grid);
        laps.lap(Stage::RevSetup);
        let grad_clamp = pipeline::reverse::<N, 1, _>(
            &self.model,
            &mut form,
            &tape.bins,
            grid,
            effect_params,
            &mut laps,
        );
        drop(form);
        let grad_values = match values {
            None => Vec::new(),
            Some(_) => self.control_values_reverse(grad_u, &grad_mom, &grad_clamp),
        };
        (grad_fc, grad_values)
    }

    /// What the reverse stages read from the forward that the tape does not hold: each
    /// particle's elastic `Fe` (the control applied to the tape's F), its stencil, and the
    /// grid velocity before the effects (which the pipeline then replays).
    fn replay<const N: usize>(
        &self,
        tape: &StepTape,
        fc: Option<&[Matrix3<f64>]>,
        rws: &mut Workspace,
    ) where
        Stencil<N>: Cached,
    {
        let (pre, form) = (&tape.pre, self.control_form);
        let par = Parallel::for_particles(pre.len());
        let fe = &mut rws.particles.fe;
        fe.resize(pre.len(), Matrix3::zeros());
        fe.par_iter_mut()
            .enumerate()
            .with_min_len(par.min_len())
            .for_each(|(p, fe)| {
                *fe = match fc {
                    Some(fc) => form.apply_scaled(&pre.f[p], &fc[p], scale_of(&tape.scale, p)),
                    None => pre.f[p],
                }
            });
        let (origin, dx) = (self.grid.origin_vec(), self.grid.dx);
        stages::stencils::<N>(self.simd, &pre.x, &origin, dx, par, &mut rws.grid.stencils);
        rws.grid.fields[0].clone_from(&tape.grid_v);
    }

    /// The reverse of `Fe = control(F, Fc)` for particle `p`: (dL/dF, dL/dFc) from dL/dFe
    /// (without a control `Fe = F`, and dL/dFc is zero).
    #[inline]
    fn control_reverse(
        &self,
        tape: &StepTape,
        fc: Option<&[Matrix3<f64>]>,
        p: usize,
        grad_fe: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        match fc {
            Some(fc) => self.control_form.apply_reverse_scaled(
                &tape.pre.f[p],
                &fc[p],
                scale_of(&tape.scale, p),
                grad_fe,
            ),
            None => (*grad_fe, Matrix3::zeros()),
        }
    }

    /// dL/d(control values) from the clamped particles' prescribed velocities (`grad_u`),
    /// the scattered momenta (`grad_mom`: body forces, clamps) and the clamped nodes.
    fn control_values_reverse(
        &self,
        mut grad_u: Vec<Vector3<f64>>,
        grad_mom: &[Vector3<f64>],
        grad_clamp: &[Vector3<f64>],
    ) -> Vec<Vector3<f64>> {
        let n = grad_mom.len();
        let mut grad_body = vec![Vector3::zeros(); n];
        for p in 0..n {
            let m = self.mass[p];
            if self.is_clamped(p) {
                grad_u[p] += m * grad_mom[p];
            } else {
                grad_body[p] = (self.dt * m) * grad_mom[p];
            }
        }
        let mut g = self.control_value_grads(&grad_u, &grad_body);
        for (g, c) in g.iter_mut().zip(grad_clamp) {
            *g += c;
        }
        g
    }
}
