//! The particle-grid transfers every integrator uses, forward and reverse side by side.
//!
//! - **Scatter** (P2G): a particle spreads its mass and `K` affine fields
//!   `q_k(x_i) = value_k + slope_k (x_i - x_p)` over its stencil: `m_i += w m_p`,
//!   `q_ik += w q_k(x_i)`. The Euler step scatters one field (APIC momentum
//!   `m v + A (x_i - x_p)`, with the stress folded into `A`); the ODE form two (momentum, and
//!   force `m b + K (x_i - x_p)`). Run under the colouring of [`super::grid::Bins`]; its
//!   reverse is a per-particle gather.
//! - **Grid quotient** (G): `v_ik = q_ik / m_i` on nodes with mass.
//! - **Gather** (G2P): [`gather_affine`] gives `v_p = sum w v_i` and the velocity gradient
//!   `C_p = D^-1 sum w v_i (x_i - x_p)^T`; [`interpolate`] gives `sum w a_i` alone. Their
//!   reverses scatter under the colouring.
//! - **Mass only** (for losses on the nodal mass grid).

use super::error::SimError;
use super::grid::{Bins, GridSpec, SharedMut};
use super::kernel::{KernelKind, Stencil};
use nalgebra::{Matrix3, Vector3};

/// A grid node: mass and `K` vector fields (momentum, force...).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node<const K: usize> {
    pub mass: f64,
    pub fields: [Vector3<f64>; K],
}

impl<const K: usize> Node<K> {
    pub const ZERO: Node<K> = Node {
        mass: 0.0,
        fields: [Vector3::new(0.0, 0.0, 0.0); K],
    };
}

impl<const K: usize> Default for Node<K> {
    fn default() -> Self {
        Node::ZERO
    }
}

/// A field that varies linearly across a particle's stencil: `value + slope (x_i - x_p)`.
#[derive(Clone, Copy, Debug)]
pub struct Affine {
    pub value: Vector3<f64>,
    pub slope: Matrix3<f64>,
}

#[inline(always)]
fn grad_w<const N: usize>(s: &Stencil<N>, a: usize, b: usize, c: usize) -> Vector3<f64> {
    Vector3::new(
        s.dw[0][a] * s.w[1][b] * s.w[2][c],
        s.w[0][a] * s.dw[1][b] * s.w[2][c],
        s.w[0][a] * s.w[1][b] * s.dw[2][c],
    )
}

/// Forward scatter of one particle. Safety: the caller runs it under
/// [`super::grid::Bins::for_each_coloured`] (or sequentially).
#[inline]
pub fn scatter<const N: usize, const K: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    fields: &[Affine; K],
    nodes: &SharedMut<Node<K>>,
) {
    let i0 = s.base_index(strides);
    // The fields are built up one axis at a time: q = value + s_x dx + s_y dy + s_z dz.
    for a in 0..N {
        let qa: [Vector3<f64>; K] =
            std::array::from_fn(|k| fields[k].value + fields[k].slope.column(0) * s.dpos[0][a]);
        for b in 0..N {
            let wab = s.w[0][a] * s.w[1][b];
            let qab: [Vector3<f64>; K] =
                std::array::from_fn(|k| qa[k] + fields[k].slope.column(1) * s.dpos[1][b]);
            let row = i0 + a * strides[0] + b * strides[1];
            for c in 0..N {
                let w = wab * s.w[2][c];
                // SAFETY: the colouring gives this thread exclusive use of the stencil's nodes.
                let node = unsafe { nodes.get(row + c) };
                node.mass += w * mass;
                for k in 0..K {
                    let q = qab[k] + fields[k].slope.column(2) * s.dpos[2][c];
                    node.fields[k] += w * q;
                }
            }
        }
    }
}

/// Adjoints of one particle's [`scatter`] inputs.
#[derive(Clone, Copy, Debug)]
pub struct ScatterGrad<const K: usize> {
    /// dL/d(value_k) = `sum_i w g_ik`.
    pub value: [Vector3<f64>; K],
    /// dL/d(slope_k) = `sum_i w g_ik (x_i - x_p)^T`.
    pub slope: [Matrix3<f64>; K],
    /// dL/dx_p through the weights and the offsets `x_i - x_p`.
    pub x: Vector3<f64>,
}

