//! The particle-grid transfers every integrator uses, forward and reverse side by side.
//!
//! - **Scatter** (P2G): a particle spreads its mass and `K` affine fields
//!   `q_k(x_i) = value_k + slope_k (x_i - x_p)` over its stencil: `m_i += w m_p`,
//!   `q_ik += w q_k(x_i)`. The Euler step scatters one field (APIC momentum
//!   `m v + A (x_i - x_p)`, with the stress folded into `A`); the ODE form two (momentum, and
//!   force `m b + K (x_i - x_p)`). Each block's particles add into the block's tile
//!   ([`super::grid::Bins::scatter`]); its reverse is a per-particle gather.
//! - **Grid quotient** (G): `v_ik = q_ik / m_i` on nodes with mass.
//! - **Gather** (G2P): [`gather_affine`] gives `v_p = sum w v_i` and the velocity gradient
//!   `C_p = D^-1 sum w v_i (x_i - x_p)^T`; [`interpolate`] gives `sum w a_i` alone. Their
//!   reverses scatter into tiles.
//! - **Mass only** (for losses on the nodal mass grid).

use super::error::SimError;
use super::grid::{Bins, GridSpec, SharedMut, Tile};
use super::kernel::{KernelKind, Stencil};
use crate::lanes::{RowKernel, Rows, SimdLevel, dispatch_rows};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

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

/// A grid vector field stored by axis: `axes[k][i]` is component `k` at node `i`, so one
/// component of a stencil row is four consecutive values (one load; see
/// [`crate::lanes::Rows`]).
#[derive(Clone, Debug, Default)]
pub struct AxisField {
    pub axes: [Vec<f64>; 3],
    /// Scratch for the scatters into this field ([`Bins::scatter`]'s tiles).
    pub tiles: Vec<f64>,
}

impl AxisField {
    /// Takes the values of `v` on the region of `bins` (keeping this field's buffers; see
    /// [`Bins`]' note on the region).
    pub fn set_from(&mut self, v: &[Vector3<f64>], bins: &Bins, parallel: bool) {
        let axes = self.axes.each_mut().map(|a| {
            a.resize(v.len(), 0.0);
            SharedMut::new(a)
        });
        bins.for_each_region_node(parallel, |i| {
            for (k, axis) in axes.iter().enumerate() {
                // SAFETY: region nodes are visited once each.
                unsafe { *axis.get(i) = v[i][k] };
            }
        });
    }

    /// Writes the field's region of `bins` into `out`, one vector a node.
    pub fn write_vectors(&self, out: &mut Vec<Vector3<f64>>, bins: &Bins, parallel: bool) {
        let [x, y, z] = &self.axes;
        out.resize(x.len(), Vector3::zeros());
        let dst = SharedMut::new(out);
        bins.for_each_region_node(parallel, |i| {
            // SAFETY: region nodes are visited once each.
            unsafe { *dst.get(i) = Vector3::new(x[i], y[i], z[i]) };
        });
    }

    /// `n` nodes from a scatter over `bins` (tile channels 0, 1, 2: the axes; see
    /// [`Bins::scatter`]): `f(tile, particle)` for each particle.
    pub fn scatter(
        &mut self,
        bins: &Bins,
        parallel: bool,
        n: usize,
        f: impl Fn(&mut Tile, usize) + Sync,
    ) {
        let AxisField { axes, tiles } = self;
        for axis in axes.iter_mut() {
            axis.resize(n, 0.0);
        }
        let [x, y, z] = axes;
        bins.scatter(parallel, tiles, &mut [x, y, z], f);
    }
}

/// Grid nodes stored by axis: the masses, and each of the `K` fields as an [`AxisField`].
#[derive(Clone, Debug)]
pub struct AxisNodes<const K: usize> {
    pub mass: Vec<f64>,
    pub fields: [AxisField; K],
    /// Scratch for the scatters into these nodes ([`Bins::scatter`]'s tiles).
    pub tiles: Vec<f64>,
}

