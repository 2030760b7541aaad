//! The interface every effect implements, for both integrators (the effects themselves are in
//! the `effects` module), and [`GridEffects`], the one place that runs them: the engine calls
//! these hooks and knows no effect by name.
//!
//! An effect acts on a grid node with mass through one hook pair, `apply_grid` and its reverse
//! `reverse_grid`, which both integrators call node by node. What the node's [`NodeMotion`]
//! holds is the integrator's [`GridForm`]: for the symplectic-Euler step the node's velocity
//! for this step (`v = p / m`), which an effect changes as one step of it would (gravity
//! `v += dt g`); for the ODE form (RK4) its velocity and acceleration, the rates an effect adds
//! to or projects (gravity `a += g`). Effects run in list order; the reverse runs them
//! backwards, each given what it saw as input (replayed from the node's first motion).
//!
//! One effect also has a particle hook, for the Euler step only: drag scales particle momentum
//! before P2G (`momentum_retention`, the reference code's form), where the ODE form states it
//! as the grid rate `a -= c v`.

use super::GridSpec;
use nalgebra::Vector3;

/// What the integrator hands an effect at a grid node, and so what [`NodeMotion`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridForm {
    /// The symplectic-Euler step: `v` is the node's velocity for the step, changed as one step
    /// of the effect would change it; `a` is zero and stays so.
    Step,
    /// The ODE form (RK4): `v` and `a` are the node's velocity and acceleration.
    Rate,
}

/// A grid node's motion as the effects see it (see [`GridForm`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NodeMotion {
    pub v: Vector3<f64>,
    pub a: Vector3<f64>,
}

/// What a grid effect may read: the integrator's form, the grid, nodal masses, the time step,
/// the global step index and the time (`step * dt` for the Euler step; the stage's time for
/// RK4).
pub struct GridContext<'a> {
    pub form: GridForm,
    pub spec: &'a GridSpec,
    pub mass: &'a [f64],
    pub dt: f64,
    pub step: usize,
    pub time: f64,
}

pub trait Effect: Send + Sync + std::fmt::Debug {
    fn name(&self) -> &'static str;

    /// Euler step only: factor applied to each particle's momentum `m v` in P2G of the step
    /// that starts at `time` (1 = no effect).
    fn momentum_retention(&self, _dt: f64, _time: f64) -> f64 {
        1.0
    }

    /// Whether [`Effect::apply_grid`] does anything in `form` (the others are not called).
    fn acts_on_grid(&self, _form: GridForm) -> bool {
        false
    }

    /// Forward, at grid node `node` (which has mass `ctx.mass[node] > 0`): change the node's
    /// motion as `ctx.form` says.
    fn apply_grid(&self, _ctx: &GridContext, _node: usize, _motion: &mut NodeMotion) {}

    /// Reverse of [`Effect::apply_grid`]: `input` is the motion the forward pass received;
    /// `grad` holds dL/d(its output) and is replaced by dL/d(its input); parameter gradients
    /// are added to `grad_params` (this node's share).
    fn reverse_grid(
        &self,
        _ctx: &GridContext,
        _node: usize,
        _input: &NodeMotion,
        _grad: &mut NodeMotion,
        _grad_params: &mut [f64],
    ) {
    }

    /// Potential energy of a conservative effect at these particle positions (gravity
    /// `-sum m g . x`), for energy reports; 0 for others.
    fn potential_energy(&self, _x: &[Vector3<f64>], _mass: &[f64]) -> f64 {
        0.0
    }

    /// Number of differentiable parameters.
    fn num_params(&self) -> usize {
        0
    }

    /// What this effect does to the Euler step's grid as plain data a device runs (none: the
    /// effect has no such description, and a device refuses a scene that has it on its grid).
    fn grid_rule(&self) -> Option<GridRule> {
        None
    }

    /// The boundary control this effect is, if it is one (driven by a controller's knots
    /// through [`crate::mpm::ControlPlan`] rather than by a grid hook).
    fn as_control(&self) -> Option<&crate::mpm::ControlEffect> {
        None
    }
}

/// A grid effect of the Euler step as plain data ([`Effect::grid_rule`]): what a device
/// applies to each node with mass, in the list's order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GridRule {
    /// `v += dt g`.
    Gravity([f64; 3]),
    /// Nodes within `thickness` cells of a face: every velocity component removed
    /// (`sticky`), or the one into the wall.
    Walls { sticky: bool, thickness: usize },
}

/// The effects that act on the grid in one form, in list order, with the layout of their
/// parameters' gradients: both integrators run the grid effects through it, forward and
/// reverse, so the sequencing is written once.
pub struct GridEffects<'a> {
    effects: &'a [Box<dyn Effect>],
    /// Indices into `effects` of those that act in this form.
    acting: Vec<usize>,
    /// Where each acting effect's parameters start in a node's row of gradients.
    offsets: Vec<usize>,
    /// Parameters of the acting effects together: the length of a node's row.
    width: usize,
}

impl<'a> GridEffects<'a> {
    pub fn new(effects: &'a [Box<dyn Effect>], form: GridForm) -> GridEffects<'a> {
        let acting: Vec<usize> = (0..effects.len())
            .filter(|&e| effects[e].acts_on_grid(form))
            .collect();
        let mut offsets = Vec::with_capacity(acting.len());
        let mut width = 0;
        for &e in &acting {
            offsets.push(width);
            width += effects[e].num_params();
        }
        GridEffects {
            effects,
            acting,
            offsets,
            width,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.acting.is_empty()
    }

    /// Parameters of the acting effects together (the length of a node's gradient row).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Forward at `node`: every acting effect in list order.
    #[inline]
    pub fn apply(&self, ctx: &GridContext, node: usize, motion: &mut NodeMotion) {
        for &e in &self.acting {
            self.effects[e].apply_grid(ctx, node, motion);
        }
    }

    /// Reverse at `node`, from the motion the first effect received (`input`): `grad` goes
    /// from dL/d(last output) to dL/d(input), and each effect's parameter gradients are added
    /// to its part of `params` (a row of [`GridEffects::width`]). Each effect's input is
    /// replayed from `input` (a few effects, each a few operations: cheaper than keeping them).
    pub fn reverse(
        &self,
        ctx: &GridContext,
        node: usize,
        input: &NodeMotion,
        grad: &mut NodeMotion,
        params: &mut [f64],
    ) {
        for k in (0..self.acting.len()).rev() {
            let mut seen = *input;
            for &e in &self.acting[..k] {
                self.effects[e].apply_grid(ctx, node, &mut seen);
            }
            let effect = &self.effects[self.acting[k]];
            let own = &mut params[self.offsets[k]..self.offsets[k] + effect.num_params()];
            effect.reverse_grid(ctx, node, &seen, grad, own);
        }
    }

    /// Adds rows of parameter gradients (one per node, [`GridEffects::width`] each) to each
    /// effect's gradients (`out`, one per effect of the list), in row order: the sum does not
    /// depend on how the rows were computed in parallel.
    pub fn add_rows(&self, rows: &[f64], out: &mut [Vec<f64>]) {
        if self.width == 0 {
            return;
        }
        for row in rows.chunks(self.width) {
            for (k, &e) in self.acting.iter().enumerate() {
                let own = &row[self.offsets[k]..];
                for (g, r) in out[e].iter_mut().zip(own) {
                    *g += r;
                }
            }
        }
    }
}
