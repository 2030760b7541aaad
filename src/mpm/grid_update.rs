//! Stage G: grid velocities from momentum, `v_i = p_i / m_i` where `m_i > 0`.
//! (Grid effects such as gravity and walls run right after; see [`crate::effects`].)

use nalgebra::Vector3;
use rayon::prelude::*;

/// Forward: `v_i = p_i / m_i` (zero on empty nodes).
pub fn grid_velocity(nodes: &[[f64; 4]], v: &mut [Vector3<f64>]) {
    v.par_iter_mut().zip(nodes.par_iter()).for_each(|(v, n)| {
        *v = if n[0] > 0.0 {
            Vector3::new(n[1], n[2], n[3]) / n[0]
        } else {
            Vector3::zeros()
        };
    });
}

/// Reverse: from dL/dv_i to node adjoints `[dL/dm_i, dL/dp_i]`:
/// `dL/dp_i = gv_i / m_i`, `dL/dm_i = -gv_i . v_i / m_i`.
pub fn grid_velocity_reverse(
    mass: &[f64],
    v: &[Vector3<f64>],
    grad_v: &[Vector3<f64>],
    grad_nodes: &mut [[f64; 4]],
) {
    grad_nodes.par_iter_mut().enumerate().for_each(|(i, g)| {
        let m = mass[i];
        *g = if m > 0.0 {
            let gp = grad_v[i] / m;
            [-gp.dot(&v[i]), gp[0], gp[1], gp[2]]
        } else {
            [0.0; 4]
        };
    });
}
