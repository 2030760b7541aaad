//! The reverse of one Euler step, stage by stage backwards (see [`super::Euler`]'s
//! `step_impl` for the forward): the grid velocity G2P read replayed from the tape, G2P with
//! the particle update, the grid update, P2G with the stress.

use super::*;

impl Euler {
    /// Reverse of one step: turns `adj` from dL/d(post) into dL/d(pre) and returns dL/dFc.
    /// Also returns dL/d(control values) when `values` (the forward pass's) are given. The
    /// stages run backwards: the grid velocity G2P read (replayed from the tape), G2P with
    /// the particle update, the grid update, P2G with the stress.
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
        let effects = GridEffects::new(&self.effects, GridForm::Step);
        let clamp_nodes = self.reverse_setup::<N>(tape, fc, values, &effects, rws);
        laps.lap(Stage::RevSetup);
        let grad_u = self.g2p_reverse::<N>(tape, post, values, adj, rws);
        laps.lap(Stage::RevG2p);
        let grad_clamp = self.grid_reverse(tape, &clamp_nodes, &effects, effect_params, rws);
        laps.lap(Stage::RevGrid);
        let (grad_fc, grad_mom) = self.p2g_stress_reverse::<N>(tape, fc, values, adj, rws);
        laps.lap(Stage::RevP2gStress);
        let grad_values = match values {
            None => Vec::new(),
            Some(_) => self.control_values_reverse(grad_u, &grad_mom, &grad_clamp),
        };
        (grad_fc, grad_values)
    }

    /// What the reverse stages read: each particle's elastic `Fe` (the control applied to
    /// the tape's F), and the grid velocity G2P read, replayed from the tape through the grid
    /// effects and the clamps. Returns the clamped nodes and their controls.
    fn reverse_setup<const N: usize>(
        &self,
        tape: &StepTape,
        fc: Option<&[Matrix3<f64>]>,
        values: Option<&[Vector3<f64>]>,
        effects: &GridEffects,
        rws: &mut Workspace,
    ) -> Vec<(usize, usize)>
    where
        Stencil<N>: Cached,
    {
        let pre = &tape.pre;
        let form = self.control_form;
        rws.fe.resize(pre.len(), Matrix3::zeros());
        let par = Parallel::for_particles(pre.len());
        rws.fe
            .par_iter_mut()
            .enumerate()
            .with_min_len(par.min_len())
            .for_each(|(p, fe)| {
                *fe = match fc {
                    Some(fc) => form.apply_scaled(&pre.f[p], &fc[p], scale_of(&tape.scale, p)),
                    None => pre.f[p],
                }
            });
        let par = Parallel::for_particles(pre.len());
        let ctx = self.grid_context(&tape.grid_mass, tape.step);
        rws.grid.fields[0].clone_from(&tape.grid_v);
        apply_grid_effects(
            &tape.bins,
            par,
            effects,
            &ctx,
            [&mut rws.grid.fields[0][..]],
        );
        let clamp_nodes = match values {
            Some(vals) => {
                let nodes = self.clamp_nodes::<N>(&pre.x);
                for &(i, e) in &nodes {
                    rws.grid.fields[0][i] = vals[e];
                }
                nodes
            }
            None => Vec::new(),
        };
        rws.grid
            .velocity_axes
            .set_from(&rws.grid.fields[0], &tape.bins, par.on);
        clamp_nodes
    }

    /// G2P reverse with the particle update's (P2), into `adj.x`, `rws.grad_fe` and the grid
    /// velocity's adjoint; returns dL/d(prescribed velocity) of each clamped particle.
    fn g2p_reverse<const N: usize>(
        &self,
        tape: &StepTape,
        post: &State,
        values: Option<&[Vector3<f64>]>,
        adj: &mut StateGrad,
        rws: &mut Workspace,
    ) -> Vec<Vector3<f64>>
    where
        Stencil<N>: Cached,
    {
        let pre = &tape.pre;
        let n = pre.len();
        let par = Parallel::for_particles(n);
        let nodes = self.grid.node_count();
        let (dt, inv_d) = (self.dt, self.inv_d());
        let (strides, origin, dx) = (self.grid.strides(), self.grid.origin_vec(), self.grid.dx);
        let (fe, grid_v) = (&rws.fe, &rws.grid.velocity_axes);
        // P2 reverse and G2P reverse, fused per particle (a scatter into the grid velocity
        // adjoint, block by block into tiles). A clamped particle's velocity is its
        // prescribed one: its adjoint goes to the control (`grad_u`), not to the gather.
        let clamped = |p: usize| values.is_some() && self.is_clamped(p);
        let mut grad_u = vec![Vector3::zeros(); if values.is_some() { n } else { 0 }];
        rws.grad_fe.resize(n, Matrix3::zeros());
        let StateGrad {
            x: ax,
            v: av,
            c: ac,
            f: af,
        } = adj;
        {
            let gx = SharedMut::new(ax);
            let gfe = SharedMut::new(&mut rws.grad_fe);
            let gu = SharedMut::new(&mut grad_u);
            let (av, ac, af) = (&*av, &*ac, &*af);
            let stencils =
                stages::stencils::<N>(self.simd, &pre.x, &origin, dx, par, &mut rws.grid.stencils);
            rws.grid.grad_axes[0].scatter(&tape.bins, par.on, nodes, |tile, p| {
                // SAFETY: each particle is visited exactly once.
                let (x_adj, fe_adj) = unsafe { (gx.get(p), gfe.get(p)) };
                let g = advance_reverse(&fe[p], &post.c[p], dt, x_adj, &av[p], &ac[p], &af[p]);
                *fe_adj = g.fe;
                let s = &stencils[p];
                // The gather's own velocity (a clamped particle's state holds the prescribed
                // one instead).
                let (grad_vel, gathered) = if clamped(p) {
                    // SAFETY: as above.
                    unsafe { *gu.get(p) = av[p] + dt * *x_adj };
                    let v = transfer::gather_affine(self.simd, s, &strides, grid_v, inv_d).0;
                    (Vector3::zeros(), v)
                } else {
                    (g.vel, post.v[p])
                };
                *x_adj += transfer::gather_affine_reverse(
                    self.simd, s, &strides, grid_v, inv_d, &grad_vel, &g.c, &gathered, tile,
                );
            });
        }
        grad_u
    }

    /// The grid update's reverse: the clamped nodes' adjoints go to their controls, then the
    /// effects backwards, then `v = p / m`, into `rws.grid.grad_nodes`. Returns dL/d(clamp values).
    fn grid_reverse(
        &self,
        tape: &StepTape,
        clamp_nodes: &[(usize, usize)],
        effects: &GridEffects,
        effect_params: &mut [Vec<f64>],
        rws: &mut Workspace,
    ) -> Vec<Vector3<f64>> {
        let (bins, par) = (&tape.bins, Parallel::for_particles(tape.pre.len()));
        let ctx = self.grid_context(&tape.grid_mass, tape.step);
        rws.grid.grad_axes[0].write_vectors(&mut rws.grid.grad_fields[0], bins, par.on);
        // The clamped nodes' velocities are the controls' values.
        let grad_grid_v = &mut rws.grid.grad_fields[0];
        let mut grad_clamp = vec![Vector3::zeros(); self.controls.effects.len()];
        for &(i, e) in clamp_nodes {
            grad_clamp[e] += grad_grid_v[i];
            grad_grid_v[i] = Vector3::zeros();
        }
        let grad_grid_v = &*grad_grid_v;
        grid_update_reverse(
            bins,
            par,
            effects,
            &ctx,
            |i| [tape.grid_v[i]],
            |i| [grad_grid_v[i]],
            &mut rws.grid.grad_nodes,
            effect_params,
        );
        grad_clamp
    }

    /// P2G reverse (a gather) and the stress's (P1), in batches of CHUNK particles (the
    /// material takes their stress differentials together), into `adj`. Returns dL/dFc and
    /// dL/d(scattered momentum) per particle (for the controls, when `values` are given).
    fn p2g_stress_reverse<const N: usize>(
        &self,
        tape: &StepTape,
        fc: Option<&[Matrix3<f64>]>,
        values: Option<&[Vector3<f64>]>,
        adj: &mut StateGrad,
        rws: &mut Workspace,
    ) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>)
    where
        Stencil<N>: Cached,
    {
        let pre = &tape.pre;
        let n = pre.len();
        let strides = self.grid.strides();
        let fe = &rws.fe;
        let clamped = |p: usize| values.is_some() && self.is_clamped(p);
        let StateGrad {
            x: ax,
            v: av,
            c: ac,
            f: af,
        } = adj;
        let retention = self.momentum_retention(tape.step);
        let body = values.map(|v| self.body_accelerations(v));
        let mut grad_fc = vec![Matrix3::zeros(); n];
        // dL/d(scattered momentum) per particle, for the controls.
        let mut grad_mom = vec![Vector3::zeros(); if values.is_some() { n } else { 0 }];
        let gm = SharedMut::new(&mut grad_mom);
        let par = Parallel::for_particles(n);
        rws.grid
            .grad_node_axes
            .set_from(&rws.grid.grad_nodes, &tape.bins, par.on);
        let (grad_nodes, grad_fe) = (&rws.grid.grad_node_axes, &rws.grad_fe);
        let stencils = &rws.grid.stencils.sized::<N>(n)[..];
        (
            ax.par_chunks_mut(CHUNK),
            av.par_chunks_mut(CHUNK),
            ac.par_chunks_mut(CHUNK),
            af.par_chunks_mut(CHUNK),
            grad_fc.par_chunks_mut(CHUNK),
        )
            .into_par_iter()
            .with_min_len(par.min_batches())
            .enumerate()
            .for_each(|(k, (gx, gv, gc, gf, gfc))| {
                let p0 = k * CHUNK;
                let len = gx.len();
                let mut grad_a = [Matrix3::zeros(); CHUNK];
                for i in 0..len {
                    let p = p0 + i;
                    let s = &stencils[p];
                    let m = self.mass[p];
                    let momentum = Affine {
                        value: self.particle_momentum(pre, values, body.as_deref(), retention, p),
                        slope: tape.affine[p],
                    };
                    let g = transfer::scatter_reverse(
                        self.simd,
                        s,
                        &strides,
                        m,
                        &[momentum],
                        grad_nodes,
                    );
                    gx[i] += g.x;
                    gv[i] = if clamped(p) {
                        Vector3::zeros()
                    } else {
                        (retention * m) * g.value[0]
                    };
                    if values.is_some() {
                        // SAFETY: each particle is visited exactly once.
                        unsafe { *gm.get(p) = g.value[0] };
                    }
                    grad_a[i] = g.slope[0];
                }
                let kept = tape.kept_of(p0..p0 + len, self.material.kept_per_particle());
                stages::stress_reverse(
                    self.material.as_ref(),
                    self.simd,
                    p0,
                    &fe[p0..p0 + len],
                    kept,
                    |p| self.stress_inputs(p),
                    &grad_a[..len],
                    |i, g_c, g_fe| {
                        gc[i] = g_c;
                        let total_fe = grad_fe[p0 + i] + g_fe;
                        (gf[i], gfc[i]) = self.control_reverse(tape, fc, p0 + i, &total_fe);
                    },
                );
            });
        (grad_fc, grad_mom)
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