impl<const K: usize> Default for AxisNodes<K> {
    fn default() -> Self {
        AxisNodes {
            mass: Vec::new(),
            fields: std::array::from_fn(|_| AxisField::default()),
            tiles: Vec::new(),
        }
    }
}

impl<const K: usize> AxisNodes<K> {
    /// Takes the values of `nodes` on the region of `bins` (keeping the buffers).
    pub fn set_from(&mut self, nodes: &[Node<K>], bins: &Bins, parallel: bool) {
        let n = nodes.len();
        self.mass.resize(n, 0.0);
        let mass = SharedMut::new(&mut self.mass);
        let fields = self.fields.each_mut().map(|f| {
            f.axes.each_mut().map(|a| {
                a.resize(n, 0.0);
                SharedMut::new(a)
            })
        });
        bins.for_each_region_node(parallel, |i| {
            // SAFETY: region nodes are visited once each.
            unsafe {
                *mass.get(i) = nodes[i].mass;
                for (k, axes) in fields.iter().enumerate() {
                    for (j, axis) in axes.iter().enumerate() {
                        *axis.get(i) = nodes[i].fields[k][j];
                    }
                }
            }
        });
    }

    /// Writes the nodes of the region of `bins` into `out`, one [`Node`] each.
    pub fn write_nodes(&self, out: &mut Vec<Node<K>>, bins: &Bins, parallel: bool) {
        out.resize(self.mass.len(), Node::ZERO);
        let dst = SharedMut::new(out);
        bins.for_each_region_node(parallel, |i| {
            let node = Node {
                mass: self.mass[i],
                fields: std::array::from_fn(|k| {
                    let [x, y, z] = &self.fields[k].axes;
                    Vector3::new(x[i], y[i], z[i])
                }),
            };
            // SAFETY: region nodes are visited once each.
            unsafe { *dst.get(i) = node };
        });
    }

