//! Stage P2G: particle to grid transfer of mass and momentum.
//!
//! Forward: `m_i += w_ip m_p`, `p_i += w_ip (mv_p + A_p (x_i - x_p))` with `mv_p` the particle
//! momentum after drag. Grid nodes hold `[m, px, py, pz]`. The forward pass is a scatter run
//! under the colouring of [`super::grid::Bins`]; its reverse is a per-particle gather.

use super::error::SimError;
use super::grid::{Bins, GridSpec, SharedMut};
use super::kernel::KernelKind;
use super::kernel::Stencil;
use nalgebra::{Matrix3, Vector3};

/// Forward scatter of one particle. Safety: caller runs it under [`super::grid::Bins::for_each_coloured`].
#[inline]
pub fn p2g_particle<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    momentum: &Vector3<f64>,
    affine: &Matrix3<f64>,
    nodes: &SharedMut<[f64; 4]>,
) {
    let i0 = s.base_index(strides);
    let (ax, ay, az) = (affine.column(0), affine.column(1), affine.column(2));
    for a in 0..N {
        let qa = momentum + ax * s.dpos[0][a];
        for b in 0..N {
            let wab = s.w[0][a] * s.w[1][b];
            let qab = qa + ay * s.dpos[1][b];
            let row = i0 + a * strides[0] + b * strides[1];
            for c in 0..N {
                let w = wab * s.w[2][c];
                let q = qab + az * s.dpos[2][c];
                // SAFETY: the colouring gives this thread exclusive use of the stencil's nodes.
                let node = unsafe { nodes.get(row + c) };
                node[0] += w * mass;
                node[1] += w * q[0];
                node[2] += w * q[1];
                node[3] += w * q[2];
            }
        }
    }
}

/// Reverse of [`p2g_particle`]: gathers the node adjoints `[gm, gpx, gpy, gpz]` and returns
/// `(sum_i w gp_i, dL/dA, dL/dx_p)`. The first is dL/d(momentum).
#[inline]
pub fn p2g_particle_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    momentum: &Vector3<f64>,
    affine: &Matrix3<f64>,
    grad_nodes: &[[f64; 4]],
) -> (Vector3<f64>, Matrix3<f64>, Vector3<f64>) {
    let i0 = s.base_index(strides);
    let (ax, ay, az) = (affine.column(0), affine.column(1), affine.column(2));
    let mut sum_wgp = Vector3::zeros();
    let mut grad_a = Matrix3::zeros();
    let mut grad_x = Vector3::zeros();
    for a in 0..N {
        let qa = momentum + ax * s.dpos[0][a];
        for b in 0..N {
            let qab = qa + ay * s.dpos[1][b];
            let row = i0 + a * strides[0] + b * strides[1];
            for c in 0..N {
                let q = qab + az * s.dpos[2][c];
                let g = &grad_nodes[row + c];
                let gp = Vector3::new(g[1], g[2], g[3]);
                let w = s.w[0][a] * s.w[1][b] * s.w[2][c];
                let grad_w = Vector3::new(
                    s.dw[0][a] * s.w[1][b] * s.w[2][c],
                    s.w[0][a] * s.dw[1][b] * s.w[2][c],
                    s.w[0][a] * s.w[1][b] * s.dw[2][c],
                );
                let wgp = w * gp;
                sum_wgp += wgp;
                grad_a += wgp * Vector3::new(s.dpos[0][a], s.dpos[1][b], s.dpos[2][c]).transpose();
                grad_x += grad_w * (mass * g[0] + gp.dot(&q));
            }
        }
    }
    // (x_i - x_p) depends on x_p with derivative -I.
    grad_x -= affine.transpose() * sum_wgp;
    (sum_wgp, grad_a, grad_x)
}

/// Mass-only transfer (for losses on the nodal mass grid): `m_i += w_ip m_p`.
#[inline]
pub fn mass_particle<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    grid_mass: &SharedMut<f64>,
) {
    s.for_each_node(strides, |i, w, _, _| {
        // SAFETY: exclusive stencil access under the colouring.
        unsafe { *grid_mass.get(i) += w * mass };
    });
}

/// Reverse of [`mass_particle`]: dL/dx_p = sum_i grad w_ip m_p dL/dm_i.
#[inline]
pub fn mass_particle_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    grad_mass: &[f64],
) -> Vector3<f64> {
    let i0 = s.base_index(strides);
    let mut grad_x = Vector3::zeros();
    for a in 0..N {
        for b in 0..N {
            let row = i0 + a * strides[0] + b * strides[1];
            for c in 0..N {
                let g = grad_mass[row + c];
                grad_x += g * Vector3::new(
                    s.dw[0][a] * s.w[1][b] * s.w[2][c],
                    s.w[0][a] * s.dw[1][b] * s.w[2][c],
                    s.w[0][a] * s.w[1][b] * s.dw[2][c],
                );
            }
        }
    }
    mass * grad_x
}

/// Nodal masses `m_i = sum_p w_ip m_p` of any particle set on `grid` (e.g. the target
/// shape's particles, which need not match the simulated ones). Deterministic: the
/// coloured scatter adds into each node in an order fixed by the positions.
pub fn mass_grid(
    grid: &GridSpec,
    kernel: KernelKind,
    positions: &[Vector3<f64>],
    masses: &[f64],
) -> Result<Vec<f64>, SimError> {
    assert_eq!(positions.len(), masses.len());
    match kernel {
        KernelKind::Quadratic => mass_grid_impl::<3>(grid, positions, masses),
        KernelKind::Cubic => mass_grid_impl::<4>(grid, positions, masses),
    }
}

fn mass_grid_impl<const N: usize>(
    grid: &GridSpec,
    positions: &[Vector3<f64>],
    masses: &[f64],
) -> Result<Vec<f64>, SimError> {
    let bins = Bins::build(grid, positions, N, 0)?;
    let mut out = vec![0.0; grid.node_count()];
    let (strides, origin, dx) = (grid.strides(), grid.origin_vec(), grid.dx);
    {
        let g = SharedMut::new(&mut out);
        bins.for_each_coloured(|p| {
            let s = Stencil::<N>::new(&positions[p], &origin, dx);
            mass_particle(&s, &strides, masses[p], &g);
        });
    }
    Ok(out)
}
