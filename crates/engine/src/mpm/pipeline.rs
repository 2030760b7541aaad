//! The one orchestration of the stages, forward and reverse, for both integrators. The
//! symplectic-Euler step is one forward pass ([`super::step`]); the ODE form's right-hand side
//! is one too ([`crate::ode::rhs`]), and an RK4 step four of them. What differs between the
//! two is a [`Form`] of `K` fields a node, the one type parameter of the pipeline: what a
//! particle scatters (APIC momentum; or momentum and force), how the effects read the grid
//! (a step, or rates), and what the gather makes of the grid (the next state; or the state's
//! rates). The clamps follow one rule for both ([`hold_clamps`]).
//!
//! Forward: bins, P1 the stress, stencils and P2G, G the grid update (quotients, effects,
//! clamps), G2P with the form's particle update.
//! Reverse, after the integrator has put the forward's grid back (from its tape, or by
//! running the forward again): G2P's reverse (a scatter into the `K` field adjoints), G's
//! (the clamps, the effects backwards, the quotients), P2G's with P1's (a gather, then the
//! stress differential in batches).

use super::effect::{GridContext, GridEffects, GridForm};
use super::error::SimError;
use super::grid::{Bins, Tile};
use super::grid_update::{apply_grid_effects, grid_quotients, grid_update_reverse};
use super::kernel::{Cached, Stencil};
use super::model::Model;
use super::profile::{Laps, Stage};
use super::scratch::GridScratch;
use super::stages::{self, CHUNK, Parallel};
use super::stress::StressInputs;
use super::transfer::{self, Affine, AxisField, AxisNodes, Node, ScatterGrad};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// The grid as the gather reads it: every particle's stencil, the velocity by axis, and
/// the `K` fields.
pub struct GridView<'g, const N: usize, const K: usize> {
    pub stencils: &'g [Stencil<N>],
    pub velocity: &'g AxisField,
    pub fields: &'g [Vec<Vector3<f64>>; K],
}

/// What both directions of one integrator's pass share.
pub trait Form<const K: usize>: Sync {
    /// How the grid effects read the fields.
    const GRID: GridForm;

    /// The particles' positions this pass transfers from.
    fn positions(&self) -> &[Vector3<f64>];
    /// The global step (time-dependent effects read it; errors name it).
    fn step(&self) -> usize;
    /// The time the grid effects see.
    fn time(&self) -> f64;
    /// What the stress stage of particle `p` takes (its mass and the step's factor).
    fn stress_inputs(&self, p: usize) -> StressInputs<'_>;
    /// The `K` fields particle `p` scatters (after the stress stage).
    fn fields(&self, p: usize) -> [Affine; K];
    /// The nodal masses the effects see, given those P2G made (a replay reads its tape's).
    fn grid_masses<'g>(&'g self, scattered: &'g [f64]) -> &'g [f64] {
        scattered
    }
    /// The boundary controls' values in this pass (what the clamps hold; none: no
    /// clamp acts).
    fn control_values(&self) -> Option<&[Vector3<f64>]>;
}

/// The forward stages' own parts of a form.
pub trait Forward<const K: usize>: Form<K> {
    /// P1: every particle's stress, into the form's own buffers.
    fn stress(&mut self, par: Parallel);
    /// G, first part seen: the quotients before the effects (a tape keeps them).
    fn quotients_seen(&mut self, _mass: &[f64], _fields: &[Vec<Vector3<f64>>; K]) {}
    /// After G: records what the reverse pass needs; whether it did.
    fn record(&mut self, _bins: &Bins) -> bool {
        false
    }
    /// G2P and the particle update.
    fn gather<const N: usize>(&mut self, grid: GridView<N, K>, par: Parallel);
}