    /// `n` nodes from a scatter over `bins`: `f(tile, particle)` for each particle, into
    /// tile channel 0 (mass) and `1 + 3 k + j` (field `k`'s axis `j`); see [`Bins::scatter`].
    pub fn scatter(
        &mut self,
        bins: &Bins,
        parallel: bool,
        n: usize,
        f: impl Fn(&mut Tile, usize) + Sync,
    ) {
        let AxisNodes {
            mass,
            fields,
            tiles,
        } = self;
        mass.resize(n, 0.0);
        let mut out: Vec<&mut [f64]> = vec![mass];
        for field in fields.iter_mut() {
            for axis in field.axes.iter_mut() {
                axis.resize(n, 0.0);
                out.push(axis);
            }
        }
        bins.scatter(parallel, tiles, &mut out, f);
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

/// Forward scatter of one particle into its block's tile (channel 0 the mass, `1 + 3 k + j`
/// field `k`'s axis `j`), on four-lane stencil rows (the row's nodes are the lanes): every
/// node receives `w m` and `w q_k(x_i)`, each formed and added as in a node-by-node loop, so
/// its bits do not depend on the lanes.
#[inline]
pub fn scatter<const N: usize, const K: usize>(
    simd: SimdLevel,
    s: &Stencil<N>,
    mass: f64,
    fields: &[Affine; K],
    tile: &mut Tile,
) {
    struct Kernel<'a, 't, const N: usize, const K: usize> {
        s: &'a Stencil<N>,
        mass: f64,
        fields: &'a [Affine; K],
        tile: &'a mut Tile<'t>,
    }
    impl<const N: usize, const K: usize> RowKernel for Kernel<'_, '_, N, K> {
        type Output = ();
        #[inline(always)]
        #[allow(clippy::needless_range_loop)]
        fn run<R: Rows>(self, r: R) {
            let Kernel {
                s,
                mass,
                fields,
                tile,
            } = self;
            let strides = &Tile::STRIDES;
            let i0 = tile.base(s);
            let (wc, dc) = (r.load_first(&s.w[2], N), r.load_first(&s.dpos[2], N));
            let mass = r.splat(mass);
            let slope_z = slopes_along_rows(r, fields);
            // The fields are built up one axis at a time: q = value + s_x dx + s_y dy + s_z dz.
            for a in 0..N {
                let qa: [Vector3<f64>; K] = std::array::from_fn(|k| {
                    fields[k].value + fields[k].slope.column(0) * s.dpos[0][a]
                });
                for b in 0..N {
                    let row = i0 + a * strides[0] + b * strides[1];
                    let w = r.mul(r.splat(s.w[0][a] * s.w[1][b]), wc);
                    r.add_into(tile.run(0, row, N), r.mul(w, mass));
                    for k in 0..K {
                        let qab = qa[k] + fields[k].slope.column(1) * s.dpos[1][b];
                        for j in 0..3 {
                            let q = r.add_mul(r.splat(qab[j]), slope_z[k][j], dc);
                            r.add_into(tile.run(1 + 3 * k + j, row, N), r.mul(w, q));
                        }
                    }
                }
            }
        }
    }
    dispatch_rows(
        simd,
        Kernel {
            s,
            mass,
            fields,
            tile,
        },
    );
}

/// Each field's slope along the rows (the third column, `d q / d z`), one value a lane.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn slopes_along_rows<R: Rows, const K: usize>(r: R, fields: &[Affine; K]) -> [[R::V; 3]; K] {
    let mut out = [[r.zero(); 3]; K];
    for k in 0..K {
        for j in 0..3 {
            out[k][j] = r.splat(fields[k].slope[(j, 2)]);
        }
    }
    out
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

/// Reverse of [`scatter`]: gathers the node adjoints `grad_nodes` (dL/dm_i, dL/dq_ik), on
/// four-lane stencil rows as [`gather_affine`]: every sum over the stencil is kept per lane
/// (the row's node) through the planes and rows, and the row's per-node factors (`w_c`,
/// `w_c d_c`, `w_c'`) multiply the lanes once at the end.
#[inline]
pub fn scatter_reverse<const N: usize, const K: usize>(
    simd: SimdLevel,
    s: &Stencil<N>,
    strides: &[usize; 3],
    mass: f64,
    fields: &[Affine; K],
    grad_nodes: &AxisNodes<K>,
) -> ScatterGrad<K> {
    struct Kernel<'a, const N: usize, const K: usize> {
        s: &'a Stencil<N>,
        strides: &'a [usize; 3],
        mass: f64,
        fields: &'a [Affine; K],
        grad_nodes: &'a AxisNodes<K>,
    }
    impl<const N: usize, const K: usize> RowKernel for Kernel<'_, N, K> {
        type Output = ScatterGrad<K>;
        #[inline(always)]
        #[allow(clippy::needless_range_loop)] // index loops: the lane code's form
        fn run<R: Rows>(self, r: R) -> ScatterGrad<K> {
            let Kernel {
                s,
                strides,
                mass,
                fields,
                grad_nodes,
            } = self;
            let i0 = s.base_index(strides);
            let zero = r.zero();
            let zeros = [[zero; 3]; K];
            let dc = r.load_first(&s.dpos[2], N);
            let slope_z = slopes_along_rows(r, fields);
            // Per lane, per field and component: sum_ab w_a w_b g, the same with d_a, with d_b.
            let (mut value, mut col0, mut col1) = (zeros, zeros, zeros);
            // Per lane: sum_a w_a' sum_b w_b e, sum_a w_a sum_b w_b' e, sum_a w_a sum_b w_b e.
            let (mut g0, mut g1, mut g2) = (zero, zero, zero);
            let mass = r.splat(mass);
            for a in 0..N {
                let qa: [Vector3<f64>; K] = std::array::from_fn(|k| {
                    fields[k].value + fields[k].slope.column(0) * s.dpos[0][a]
                });
                let (mut sb, mut sb1) = (zeros, zeros);
                let (mut e_w, mut e_dw1) = (zero, zero);
                for b in 0..N {
                    let row = i0 + a * strides[0] + b * strides[1];
                    let (wb, wbd) = (r.splat(s.w[1][b]), r.splat(s.w[1][b] * s.dpos[1][b]));
                    // e_i = m dL/dm_i + sum_k dL/dq_ik . q_k(x_i).
                    let mut e = r.mul(mass, r.load_first(&grad_nodes.mass[row..], N));
                    for k in 0..K {
                        let qab = qa[k] + fields[k].slope.column(1) * s.dpos[1][b];
                        let mut dot = zero;
                        for j in 0..3 {
                            let g = r.load_first(&grad_nodes.fields[k].axes[j][row..], N);
                            let q = r.add_mul(r.splat(qab[j]), slope_z[k][j], dc);
                            dot = if j == 0 {
                                r.mul(g, q)
                            } else {
                                r.add_mul(dot, g, q)
                            };
                            sb[k][j] = r.add_mul(sb[k][j], wb, g);
                            sb1[k][j] = r.add_mul(sb1[k][j], wbd, g);
                        }
                        e = r.add(e, dot);
                    }
                    e_w = r.add_mul(e_w, wb, e);
                    e_dw1 = r.add_mul(e_dw1, r.splat(s.dw[1][b]), e);
                }
                let (wa, wad) = (r.splat(s.w[0][a]), r.splat(s.w[0][a] * s.dpos[0][a]));
                for k in 0..K {
                    for j in 0..3 {
                        value[k][j] = r.add_mul(value[k][j], wa, sb[k][j]);
                        col0[k][j] = r.add_mul(col0[k][j], wad, sb[k][j]);
                        col1[k][j] = r.add_mul(col1[k][j], wa, sb1[k][j]);
                    }
                }
                g0 = r.add_mul(g0, r.splat(s.dw[0][a]), e_w);
                g1 = r.add_mul(g1, wa, e_dw1);
                g2 = r.add_mul(g2, wa, e_w);
            }
            let wc = r.load_first(&s.w[2], N);
            let wcd = r.mul(wc, dc);
            let dwc = r.load_first(&s.dw[2], N);
            let mut out = ScatterGrad {
                value: [Vector3::zeros(); K],
                slope: [Matrix3::zeros(); K],
                x: Vector3::new(r.dot(wc, g0), r.dot(wc, g1), r.dot(dwc, g2)),
            };
            for k in 0..K {
                for j in 0..3 {
                    out.value[k][j] = r.dot(wc, value[k][j]);
                    out.slope[k][(j, 0)] = r.dot(wc, col0[k][j]);
                    out.slope[k][(j, 1)] = r.dot(wc, col1[k][j]);
                    out.slope[k][(j, 2)] = r.dot(wcd, value[k][j]);
                }
            }
            // The offsets x_i - x_p move with the particle (derivative -I).
            for (field, value) in fields.iter().zip(&out.value) {
                out.x -= field.slope.transpose() * value;
            }
            out
        }
    }
    dispatch_rows(
        simd,
        Kernel {
            s,
            strides,
            mass,
            fields,
            grad_nodes,
        },
    )
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
/// `C_p = D^-1 sum w v_i (x_i - x_p)^T`, on four-lane stencil rows (see [`AxisField`]).
///
/// The nodes of a row are the lanes: each lane sums over the rows its node's share
/// (`sum_ab w_a w_b v`, and the same with `d_a` and `d_b`), and the row's weights `w_c`
/// (and `w_c d_c`) multiply the lanes once at the end.
#[inline]
pub fn gather_affine<const N: usize>(
    simd: SimdLevel,
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &AxisField,
    inv_d: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    struct Kernel<'a, const N: usize>(&'a Stencil<N>, &'a [usize; 3], &'a AxisField, f64);
    impl<const N: usize> RowKernel for Kernel<'_, N> {
        type Output = (Vector3<f64>, Matrix3<f64>);
        #[inline(always)]
        fn run<R: Rows>(self, r: R) -> Self::Output {
            gather_affine_rows(r, self.0, self.1, self.2, self.3)
        }
    }
    dispatch_rows(simd, Kernel(s, strides, grid_v, inv_d))
}