/// Reverse of [`scatter`]: gathers the node adjoints `grad_nodes` (dL/dm_i, dL/dq_ik).
///
/// Every sum over the stencil is taken one axis at a time, as in [`gather_affine`]: the
/// weight `w_a w_b w_c`, its gradient and the offset `x_i - x_p` are products of per-axis
/// factors, so the innermost loop adds each node's adjoint into a few per-row sums and the
/// per-axis factors are applied once per row and plane.
#[inline]
pub fn scatter_reverse<const N: usize, const K: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    fields: &[Affine; K],
    grad_nodes: &[Node<K>],
) -> ScatterGrad<K> {
    let i0 = s.base_index(strides);
    let zero = [Vector3::zeros(); K];
    let mut value = zero;
    // Columns of dL/d(slope_k): sum w g (x_i - x_p)_j.
    let mut col = [zero; 3];
    // dL/dx through the weights, per axis: sum (d w / d x_j) e_i.
    let mut gx = [0.0; 3];
    let w2d2: [f64; N] = std::array::from_fn(|c| s.w[2][c] * s.dpos[2][c]);
    for a in 0..N {
        let qa: [Vector3<f64>; K] =
            std::array::from_fn(|k| fields[k].value + fields[k].slope.column(0) * s.dpos[0][a]);
        // Sums over the plane a: sum_b w_b (row sums), sum_b w_b d_b (.), and the e sums.
        let (mut sb, mut sb_d1, mut sb_z) = (zero, zero, zero);
        let (mut e_w, mut e_dw1, mut e_dw2) = (0.0, 0.0, 0.0);
        for b in 0..N {
            let qab: [Vector3<f64>; K] =
                std::array::from_fn(|k| qa[k] + fields[k].slope.column(1) * s.dpos[1][b]);
            let row = i0 + a * strides[0] + b * strides[1];
            // Row sums over c: sum w_c g, sum w_c d_c g, sum w_c e, sum w_c' e.
            let (mut sc, mut sc_z) = (zero, zero);
            let (mut ec, mut ec_d) = (0.0, 0.0);
            for c in 0..N {
                let g = &grad_nodes[row + c];
                let mut e = mass * g.mass;
                for k in 0..K {
                    let q = qab[k] + fields[k].slope.column(2) * s.dpos[2][c];
                    e += g.fields[k].dot(&q);
                    sc[k] += s.w[2][c] * g.fields[k];
                    sc_z[k] += w2d2[c] * g.fields[k];
                }
                ec += s.w[2][c] * e;
                ec_d += s.dw[2][c] * e;
            }
            let (wb, db) = (s.w[1][b], s.w[1][b] * s.dpos[1][b]);
            for k in 0..K {
                sb[k] += wb * sc[k];
                sb_d1[k] += db * sc[k];
                sb_z[k] += wb * sc_z[k];
            }
            e_w += wb * ec;
            e_dw1 += s.dw[1][b] * ec;
            e_dw2 += wb * ec_d;
        }
        let (wa, da) = (s.w[0][a], s.w[0][a] * s.dpos[0][a]);
        for k in 0..K {
            value[k] += wa * sb[k];
            col[0][k] += da * sb[k];
            col[1][k] += wa * sb_d1[k];
            col[2][k] += wa * sb_z[k];
        }
        gx[0] += s.dw[0][a] * e_w;
        gx[1] += wa * e_dw1;
        gx[2] += wa * e_dw2;
    }
    let mut out = ScatterGrad {
        value,
        slope: std::array::from_fn(|k| Matrix3::from_columns(&[col[0][k], col[1][k], col[2][k]])),
        x: Vector3::new(gx[0], gx[1], gx[2]),
    };
    // The offsets x_i - x_p move with the particle (derivative -I).
    for (field, value) in fields.iter().zip(&out.value) {
        out.x -= field.slope.transpose() * value;
    }
    out
}

/// Grid quotient of one node: `q_k / m` (zero on a node without mass).
#[inline]
pub fn quotient<const K: usize>(node: &Node<K>) -> [Vector3<f64>; K] {
    if node.mass > 0.0 {
        node.fields.map(|q| q / node.mass)
    } else {
        [Vector3::zeros(); K]
    }
}

/// Reverse of [`quotient`]: from dL/d(q_k / m) (`grad`) and the forward result `out` to the
/// node adjoint: `dL/dq_k = g_k / m`, `dL/dm = -sum_k (g_k / m) . out_k`.
#[inline]
pub fn quotient_reverse<const K: usize>(
    mass: f64,
    out: &[Vector3<f64>; K],
    grad: &[Vector3<f64>; K],
) -> Node<K> {
    if mass > 0.0 {
        let fields = grad.map(|g| g / mass);
        let mut gm = -fields[0].dot(&out[0]);
        for k in 1..K {
            gm -= fields[k].dot(&out[k]);
        }
        Node { mass: gm, fields }
    } else {
        Node::ZERO
    }
}

