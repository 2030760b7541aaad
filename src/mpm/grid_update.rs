//! Stage G on the dense grid: velocities from momentum, `v_i = p_i / m_i` where `m_i > 0`
//! ([`super::transfer::quotient`]). Grid effects such as gravity and walls run right after;
//! see the `effects` module.

use super::transfer::{Node, quotient, quotient_reverse};
use nalgebra::Vector3;
use rayon::prelude::*;

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
