//! Stage G, the grid update between the transfers, for both integrators: each node's `K`
//! fields over its mass ([`super::transfer::quotient`]: the Euler step's velocity `p / m`;
//! the ODE form's velocity and acceleration `p / m`, `f / m`), then the grid effects at
//! every node with mass (gravity, colliders, walls, drag: the `effects` module), in list
//! order. The reverse runs the effects backwards and then the quotient's. Every pass visits
//! the region of the bins alone (see [`super::grid`]).

use super::effect::{GridContext, GridEffects, NodeMotion};
use super::grid::{Bins, SharedMut};
use super::stages::Parallel;
use super::transfer::{Node, quotient, quotient_reverse};
use nalgebra::Vector3;

/// A node's fields as the effects see them: the velocity, and the acceleration when there
/// are two (the Euler step's is zero).
#[inline]
fn motion_of<const K: usize>(fields: &[Vector3<f64>; K]) -> NodeMotion {
    NodeMotion {
        v: fields[0],
        a: if K > 1 { fields[1] } else { Vector3::zeros() },
    }
}

/// The inverse of [`motion_of`].
#[inline]
fn fields_of<const K: usize>(motion: &NodeMotion) -> [Vector3<f64>; K] {
    std::array::from_fn(|k| if k == 0 { motion.v } else { motion.a })
}

/// Forward, first part: the nodal masses into `mass`, and each field's quotient
/// `q_ik / m_i` (zero on empty nodes) into `fields[k]`.
pub fn grid_quotients<const K: usize>(
    bins: &Bins,
    par: Parallel,
    nodes: &[Node<K>],
    mass: &mut Vec<f64>,
    fields: [&mut Vec<Vector3<f64>>; K],
) {
    mass.resize(nodes.len(), 0.0);
    let m = SharedMut::new(mass);
    let out = fields.map(|f| {
        f.resize(nodes.len(), Vector3::zeros());
        SharedMut::new(f)
    });
    bins.for_each_region_node(par.on, |i| {
        let q = quotient(&nodes[i]);
        // SAFETY: region nodes are visited once each.
        unsafe {
            *m.get(i) = nodes[i].mass;
            for (out, q) in out.iter().zip(q) {
                *out.get(i) = q;
            }
        }
    });
}

/// Forward, second part: the grid effects at every node with mass, in list order, on the
/// fields `[v]` or `[v, a]` in place (an empty node's are zero, which no effect moves).
pub fn apply_grid_effects<const K: usize>(
    bins: &Bins,
    par: Parallel,
    effects: &GridEffects,
    ctx: &GridContext,
    fields: [&mut [Vector3<f64>]; K],
) {
    if effects.is_empty() {
        return;
    }
    let fields = fields.map(SharedMut::new);
    bins.for_each_region_node(par.on, |i| {
        if ctx.mass[i] > 0.0 {
            // SAFETY: region nodes are visited once each.
            let mut motion = motion_of::<K>(&std::array::from_fn(|k| unsafe { *fields[k].get(i) }));
            effects.apply(ctx, i, &mut motion);
            for (f, value) in fields.iter().zip(fields_of::<K>(&motion)) {
                // SAFETY: as above.
                unsafe { *f.get(i) = value };
            }
        }
    });
}

/// Reverse of the grid update: `input(i)` is node `i`'s quotients as the effects received
/// them, `grad(i)` dL/d(the fields after the effects). Writes dL/d(node) (mass and fields)
/// into `grad_nodes` and returns the effects' parameter gradients, one vector per effect of
/// the model, summed in node order whatever the thread count.
#[allow(clippy::too_many_arguments)]
pub fn grid_update_reverse<const K: usize>(
    bins: &Bins,
    par: Parallel,
    effects: &GridEffects,
    ctx: &GridContext,
    input: impl Fn(usize) -> [Vector3<f64>; K] + Sync,
    grad: impl Fn(usize) -> [Vector3<f64>; K] + Sync,
    grad_nodes: &mut Vec<Node<K>>,
    params: &mut [Vec<f64>],
) {
    let mass = ctx.mass;
    grad_nodes.resize(mass.len(), Node::ZERO);
    let g_nodes = SharedMut::new(grad_nodes);
    let width = effects.width();
    let mut rows = vec![0.0; width * mass.len()];
    let row_of = SharedMut::new(&mut rows);
    bins.for_each_region_node(par.on, |i| {
        let fields = input(i);
        let mut g = motion_of(&grad(i));
        if mass[i] > 0.0 && !effects.is_empty() {
            // SAFETY: region nodes are visited once each; a node's row is its own.
            let row = unsafe { row_of.run(i * width, width) };
            effects.reverse(ctx, i, &motion_of(&fields), &mut g, row);
        }
        // SAFETY: as above.
        unsafe { *g_nodes.get(i) = quotient_reverse(mass[i], &fields, &fields_of::<K>(&g)) };
    });
    effects.add_rows(&rows, params);
}