/// The reverse stages' own parts of a form: each particle's adjoints are the form's to keep
/// (every call is for one particle, which no other call touches).
pub trait Reverse<const K: usize>: Form<K> {
    /// Reverse of G2P and the particle update for particle `p`: scatters dL/d(fields) into
    /// `tile` (channel `3 k + j`: field `k`'s axis `j`).
    fn gather_reverse<const N: usize>(&self, p: usize, grid: &GridView<N, K>, tile: &mut Tile);
    /// Node `i`'s quotients as the effects received them.
    fn grid_input(&self, nodes: &[Node<K>], i: usize) -> [Vector3<f64>; K];
    /// Reverse of P2G for particle `p` from what its fields gathered; returns dL/d(the
    /// slope the stress makes).
    fn scatter_reverse(&self, p: usize, g: &ScatterGrad<K>) -> Matrix3<f64>;
    /// The elastic gradients of particles `range` (what the stress took), and what the
    /// stress stage kept of them (empty: none).
    fn elastic(&self, range: std::ops::Range<usize>) -> (&[Matrix3<f64>], &[f64]);
    /// Reverse of P1 for particle `p`: dL/dC and dL/dFe.
    fn stress_reverse(&self, p: usize, grad_c: Matrix3<f64>, grad_fe: Matrix3<f64>);
}

/// The context the effects see in `form`'s pass, given the nodal masses.
pub fn context<'a, const K: usize, F: Form<K>>(
    model: &'a Model,
    form: &F,
    mass: &'a [f64],
) -> GridContext<'a> {
    GridContext {
        form: F::GRID,
        spec: &model.grid,
        mass,
        dt: model.dt,
        step: form.step(),
        time: form.time(),
    }
}

/// One forward pass of `form` (see the module's note), in `bins` and `grid`.
pub fn forward<const N: usize, const K: usize, F: Forward<K>>(
    model: &Model,
    form: &mut F,
    bins: &mut Bins,
    grid: &mut GridScratch<K>,
    laps: &mut Laps,
) -> Result<(), SimError>
where
    Stencil<N>: Cached,
{
    let n = form.positions().len();
    let par = Parallel::for_particles(n);
    *bins = Bins::build(&model.grid, form.positions(), N, form.step())?;
    laps.lap(Stage::Bins);
    form.stress(par);
    laps.lap(Stage::Stress);
    let (origin, dx) = (model.grid.origin_vec(), model.grid.dx);
    let GridScratch {
        nodes,
        node_axes,
        stencils,
        ..
    } = grid;
    let stencils = stages::stencils::<N>(model.simd, form.positions(), &origin, dx, par, stencils);
    let node_count = model.grid.node_count();
    let fields = |p| form.fields(p);
    stages::p2g(
        model.simd,
        bins,
        stencils,
        &model.mass,
        par,
        fields,
        node_axes,
        nodes,
        node_count,
    );
    laps.lap(Stage::P2g);
    grid_quotients(
        bins,
        par,
        &grid.nodes,
        &mut grid.mass,
        grid.fields.each_mut(),
    );
    form.quotients_seen(&grid.mass, &grid.fields);
    effects_and_boundary::<N, K, F>(model, form, bins, par, grid);
    laps.lap(Stage::Grid);
    if form.record(bins) {
        laps.lap(Stage::Tape);
    }
    let stencils = &grid.stencils.sized::<N>(n)[..];
    let view = GridView {
        stencils,
        velocity: &grid.velocity_axes,
        fields: &grid.fields,
    };
    form.gather(view, par);
    laps.lap(Stage::G2p);
    Ok(())
}

/// G after the quotients (in `grid.fields`), forward and in a replay: the effects, the
/// clamps (see [`hold_clamps`]), and the velocity by axis for the gather.
pub fn effects_and_boundary<const N: usize, const K: usize, F: Form<K>>(
    model: &Model,
    form: &mut F,
    bins: &Bins,
    par: Parallel,
    grid: &mut GridScratch<K>,
) where
    Stencil<N>: Cached,
{
    let effects = GridEffects::new(&model.effects, F::GRID);
    let ctx = context(model, form, form.grid_masses(&grid.mass));
    let fields = grid.fields.each_mut().map(|f| &mut f[..]);
    apply_grid_effects(bins, par, &effects, &ctx, fields);
    let (x, values) = (form.positions(), form.control_values());
    grid.held = hold_clamps::<N, K>(model, x, values, &mut grid.fields);
    grid.velocity_axes.set_from(&grid.fields[0], bins, par.on);
}

