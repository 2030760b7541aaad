//! The simulator: a scene's fixed data plus the step, its tape and its reverse pass.

use super::advance::{advance, advance_reverse};
use super::error::SimError;
use super::grid::{Bins, GridSpec, SharedMut};
use super::grid_update::{grid_velocity, grid_velocity_reverse};
use super::kernel::{KernelKind, Stencil};
use super::model::Model;
use super::state::{State, StateGrad};
use super::stress::StressInputs;
use super::transfer::{self, Affine, Node};
use crate::effects::{Effect, GridContext};
use crate::material::ConstitutiveModel;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// The symplectic-Euler MLS-MPM integrator over a [`Model`] (which it dereferences to).
#[derive(Debug)]
pub struct Simulator {
    pub model: Model,
}

impl std::ops::Deref for Simulator {
    type Target = Model;
    fn deref(&self) -> &Model {
        &self.model
    }
}

impl std::ops::DerefMut for Simulator {
    fn deref_mut(&mut self) -> &mut Model {
        &mut self.model
    }
}

impl From<Model> for Simulator {
    fn from(model: Model) -> Self {
        Simulator { model }
    }
}

/// Scratch buffers reused across steps.
#[derive(Default)]
pub struct Workspace {
    bins: Bins,
    nodes: Vec<Node<1>>,
    grid_v: Vec<Vector3<f64>>,
    fe: Vec<Matrix3<f64>>,
    affine: Vec<Matrix3<f64>>,
}

/// What the reverse pass needs from one forward step.
#[derive(Clone, Debug)]
pub struct StepTape {
    /// Particle state at the start of the step.
    pub pre: State,
    bins: Bins,
    /// Affine momentum `A` of each particle (saves recomputing the stress in reverse).
    affine: Vec<Matrix3<f64>>,
    grid_mass: Vec<f64>,
    /// Grid velocity `p / m`, before grid effects.
    grid_v: Vec<Vector3<f64>>,
    /// The global step index: the reverse pass gives time-dependent effects the same
    /// context the forward pass did.
    step: usize,
}

/// Recorded forward steps of a rollout, and the state after the last one.
#[derive(Clone, Debug, Default)]
pub struct Tape {
    pub steps: Vec<StepTape>,
    pub last: State,
}

/// Result of [`Simulator::backward`].
#[derive(Clone, Debug)]
pub struct Gradients {
    /// dL/d(initial state).
    pub initial: StateGrad,
    /// dL/dFc per step, for the steps whose control was given.
    pub controls: Vec<Option<Vec<Matrix3<f64>>>>,
    /// dL/d(parameters) of each effect, in scene order.
    pub effect_params: Vec<Vec<f64>>,
}

/// Control `Fc` for local step `s`, if any.
fn control_at(controls: &[Option<Vec<Matrix3<f64>>>], s: usize) -> Option<&[Matrix3<f64>]> {
    controls.get(s).and_then(|c| c.as_deref())
}

impl Simulator {
    /// Validates the scene (see [`Model::new`]) and makes its Euler integrator.
    pub fn new(
        grid: GridSpec,
        dt: f64,
        kernel: KernelKind,
        material: Arc<dyn ConstitutiveModel>,
        effects: Vec<Box<dyn Effect>>,
        mass: Vec<f64>,
        volume: Vec<f64>,
    ) -> Result<Simulator, SimError> {
        Model::new(grid, dt, kernel, material, effects, mass, volume).map(Simulator::from)
    }

