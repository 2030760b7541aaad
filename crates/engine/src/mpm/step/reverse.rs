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
        rws: &mut ReverseWorkspace,
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
        rws: &mut ReverseWorkspace,
    ) -> Vec<(usize, usize)>
    where
        Stencil<N>: Cached,
    {
        let pre = &tape.pre;
        let form = self.control_form;
        rws.fe.resize(pre.len(), Matrix3::zeros());
        rws.fe.par_iter_mut().enumerate().for_each(|(p, fe)| {
            *fe = match fc {
                Some(fc) => form.apply_scaled(&pre.f[p], &fc[p], scale_of(&tape.scale, p)),
                None => pre.f[p],
            }
        });
        let ctx = self.grid_context(&tape.grid_mass, tape.step);
        rws.grid_v.clone_from(&tape.grid_v);
        apply_grid_effects(effects, &ctx, &mut rws.grid_v);
        let clamp_nodes = match values {
            Some(vals) => {
                let nodes = self.clamp_nodes::<N>(&pre.x);
                for &(i, e) in &nodes {
                    rws.grid_v[i] = vals[e];
                }
                nodes
            }
            None => Vec::new(),
        };
        rws.grid_axes.set_from(&rws.grid_v);
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
        rws: &mut ReverseWorkspace,
    ) -> Vec<Vector3<f64>>
    where
        Stencil<N>: Cached,
    {
        let pre = &tape.pre;
        let n = pre.len();
        let nodes = self.grid.node_count();
        let (dt, inv_d) = (self.dt, self.inv_d());
        let (strides, origin, dx) = (self.grid.strides(), self.grid.origin_vec(), self.grid.dx);
        let (fe, grid_v) = (&rws.fe, &rws.grid_axes);
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
                stages::stencils::<N>(self.simd, &pre.x, &origin, dx, 1, &mut rws.stencils);
            rws.grad_axes.scatter(&tape.bins, true, nodes, |tile, p| {
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
    /// effects backwards, then `v = p / m`, into `rws.grad_nodes`. Returns dL/d(clamp values).
    fn grid_reverse(
        &self,
        tape: &StepTape,
        clamp_nodes: &[(usize, usize)],
        effects: &GridEffects,
        effect_params: &mut [Vec<f64>],
        rws: &mut ReverseWorkspace,
    ) -> Vec<Vector3<f64>> {
        let ctx = self.grid_context(&tape.grid_mass, tape.step);
        rws.grad_axes.write_vectors(&mut rws.grad_grid_v);
        // The clamped nodes' velocities are the controls' values.
        let grad_grid_v = &mut rws.grad_grid_v;
        let mut grad_clamp = vec![Vector3::zeros(); self.controls.effects.len()];
        for &(i, e) in clamp_nodes {
            grad_clamp[e] += grad_grid_v[i];
            grad_grid_v[i] = Vector3::zeros();
        }
        reverse_grid_effects(effects, &ctx, &tape.grid_v, grad_grid_v, effect_params);
        rws.grad_nodes.resize(self.grid.node_count(), Node::ZERO);
        grid_velocity_reverse(
            &tape.grid_mass,
            &tape.grid_v,
            grad_grid_v,
            &mut rws.grad_nodes,
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
        rws: &mut ReverseWorkspace,
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
        rws.grad_node_axes.set_from(&rws.grad_nodes);
        let (grad_nodes, grad_fe) = (&rws.grad_node_axes, &rws.grad_fe);
        let stencils = &rws.stencils.sized::<N>(n)[..];
        (
            ax.par_chunks_mut(CHUNK),
            av.par_chunks_mut(CHUNK),
            ac.par_chunks_mut(CHUNK),
            af.par_chunks_mut(CHUNK),
            grad_fc.par_chunks_mut(CHUNK),
        )
            .into_par_iter()
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