/// One reverse pass of `form`, once `grid` holds its forward's (see the module's note):
/// the form keeps the particles' adjoints; the effects' parameter adjoints are added to
/// `effect_params`. Returns dL/d(each control's value) through the nodes its clamp held.
pub fn reverse<const N: usize, const K: usize, F: Reverse<K>>(
    model: &Model,
    form: &mut F,
    bins: &Bins,
    grid: &mut GridScratch<K>,
    effect_params: &mut [Vec<f64>],
    laps: &mut Laps,
) -> Vec<Vector3<f64>>
where
    Stencil<N>: Cached,
{
    let n = form.positions().len();
    let par = Parallel::for_particles(n);
    gather_reverse::<N, K, F>(model, form, bins, par, grid);
    laps.lap(Stage::RevG2p);
    let grad_held = grid_reverse(model, form, bins, par, grid, effect_params);
    laps.lap(Stage::RevGrid);
    grid.grad_node_axes.set_from(&grid.grad_nodes, bins, par.on);
    let stencils = &grid.stencils.sized::<N>(n)[..];
    scatter_and_stress_reverse(model, form, par, stencils, &grid.grad_node_axes);
    laps.lap(Stage::RevP2gStress);
    grad_held
}

/// G2P's reverse: every particle's [`Form::gather_reverse`], block by block into tiles,
/// then summed into `grid.grad_fields`.
fn gather_reverse<const N: usize, const K: usize, F: Reverse<K>>(
    model: &Model,
    form: &F,
    bins: &Bins,
    par: Parallel,
    grid: &mut GridScratch<K>,
) where
    Stencil<N>: Cached,
{
    let nodes = model.grid.node_count();
    let GridScratch {
        fields,
        velocity_axes,
        stencils,
        grad_fields,
        grad_axes,
        ..
    } = grid;
    let stencils = &stencils.sized::<N>(form.positions().len())[..];
    let view = GridView {
        stencils,
        velocity: velocity_axes,
        fields,
    };
    // Tile channel 3 k + j: field k's axis j.
    let mut tiles = std::mem::take(&mut grad_axes[0].tiles);
    let mut out: Vec<&mut [f64]> = Vec::with_capacity(3 * K);
    for field in grad_axes.iter_mut() {
        for axis in field.axes.iter_mut() {
            axis.resize(nodes, 0.0);
            out.push(axis);
        }
    }
    bins.scatter(par.on, &mut tiles, &mut out, |tile, p| {
        form.gather_reverse(p, &view, tile)
    });
    grad_axes[0].tiles = tiles;
    for (axes, out) in grad_axes.iter().zip(grad_fields.iter_mut()) {
        axes.write_vectors(out, bins, par.on);
    }
}

/// G's reverse: the clamps', then the effects backwards and the quotients', into
/// `grid.grad_nodes`.
fn grid_reverse<const K: usize, F: Reverse<K>>(
    model: &Model,
    form: &mut F,
    bins: &Bins,
    par: Parallel,
    grid: &mut GridScratch<K>,
    effect_params: &mut [Vec<f64>],
) -> Vec<Vector3<f64>> {
    let GridScratch {
        nodes,
        mass,
        held,
        grad_fields,
        grad_nodes,
        ..
    } = grid;
    let grad_held = release_clamps(model, held, grad_fields);
    let effects = GridEffects::new(&model.effects, F::GRID);
    let ctx = context(model, form, form.grid_masses(mass));
    grid_update_reverse(
        bins,
        par,
        &effects,
        &ctx,
        |i| form.grid_input(nodes, i),
        |i| std::array::from_fn(|k| grad_fields[k][i]),
        grad_nodes,
        effect_params,
    );
    grad_held
}

