//! The symplectic-Euler step as a [`Form`] of the one pipeline (see [`crate::mpm::pipeline`]):
//! one field a node (APIC momentum `m v + A (x_i - x_p)`, the stress folded into `A`), the
//! effects as one step of them, the clamped nodes held at their controls' velocities, and a
//! gather that advances each particle in place.

use super::*;
use crate::mpm::pipeline::{Form, Forward, GridView};

/// The particle buffers of a step, forward and reverse.
#[derive(Default)]
pub(super) struct ParticleScratch {
    /// Each particle's elastic gradient `Fe` (the control applied), and its adjoint.
    pub fe: Vec<Matrix3<f64>>,
    pub grad_fe: Vec<Matrix3<f64>>,
    pub affine: Vec<Matrix3<f64>>,
    pub kept: Vec<f64>,
    pub scale: Vec<f64>,
}

/// One forward step of `state` (in place).
pub(super) struct StepPass<'a> {
    pub euler: &'a Euler,
    pub state: &'a mut State,
    pub fc: Option<&'a [Matrix3<f64>]>,
    pub values: Option<&'a [Vector3<f64>]>,
    pub body: Option<Vec<Vector3<f64>>>,
    pub retention: f64,
    pub step: usize,
    pub buf: &'a mut ParticleScratch,
    pub tape: Option<&'a mut Vec<StepTape>>,
    /// The nodal masses and velocities before the effects, for the tape.
    pub taped_grid: (Vec<f64>, Vec<Vector3<f64>>),
}

impl Form<1> for StepPass<'_> {
    const GRID: GridForm = GridForm::Step;

    fn positions(&self) -> &[Vector3<f64>] {
        &self.state.x
    }
    fn step(&self) -> usize {
        self.step
    }
    fn time(&self) -> f64 {
        self.step as f64 * self.euler.dt
    }
    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        self.euler.stress_inputs(p)
    }
    fn fields(&self, p: usize) -> [Affine; 1] {
        let (e, body) = (self.euler, self.body.as_deref());
        [Affine {
            value: e.particle_momentum(self.state, self.values, body, self.retention, p),
            slope: self.buf.affine[p],
        }]
    }
    fn control_values(&self) -> Option<&[Vector3<f64>]> {
        self.values
    }
}

impl Forward<1> for StepPass<'_> {
    /// P1: each particle's elastic gradient (the control applied), its stress (batched
    /// across particles) and its affine momentum; taped, what spares the reverse pass
    /// recomputing the stress.
    fn stress(&mut self, par: Parallel) {
        let (e, n, buf) = (self.euler, self.state.len(), &mut *self.buf);
        buf.fe.resize(n, Matrix3::zeros());
        buf.affine.resize(n, Matrix3::zeros());
        let keep = match self.tape {
            Some(_) => e.material.kept_per_particle(),
            None => 0,
        };
        buf.kept.resize(n * keep, 0.0);
        let (form, fc, f) = (e.control_form, self.fc, &self.state.f);
        // The plastic form's volume factors (kept on the tape: its reverse needs them twice).
        buf.scale.clear();
        if let (Some(fc), ControlForm::Plastic) = (fc, form) {
            let scales = fc.par_iter().with_min_len(par.min_len());
            buf.scale.par_extend(scales.map(|fc| form.scale(fc)));
        }
        let scale = &buf.scale;
        stages::stress_of(
            e.material.as_ref(),
            e.simd,
            |p| match fc {
                Some(fc) => form.apply_scaled(&f[p], &fc[p], scale_of(scale, p)),
                None => f[p],
            },
            &mut buf.fe,
            Some(&self.state.c),
            |p| e.stress_inputs(p),
            par,
            &mut buf.affine,
            &mut buf.kept,
        );
    }

    fn quotients_seen(&mut self, mass: &[f64], fields: &[Vec<Vector3<f64>>; 1]) {
        if self.tape.is_some() {
            self.taped_grid = (par_copy(mass), par_copy(&fields[0]));
        }
    }

    fn record(&mut self, bins: &Bins) -> bool {
        let Some(tape) = self.tape.as_deref_mut() else {
            return false;
        };
        let (grid_mass, grid_v) = std::mem::take(&mut self.taped_grid);
        tape.push(StepTape {
            pre: self.state.par_clone(),
            bins: bins.clone(),
            affine: par_copy(&self.buf.affine),
            kept: std::mem::take(&mut self.buf.kept),
            scale: std::mem::take(&mut self.buf.scale),
            grid_mass,
            grid_v,
            step: self.step,
        });
        true
    }

    /// G2P and P2: a per-particle gather of the grid velocity and its gradient, then the
    /// particle update, in place.
    fn gather<const N: usize>(&mut self, grid: GridView<N, 1>, par: Parallel) {
        let e = self.euler;
        let (dt, inv_d, strides) = (e.dt, e.inv_d(), e.grid.strides());
        let (fe, values, grid_v) = (&self.buf.fe, self.values, grid.velocity);
        let State { x, v, c, f } = &mut *self.state;
        x.par_iter_mut()
            .zip(v.par_iter_mut())
            .zip(c.par_iter_mut().zip(f.par_iter_mut()))
            .enumerate()
            .with_min_len(par.min_len())
            .for_each(|(p, ((x, v), (c, f)))| {
                let s = &grid.stencils[p];
                let (mut vel, mut cn) = transfer::gather_affine(e.simd, s, &strides, grid_v, inv_d);
                if let Some(u) = values.and_then(|vals| e.prescribed_velocity(vals, p)) {
                    vel = u;
                    cn = Matrix3::zeros();
                }
                let (xn, fnew) = advance(x, &fe[p], &vel, &cn, dt);
                *x = xn;
                *v = vel;
                *c = cn;
                *f = fnew;
            });
    }
}
