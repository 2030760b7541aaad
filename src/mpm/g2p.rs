//! Stage G2P: grid to particle transfer of velocity and affine velocity.
//!
//! Forward: `v_p' = sum_i w_ip v_i`, `C_p' = D^-1 sum_i w_ip v_i (x_i - x_p)^T` (a gather).
//! Its reverse scatters `w_ip (gv + D^-1 gC (x_i - x_p))` to the grid, so it runs under the
//! colouring of [`super::grid::Bins`].

use super::grid::SharedMut;
use super::kernel::Stencil;
use nalgebra::{Matrix3, Vector3};

/// Forward gather: returns `(v_p', C_p')`.
#[inline]
pub fn g2p_particle<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &[Vector3<f64>],
    inv_d: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    let i0 = s.base_index(strides);
    let mut vel = Vector3::zeros();
    let mut b_mat = Matrix3::zeros(); // sum w v (x_i - x_p)^T
    for a in 0..N {
        let mut sum_a = Vector3::zeros(); // sum over (b, c) of w_b w_c v
        for b in 0..N {
            let row = i0 + a * strides[0] + b * strides[1];
            let mut sum_c = Vector3::zeros();
            let mut sum_cz = Vector3::zeros();
            for c in 0..N {
                let wv: Vector3<f64> = grid_v[row + c] * s.w[2][c];
                sum_c += wv;
                sum_cz += wv * s.dpos[2][c];
            }
            let wb = s.w[0][a] * s.w[1][b];
            let t = s.w[1][b] * sum_c;
            sum_a += t;
            b_mat.column_mut(1).axpy(wb * s.dpos[1][b], &sum_c, 1.0);
            b_mat.column_mut(2).axpy(wb, &sum_cz, 1.0);
        }
        vel.axpy(s.w[0][a], &sum_a, 1.0);
        b_mat
            .column_mut(0)
            .axpy(s.w[0][a] * s.dpos[0][a], &sum_a, 1.0);
    }
    (vel, inv_d * b_mat)
}

/// Reverse: given dL/dv_p' and dL/dC_p' (and the forward result `v_p'`), scatters dL/dv_i
/// into `grad_grid_v` and returns this stage's part of dL/dx_p:
/// `sum_i grad w_ip (v_i . u_i) - D^-1 gC^T v_p'` with `u_i = gv + D^-1 gC (x_i - x_p)`.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn g2p_particle_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &[Vector3<f64>],
    inv_d: f64,
    grad_vel: &Vector3<f64>,
    grad_c: &Matrix3<f64>,
    vel: &Vector3<f64>,
    grad_grid_v: &SharedMut<Vector3<f64>>,
) -> Vector3<f64> {
    let i0 = s.base_index(strides);
    let gc = inv_d * grad_c;
    let (gx_col, gy_col, gz_col) = (gc.column(0), gc.column(1), gc.column(2));
    let mut grad_x = Vector3::zeros();
    for a in 0..N {
        let ua = grad_vel + gx_col * s.dpos[0][a];
        for b in 0..N {
            let uab = ua + gy_col * s.dpos[1][b];
            let wab = s.w[0][a] * s.w[1][b];
            let row = i0 + a * strides[0] + b * strides[1];
            for c in 0..N {
                let u = uab + gz_col * s.dpos[2][c];
                let w = wab * s.w[2][c];
                let node = row + c;
                let vu = grid_v[node].dot(&u);
                grad_x += vu
                    * Vector3::new(
                        s.dw[0][a] * s.w[1][b] * s.w[2][c],
                        s.w[0][a] * s.dw[1][b] * s.w[2][c],
                        wab * s.dw[2][c],
                    );
                // SAFETY: exclusive stencil access under the colouring.
                unsafe { *grad_grid_v.get(node) += w * u };
            }
        }
    }
    grad_x - gc.transpose() * vel
}