/// P2G's reverse (a gather of the node adjoints) and P1's, in batches of [`CHUNK`]
/// particles (the material takes their stress differentials together).
fn scatter_and_stress_reverse<const N: usize, const K: usize, F: Reverse<K>>(
    model: &Model,
    form: &F,
    par: Parallel,
    stencils: &[Stencil<N>],
    grad_nodes: &AxisNodes<K>,
) {
    let n = form.positions().len();
    let strides = model.grid.strides();
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .with_min_len(par.min_batches())
        .for_each(|k| {
            let range = k * CHUNK..((k + 1) * CHUNK).min(n);
            let mut grad_slope = [Matrix3::zeros(); CHUNK];
            for (p, g_slope) in range.clone().zip(&mut grad_slope) {
                let (m, fields) = (model.mass[p], form.fields(p));
                let g = transfer::scatter_reverse(
                    model.simd,
                    &stencils[p],
                    &strides,
                    m,
                    &fields,
                    grad_nodes,
                );
                *g_slope = form.scatter_reverse(p, &g);
            }
            let (fe, kept) = form.elastic(range.clone());
            stages::stress_reverse(
                model.material.as_ref(),
                model.simd,
                range.start,
                fe,
                kept,
                |p| form.stress_inputs(p),
                &grad_slope[..range.len()],
                |i, g_c, g_fe| form.stress_reverse(range.start + i, g_c, g_fe),
            );
        });
}

/// The one clamp rule, a grid boundary condition: every node in a clamped particle's stencil
/// (at `x`) moves with its control, `v_i = u` (and `a_i = 0` in the ODE form), after the
/// effects. A clamp that only overrode its particles' motion would let the rest of the body
/// slide off it: the body feels a boundary through the grid. Returns the held nodes with
/// their controls (sorted by node; where two controls meet, the first).
pub fn hold_clamps<const N: usize, const K: usize>(
    model: &Model,
    x: &[Vector3<f64>],
    values: Option<&[Vector3<f64>]>,
    fields: &mut [Vec<Vector3<f64>>; K],
) -> Vec<(usize, usize)> {
    let kinematic = model.controls().iter().any(|e| e.kind.is_kinematic());
    let Some(values) = values.filter(|_| kinematic) else {
        // No clamp: the ODE form's every evaluation passes here, so no scan of the particles.
        return Vec::new();
    };
    let (strides, origin, dx) = (model.grid.strides(), model.grid.origin_vec(), model.grid.dx);
    let mut held = Vec::new();
    for (p, xp) in x.iter().enumerate() {
        if let Some(e) = model.kinematic_control(p) {
            let stencil = Stencil::<N>::new(xp, &origin, dx);
            stencil.for_each_node(&strides, |i, _, _, _| held.push((i, e)));
        }
    }
    held.sort_unstable();
    held.dedup_by_key(|n| n.0);
    for &(i, e) in &held {
        for (k, field) in fields.iter_mut().enumerate() {
            field[i] = if k == 0 { values[e] } else { Vector3::zeros() };
        }
    }
    held
}

/// Reverse of [`hold_clamps`]: the held nodes' adjoints go to their controls' values
/// (returned, one a control) and no further.
fn release_clamps<const K: usize>(
    model: &Model,
    held: &[(usize, usize)],
    grad_fields: &mut [Vec<Vector3<f64>>; K],
) -> Vec<Vector3<f64>> {
    let mut grad_values = vec![Vector3::zeros(); model.controls().len()];
    for &(i, e) in held {
        grad_values[e] += grad_fields[0][i];
        for field in grad_fields.iter_mut() {
            field[i] = Vector3::zeros();
        }
    }
    grad_values
}