#[inline(always)]
fn gather_affine_rows<R: Rows, const N: usize>(
    r: R,
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &AxisField,
    inv_d: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    let i0 = s.base_index(strides);
    let zero = [r.zero(); 3];
    // Per lane c, per component: sum_ab w_a w_b v, sum_ab w_a d_a w_b v, sum_ab w_a w_b d_b v.
    let (mut acc, mut acc0, mut acc1) = (zero, zero, zero);
    for a in 0..N {
        let (mut sa, mut sa1) = (zero, zero);
        for b in 0..N {
            let row = i0 + a * strides[0] + b * strides[1];
            let (wb, wbd) = (r.splat(s.w[1][b]), r.splat(s.w[1][b] * s.dpos[1][b]));
            for k in 0..3 {
                let v = r.load_first(&grid_v.axes[k][row..], N);
                sa[k] = r.add_mul(sa[k], wb, v);
                sa1[k] = r.add_mul(sa1[k], wbd, v);
            }
        }
        let (wa, wad) = (r.splat(s.w[0][a]), r.splat(s.w[0][a] * s.dpos[0][a]));
        for k in 0..3 {
            acc[k] = r.add_mul(acc[k], wa, sa[k]);
            acc0[k] = r.add_mul(acc0[k], wad, sa[k]);
            acc1[k] = r.add_mul(acc1[k], wa, sa1[k]);
        }
    }
    let wc = r.load_first(&s.w[2], N);
    let wcd = r.mul(wc, r.load_first(&s.dpos[2], N));
    let mut vel = Vector3::zeros();
    let mut b_mat = Matrix3::zeros(); // sum w v (x_i - x_p)^T
    for k in 0..3 {
        vel[k] = r.dot(wc, acc[k]);
        b_mat[(k, 0)] = r.dot(wc, acc0[k]);
        b_mat[(k, 1)] = r.dot(wc, acc1[k]);
        b_mat[(k, 2)] = r.dot(wcd, acc[k]);
    }
    (vel, inv_d * b_mat)
}

