//! Stage G on the dense grid (the Euler step): velocities from momentum, `v_i = p_i / m_i`
//! where `m_i > 0` ([`super::transfer::quotient`]), then the grid effects at every node with
//! mass (gravity, colliders, walls: the `effects` module), each stage with its reverse.

use super::effect::{GridContext, GridEffects, NodeMotion};
use super::transfer::{Node, quotient, quotient_reverse};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Nodes a thread takes at a time in the effects' passes.
const NODES_PER_TASK: usize = 1024;

/// Forward: `v_i = p_i / m_i` (zero on empty nodes).
pub fn grid_velocity(nodes: &[Node<1>], v: &mut [Vector3<f64>]) {
    v.par_iter_mut()
        .zip(nodes.par_iter())
        .for_each(|(v, n)| *v = quotient(n)[0]);
}

/// Reverse: from dL/dv_i to node adjoints `[dL/dm_i, dL/dp_i]`.
pub fn grid_velocity_reverse(
    mass: &[f64],
    v: &[Vector3<f64>],
    grad_v: &[Vector3<f64>],
    grad_nodes: &mut [Node<1>],
) {
    grad_nodes
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, g)| *g = quotient_reverse(mass[i], &[v[i]], &[grad_v[i]]));
}

/// Forward: the grid effects at every node with mass, in list order, on the velocity `v`
/// (an empty node's velocity is zero, which no effect moves).
pub fn apply_grid_effects(effects: &GridEffects, ctx: &GridContext, v: &mut [Vector3<f64>]) {
    v.par_iter_mut()
        .enumerate()
        .with_min_len(NODES_PER_TASK)
        .for_each(|(i, v)| {
            if ctx.mass[i] > 0.0 {
                let mut motion = NodeMotion {
                    v: *v,
                    a: Vector3::zeros(),
                };
                effects.apply(ctx, i, &mut motion);
                *v = motion.v;
            }
        });
}

/// Reverse of [`apply_grid_effects`] from the velocity it received (`v_in`): `grad_v` goes
/// from dL/d(its output) to dL/d(its input), and the effects' parameter gradients are added
/// to `params` (one per effect of the list), summed in node order whatever the thread count.
/// An empty node's adjoint is left as it is: the quotient's reverse drops it.
pub fn reverse_grid_effects(
    effects: &GridEffects,
    ctx: &GridContext,
    v_in: &[Vector3<f64>],
    grad_v: &mut [Vector3<f64>],
    params: &mut [Vec<f64>],
) {
    if effects.is_empty() {
        return;
    }
    let width = effects.width();
    let mut rows = vec![0.0; width * grad_v.len()];
    let reverse_node = |i: usize, g: &mut Vector3<f64>, row: &mut [f64]| {
        if ctx.mass[i] > 0.0 {
            let input = NodeMotion {
                v: v_in[i],
                a: Vector3::zeros(),
            };
            let mut grad = NodeMotion {
                v: *g,
                a: Vector3::zeros(),
            };
            effects.reverse(ctx, i, &input, &mut grad, row);
            *g = grad.v;
        }
    };
    if width > 0 {
        grad_v
            .par_iter_mut()
            .zip(rows.par_chunks_mut(width))
            .enumerate()
            .with_min_len(NODES_PER_TASK)
            .for_each(|(i, (g, row))| reverse_node(i, g, row));
        effects.add_rows(&rows, params);
    } else {
        grad_v
            .par_iter_mut()
            .enumerate()
            .with_min_len(NODES_PER_TASK)
            .for_each(|(i, g)| reverse_node(i, g, &mut []));
    }
}