/// Forward gather of a grid velocity: `(v_p, C_p)` with `v_p = sum w v_i` and
/// `C_p = D^-1 sum w v_i (x_i - x_p)^T`.
#[inline]
pub fn gather_affine<const N: usize>(
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

/// Reverse of [`gather_affine`]: given dL/dv_p and dL/dC_p (and the forward `v_p`), scatters
/// dL/dv_i into `grad_grid_v` (under the colouring) and returns this gather's part of dL/dx_p:
/// `sum_i grad w_ip (v_i . u_i) - D^-1 gC^T v_p` with `u_i = gv + D^-1 gC (x_i - x_p)`.
/// The weight gradient's sum is taken one axis at a time (see [`scatter_reverse`]).
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn gather_affine_reverse<const N: usize>(
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
    let mut gx = [0.0; 3];
    for a in 0..N {
        let ua = grad_vel + gx_col * s.dpos[0][a];
        let (mut e_w, mut e_dw1, mut e_dw2) = (0.0, 0.0, 0.0);
        for b in 0..N {
            let uab = ua + gy_col * s.dpos[1][b];
            let wab = s.w[0][a] * s.w[1][b];
            let row = i0 + a * strides[0] + b * strides[1];
            let (mut ec, mut ec_d) = (0.0, 0.0);
            for c in 0..N {
                let u = uab + gz_col * s.dpos[2][c];
                let node = row + c;
                let vu = grid_v[node].dot(&u);
                ec += s.w[2][c] * vu;
                ec_d += s.dw[2][c] * vu;
                // SAFETY: exclusive stencil access under the colouring.
                unsafe { *grad_grid_v.get(node) += (wab * s.w[2][c]) * u };
            }
            e_w += s.w[1][b] * ec;
            e_dw1 += s.dw[1][b] * ec;
            e_dw2 += s.w[1][b] * ec_d;
        }
        gx[0] += s.dw[0][a] * e_w;
        gx[1] += s.w[0][a] * e_dw1;
        gx[2] += s.w[0][a] * e_dw2;
    }
    Vector3::new(gx[0], gx[1], gx[2]) - gc.transpose() * vel
}

/// Forward gather of a grid field's value alone: `sum w a_i`.
#[inline]
pub fn interpolate<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    field: &[Vector3<f64>],
) -> Vector3<f64> {
    let mut out = Vector3::zeros();
    s.for_each_node(strides, |i, w, _, _| out += w * field[i]);
    out
}

/// Reverse of [`interpolate`]: scatters `w g` into `grad_field` (under the colouring) and
/// returns dL/dx_p = `sum_i grad w_ip (a_i . g)`.
#[inline]
pub fn interpolate_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    field: &[Vector3<f64>],
    grad: &Vector3<f64>,
    grad_field: &SharedMut<Vector3<f64>>,
) -> Vector3<f64> {
    let mut grad_x = Vector3::zeros();
    s.for_each_node(strides, |i, w, _, (a, b, c)| {
        grad_x += grad_w(s, a, b, c) * field[i].dot(grad);
        // SAFETY: exclusive stencil access under the colouring.
        unsafe { *grad_field.get(i) += w * grad };
    });
    grad_x
}

/// Mass-only scatter (for losses on the nodal mass grid): `m_i += w_ip m_p`.
#[inline]
pub fn scatter_mass<const N: usize>(
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

/// Reverse of [`scatter_mass`]: dL/dx_p = sum_i grad w_ip m_p dL/dm_i.
#[inline]
pub fn scatter_mass_reverse<const N: usize>(
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
                grad_x += grad_mass[row + c] * grad_w(s, a, b, c);
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
            scatter_mass(&s, &strides, masses[p], &g);
        });
    }
    Ok(out)
}

/// Reverse of [`mass_grid`]: dL/dx_p from dL/dm_i.
pub fn mass_grid_reverse(
    grid: &GridSpec,
    kernel: KernelKind,
    positions: &[Vector3<f64>],
    masses: &[f64],
    grad_mass: &[f64],
) -> Vec<Vector3<f64>> {
    use rayon::prelude::*;
    let (strides, origin, dx) = (grid.strides(), grid.origin_vec(), grid.dx);
    positions
        .par_iter()
        .zip(masses.par_iter())
        .map(|(x, &m)| match kernel {
            KernelKind::Quadratic => {
                scatter_mass_reverse(&Stencil::<3>::new(x, &origin, dx), &strides, m, grad_mass)
            }
            KernelKind::Cubic => {
                scatter_mass_reverse(&Stencil::<4>::new(x, &origin, dx), &strides, m, grad_mass)
            }
        })
        .collect()
}