/// Reverse of [`gather_affine`]: given dL/dv_p and dL/dC_p (and the forward `v_p`), adds
/// dL/dv_i into the tile's channels 0, 1, 2 (the axes) and returns this gather's part of dL/dx_p:
/// `sum_i grad w_ip (v_i . u_i) - D^-1 gC^T v_p` with `u_i = gv + D^-1 gC (x_i - x_p)`.
/// On stencil rows, as the forward gather: the weight gradient's sums are kept per lane and
/// weighted by the row's `w_c` (or `w_c'`) at the end.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn gather_affine_reverse<const N: usize>(
    simd: SimdLevel,
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &AxisField,
    inv_d: f64,
    grad_vel: &Vector3<f64>,
    grad_c: &Matrix3<f64>,
    vel: &Vector3<f64>,
    grad_grid_v: &mut Tile,
) -> Vector3<f64> {
    struct Kernel<'a, 't, const N: usize> {
        s: &'a Stencil<N>,
        strides: &'a [usize; 3],
        grid_v: &'a AxisField,
        gc: Matrix3<f64>,
        grad_vel: &'a Vector3<f64>,
        grad_grid_v: &'a mut Tile<'t>,
    }
    impl<const N: usize> RowKernel for Kernel<'_, '_, N> {
        type Output = Vector3<f64>;
        #[inline(always)]
        #[allow(clippy::needless_range_loop)] // index loops: the lane code's form
        fn run<R: Rows>(self, r: R) -> Vector3<f64> {
            let Kernel {
                s,
                strides,
                grid_v,
                gc,
                grad_vel,
                grad_grid_v,
            } = self;
            let i0 = s.base_index(strides);
            let t0 = grad_grid_v.base(s);
            let ts = &Tile::STRIDES;
            let zero = r.zero();
            let wc = r.load_first(&s.w[2], N);
            let dwc = r.load_first(&s.dw[2], N);
            let dc = r.load_first(&s.dpos[2], N);
            let gz = [
                r.splat(gc[(0, 2)]),
                r.splat(gc[(1, 2)]),
                r.splat(gc[(2, 2)]),
            ];
            // Per lane: sum_a w_a' sum_b w_b e, sum_a w_a sum_b w_b' e, sum_a w_a sum_b w_b e.
            let (mut g0, mut g1, mut g2) = (zero, zero, zero);
            for a in 0..N {
                let ua = grad_vel + gc.column(0) * s.dpos[0][a];
                let (mut e_w, mut e_dw1) = (zero, zero);
                for b in 0..N {
                    let uab = ua + gc.column(1) * s.dpos[1][b];
                    let row = i0 + a * strides[0] + b * strides[1];
                    let mut u = [zero; 3];
                    let mut vu = zero;
                    for k in 0..3 {
                        u[k] = r.add_mul(r.splat(uab[k]), gz[k], dc);
                        let v = r.load_first(&grid_v.axes[k][row..], N);
                        vu = if k == 0 {
                            r.mul(v, u[k])
                        } else {
                            r.add_mul(vu, v, u[k])
                        };
                    }
                    // dL/dv_i += w_i u_i.
                    let w = r.mul(r.splat(s.w[0][a] * s.w[1][b]), wc);
                    let t_row = t0 + a * ts[0] + b * ts[1];
                    for k in 0..3 {
                        r.add_into(grad_grid_v.run(k, t_row, N), r.mul(w, u[k]));
                    }
                    e_w = r.add_mul(e_w, r.splat(s.w[1][b]), vu);
                    e_dw1 = r.add_mul(e_dw1, r.splat(s.dw[1][b]), vu);
                }
                g0 = r.add_mul(g0, r.splat(s.dw[0][a]), e_w);
                g1 = r.add_mul(g1, r.splat(s.w[0][a]), e_dw1);
                g2 = r.add_mul(g2, r.splat(s.w[0][a]), e_w);
            }
            Vector3::new(r.dot(wc, g0), r.dot(wc, g1), r.dot(dwc, g2))
        }
    }
    let gc = inv_d * grad_c;
    let gx = dispatch_rows(
        simd,
        Kernel {
            s,
            strides,
            grid_v,
            gc,
            grad_vel,
            grad_grid_v,
        },
    );
    gx - gc.transpose() * vel
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

/// Reverse of [`interpolate`]: scatters `w g` into the tile's channels `c0 .. c0 + 3` (the
/// axes) and returns dL/dx_p = `sum_i grad w_ip (a_i . g)`.
#[inline]
pub fn interpolate_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    field: &[Vector3<f64>],
    grad: &Vector3<f64>,
    grad_field: &mut Tile,
    c0: usize,
) -> Vector3<f64> {
    let mut grad_x = Vector3::zeros();
    let (t0, ts) = (grad_field.base(s), Tile::STRIDES);
    s.for_each_node(strides, |i, w, _, (a, b, c)| {
        grad_x += grad_w(s, a, b, c) * field[i].dot(grad);
        let t = t0 + a * ts[0] + b * ts[1] + c;
        for j in 0..3 {
            grad_field.channel(c0 + j)[t] += w * grad[j];
        }
    });
    grad_x
}

/// Mass-only scatter (for losses on the nodal mass grid) into the tile's channel 0:
/// `m_i += w_ip m_p`.
#[inline]
pub fn scatter_mass<const N: usize>(s: &Stencil<N>, mass: f64, tile: &mut Tile) {
    let t0 = tile.base(s);
    let ts = Tile::STRIDES;
    s.for_each_node(&ts, |_, w, _, (a, b, c)| {
        tile.channel(0)[t0 + a * ts[0] + b * ts[1] + c] += w * mass;
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
/// tiled scatter adds into each node in an order fixed by the positions.
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
    let (origin, dx) = (grid.origin_vec(), grid.dx);
    bins.scatter(true, &mut Vec::new(), &mut [&mut out], |tile, p| {
        let s = Stencil::<N>::new(&positions[p], &origin, dx);
        scatter_mass(&s, masses[p], tile);
    });
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