    fn stress_inputs(&self, p: usize) -> StressInputs<'_> {
        StressInputs {
            model: self.material.as_ref(),
            mass: self.mass[p],
            volume: self.volume[p],
            dt: self.dt,
            inv_d: self.inv_d(),
        }
    }

    /// Product of the effects' momentum factors (1 when no drag is on).
    fn momentum_retention(&self) -> f64 {
        self.effects
            .iter()
            .map(|e| e.momentum_retention(self.dt))
            .product()
    }

    fn check_state(&self, state: &State, step: usize) -> Result<(), SimError> {
        self.check_size(state.len())?;
        self.check_finite_and_cfl(state.first_non_finite(), &state.v, step)
    }

    /// Advances `state` by one step with optional controls `fc` (per particle, added to F).
    /// `step` is the global step index (time-dependent effects read it; errors name it).
    pub fn step(
        &self,
        state: &mut State,
        fc: Option<&[Matrix3<f64>]>,
        step: usize,
        ws: &mut Workspace,
    ) -> Result<(), SimError> {
        match self.kernel {
            KernelKind::Quadratic => self.step_impl::<3>(state, fc, step, ws, None),
            KernelKind::Cubic => self.step_impl::<4>(state, fc, step, ws, None),
        }
    }

    /// Runs `n_steps` steps from `state`; `controls[s]` (if present and `Some`) is the `Fc` of
    /// local step `s`. Records a tape for [`Simulator::backward`] when `tape` is given.
    pub fn forward(
        &self,
        state: &mut State,
        controls: &[Option<Vec<Matrix3<f64>>>],
        first_step: usize,
        n_steps: usize,
        mut tape: Option<&mut Tape>,
    ) -> Result<(), SimError> {
        let mut ws = Workspace::default();
        if let Some(t) = tape.as_deref_mut() {
            t.steps.clear();
        }
        self.check_state(state, first_step)?;
        for s in 0..n_steps {
            let fc = control_at(controls, s);
            let rec = tape.as_deref_mut().map(|t| &mut t.steps);
            match self.kernel {
                KernelKind::Quadratic => {
                    self.step_impl::<3>(state, fc, first_step + s, &mut ws, rec)?
                }
                KernelKind::Cubic => {
                    self.step_impl::<4>(state, fc, first_step + s, &mut ws, rec)?
                }
            }
        }
        if let Some(t) = tape {
            t.last = state.clone();
        }
        Ok(())
    }

    fn step_impl<const N: usize>(
        &self,
        state: &mut State,
        fc: Option<&[Matrix3<f64>]>,
        step: usize,
        ws: &mut Workspace,
        tape: Option<&mut Vec<StepTape>>,
    ) -> Result<(), SimError> {
        self.check_size(state.len())?;
        self.check_control(fc, step)?;
        let n = state.len();
        let dt = self.dt;
        let inv_d = self.inv_d();
        let strides = self.grid.strides();
        let origin = self.grid.origin_vec();
        let dx = self.grid.dx;
        ws.bins = Bins::build(&self.grid, &state.x, N, step)?;

        // P1: elastic gradient, stress (batched across particles) and affine momentum.
        ws.fe.resize(n, Matrix3::zeros());
        ws.affine.resize(n, Matrix3::zeros());
        ws.fe.par_iter_mut().enumerate().for_each(|(p, fe)| {
            *fe = match fc {
                Some(fc) => state.f[p] + fc[p],
                None => state.f[p],
            };
        });
        const CHUNK: usize = 64;
        ws.affine
            .par_chunks_mut(CHUNK)
            .zip(ws.fe.par_chunks(CHUNK))
            .enumerate()
            .for_each(|(k, (a, fe))| {
                self.material.stress_batch(fe, a);
                for (i, (a, fe)) in a.iter_mut().zip(fe).enumerate() {
                    let p = k * CHUNK + i;
                    *a = self.stress_inputs(p).affine_from_stress(&state.c[p], fe, a);
                }
            });

        // P2G (coloured scatter).
        ws.nodes.clear();
        ws.nodes.resize(self.grid.node_count(), Node::ZERO);
        let retention = self.momentum_retention();
        {
            let nodes = SharedMut::new(&mut ws.nodes);
            let (affine, mass) = (&ws.affine, &self.mass);
            ws.bins.for_each_coloured(|p| {
                let s = Stencil::<N>::new(&state.x[p], &origin, dx);
                let momentum = Affine {
                    value: (retention * mass[p]) * state.v[p],
                    slope: affine[p],
                };
                transfer::scatter(&s, &strides, mass[p], &[momentum], &nodes);
            });
        }

        // G: grid velocity, then effects.
        ws.grid_v.resize(self.grid.node_count(), Vector3::zeros());
        grid_velocity(&ws.nodes, &mut ws.grid_v);
        let has_grid_effects = self.effects.iter().any(|e| e.acts_on_grid());
        // Nodal masses alone: the tape and the grid effects need them.
        let grid_mass: Vec<f64> = if tape.is_some() || has_grid_effects {
            ws.nodes.par_iter().map(|n| n.mass).collect()
        } else {
            Vec::new()
        };
        let grid_v_pre = if tape.is_some() {
            ws.grid_v.clone()
        } else {
            Vec::new()
        };
        if has_grid_effects {
            let ctx = GridContext {
                spec: &self.grid,
                mass: &grid_mass,
                dt,
                step,
                time: step as f64 * dt,
            };
            for e in self.effects.iter().filter(|e| e.acts_on_grid()) {
                e.apply_grid(&ctx, &mut ws.grid_v);
            }
        }
        if let Some(tape) = tape {
            tape.push(StepTape {
                pre: state.clone(),
                bins: ws.bins.clone(),
                affine: ws.affine.clone(),
                grid_mass,
                grid_v: grid_v_pre,
                step,
            });
        }

        // G2P and P2 (per-particle gather, in place).
        let grid_v = &ws.grid_v;
        let fe = &ws.fe;
        let State { x, v, c, f } = state;
        x.par_iter_mut()
            .zip(v.par_iter_mut())
            .zip(c.par_iter_mut().zip(f.par_iter_mut()))
            .enumerate()
            .for_each(|(p, ((x, v), (c, f)))| {
                let s = Stencil::<N>::new(x, &origin, dx);
                let (vel, cn) = transfer::gather_affine(&s, &strides, grid_v, inv_d);
                let (xn, fnew) = advance(x, &fe[p], &vel, &cn, dt);
                *x = xn;
                *v = vel;
                *c = cn;
                *f = fnew;
            });
        self.check_finite_and_cfl(state.first_non_finite(), &state.v, step)
    }

    /// Reverse pass over a taped rollout. `grad_last` is dL/d(state after the last step);
    /// `controls` must be the ones the forward pass used.
    pub fn backward(
        &self,
        tape: &Tape,
        controls: &[Option<Vec<Matrix3<f64>>>],
        grad_last: StateGrad,
    ) -> Gradients {
        let mut adj = grad_last;
        let mut grad_controls = vec![None; tape.steps.len()];
        let mut effect_params: Vec<Vec<f64>> = self
            .effects
            .iter()
            .map(|e| vec![0.0; e.num_params()])
            .collect();
        for s in (0..tape.steps.len()).rev() {
            let post = if s + 1 < tape.steps.len() {
                &tape.steps[s + 1].pre
            } else {
                &tape.last
            };
            let fc = control_at(controls, s);
            let g = match self.kernel {
                KernelKind::Quadratic => {
                    self.reverse_impl::<3>(&tape.steps[s], post, fc, &mut adj, &mut effect_params)
                }
                KernelKind::Cubic => {
                    self.reverse_impl::<4>(&tape.steps[s], post, fc, &mut adj, &mut effect_params)
                }
            };
            if fc.is_some() {
                grad_controls[s] = Some(g);
            }
        }
        Gradients {
            initial: adj,
            controls: grad_controls,
            effect_params,
        }
    }

    /// Reverse of one step: turns `adj` from dL/d(post) into dL/d(pre) and returns dL/dFc.
    fn reverse_impl<const N: usize>(
        &self,
        tape: &StepTape,
        post: &State,
        fc: Option<&[Matrix3<f64>]>,
        adj: &mut StateGrad,
        effect_params: &mut [Vec<f64>],
    ) -> Vec<Matrix3<f64>> {
        let pre = &tape.pre;
        let n = pre.len();
        let dt = self.dt;
        let inv_d = self.inv_d();
        let strides = self.grid.strides();
        let origin = self.grid.origin_vec();
        let dx = self.grid.dx;
        let fe: Vec<Matrix3<f64>> = (0..n)
            .into_par_iter()
            .map(|p| match fc {
                Some(fc) => pre.f[p] + fc[p],
                None => pre.f[p],
            })
            .collect();

        // Replay the grid effects to recover each one's input velocity.
        let ctx = GridContext {
            spec: &self.grid,
            mass: &tape.grid_mass,
            dt,
            step: tape.step,
            time: tape.step as f64 * dt,
        };
        let grid_effects: Vec<usize> = (0..self.effects.len())
            .filter(|&e| self.effects[e].acts_on_grid())
            .collect();
        let mut effect_inputs = Vec::with_capacity(grid_effects.len());
        let mut grid_v = tape.grid_v.clone();
        for &e in &grid_effects {
            effect_inputs.push(grid_v.clone());
            self.effects[e].apply_grid(&ctx, &mut grid_v);
        }

        // P2 reverse.
        let mut grad_fe = vec![Matrix3::zeros(); n];
        let mut grad_vel = vec![Vector3::zeros(); n];
        let mut grad_cn = vec![Matrix3::zeros(); n];
        (
            grad_fe.par_iter_mut(),
            grad_vel.par_iter_mut(),
            grad_cn.par_iter_mut(),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(p, (gfe, gv, gc))| {
                let g = advance_reverse(
                    &fe[p], &post.c[p], dt, &adj.x[p], &adj.v[p], &adj.c[p], &adj.f[p],
                );
                *gfe = g.fe;
                *gv = g.vel;
                *gc = g.c;
            });

        // G2P reverse (coloured scatter into the grid velocity adjoint).
        let mut grad_grid_v = vec![Vector3::zeros(); self.grid.node_count()];
        {
            let ggv = SharedMut::new(&mut grad_grid_v);
            let gx = SharedMut::new(&mut adj.x);
            tape.bins.for_each_coloured(|p| {
                let s = Stencil::<N>::new(&pre.x[p], &origin, dx);
                let d = transfer::gather_affine_reverse(
                    &s,
                    &strides,
                    &grid_v,
                    inv_d,
                    &grad_vel[p],
                    &grad_cn[p],
                    &post.v[p],
                    &ggv,
                );
                // SAFETY: each particle is visited exactly once.
                unsafe { *gx.get(p) += d };
            });
        }

        // G reverse: effects backwards, then v = p / m.
        for (k, &e) in grid_effects.iter().enumerate().rev() {
            self.effects[e].reverse_grid(
                &ctx,
                &effect_inputs[k],
                &mut grad_grid_v,
                &mut effect_params[e],
            );
        }
        let mut grad_nodes = vec![Node::ZERO; self.grid.node_count()];
        grid_velocity_reverse(&tape.grid_mass, &tape.grid_v, &grad_grid_v, &mut grad_nodes);

        // P2G reverse (gather) and P1 reverse.
        let retention = self.momentum_retention();
        let mut grad_fc = vec![Matrix3::zeros(); n];
        let StateGrad {
            x: ax,
            v: av,
            c: ac,
            f: af,
        } = adj;
        (
            ax.par_iter_mut(),
            av.par_iter_mut(),
            ac.par_iter_mut(),
            af.par_iter_mut(),
            grad_fc.par_iter_mut(),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(p, (gx, gv, gc, gf, gfc))| {
                let inputs = self.stress_inputs(p);
                let affine = tape.affine[p];
                let s = Stencil::<N>::new(&pre.x[p], &origin, dx);
                let m = self.mass[p];
                let momentum = Affine {
                    value: (retention * m) * pre.v[p],
                    slope: affine,
                };
                let g = transfer::scatter_reverse(&s, &strides, m, &[momentum], &grad_nodes);
                let (g_c, g_fe) = inputs.affine_momentum_reverse(&fe[p], &g.slope[0]);
                *gx += g.x;
                *gv = (retention * m) * g.value[0];
                *gc = g_c;
                let total_fe = grad_fe[p] + g_fe;
                *gf = total_fe;
                *gfc = total_fe;
            });
        grad_fc
    }
}
