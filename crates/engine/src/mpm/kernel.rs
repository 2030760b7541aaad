//! Quadratic and cubic B-spline interpolation kernels.
//!
//! A particle at `x` touches an `N x N x N` stencil of grid nodes starting at `base`
//! (N = 3 for quadratic, 4 for cubic). Weights are tensor products of 1D B-splines and are
//! differentiable in `x`, which the reverse pass needs because every transfer moves with the
//! particle.

use crate::lanes::{RowKernel, Rows, SimdLevel, dispatch_rows};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Which B-spline the transfers use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum KernelKind {
    Quadratic,
    Cubic,
}

impl KernelKind {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [KernelKind; 2] = [KernelKind::Quadratic, KernelKind::Cubic];
}

impl KernelKind {
    /// Nodes per axis in the stencil.
    pub fn support(self) -> usize {
        match self {
            KernelKind::Quadratic => 3,
            KernelKind::Cubic => 4,
        }
    }

    /// `D^-1` of MLS-MPM / APIC, `(sum_i w_ip (x_i - x_p)(x_i - x_p)^T)^-1`, a multiple of I.
    pub fn inv_d(self, dx: f64) -> f64 {
        match self {
            KernelKind::Quadratic => 4.0 / (dx * dx),
            KernelKind::Cubic => 3.0 / (dx * dx),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            KernelKind::Quadratic => "quadratic",
            KernelKind::Cubic => "cubic",
        }
    }
}

pub use crate::lanes::floor;

/// Per-particle stencils kept between the transfers of one step (built once, read again):
/// the quadratic and the cubic kernel's, whichever the step uses.
#[derive(Clone, Debug, Default)]
pub struct StencilCache {
    quadratic: Vec<Stencil<3>>,
    cubic: Vec<Stencil<4>>,
}

/// The stencils a [`StencilCache`] holds for this support.
pub trait Cached: Sized {
    fn slot(cache: &mut StencilCache) -> &mut Vec<Self>;
}

impl Cached for Stencil<3> {
    fn slot(cache: &mut StencilCache) -> &mut Vec<Self> {
        &mut cache.quadratic
    }
}

impl Cached for Stencil<4> {
    fn slot(cache: &mut StencilCache) -> &mut Vec<Self> {
        &mut cache.cubic
    }
}

impl StencilCache {
    /// Room for `n` stencils of support `N` (their contents are whatever was there).
    pub fn sized<const N: usize>(&mut self, n: usize) -> &mut Vec<Stencil<N>>
    where
        Stencil<N>: Cached,
    {
        let v = <Stencil<N> as Cached>::slot(self);
        v.resize(n, Stencil::ZERO);
        v
    }
}

/// Weights of one particle on its `N^3` stencil, per axis.
#[derive(Clone, Copy, Debug)]
pub struct Stencil<const N: usize> {
    /// Grid index of the stencil's first node on each axis (may be out of range: the caller
    /// checks it against the grid).
    pub base: [i64; 3],
    /// 1D weights `w[axis][k]` for node `base + k`.
    pub w: [[f64; N]; 3],
    /// 1D weight derivatives with respect to the particle position (already divided by dx).
    pub dw: [[f64; N]; 3],
    /// `(x_node - x_p)` per axis and node, in world units.
    pub dpos: [[f64; N]; 3],
}

impl<const N: usize> Stencil<N> {
    pub const ZERO: Self = Stencil {
        base: [0; 3],
        w: [[0.0; N]; 3],
        dw: [[0.0; N]; 3],
        dpos: [[0.0; N]; 3],
    };

    /// Flat index of the stencil's first node in a grid with these node strides.
    #[inline(always)]
    pub fn base_index(&self, strides: &[usize; 3]) -> usize {
        self.base[0] as usize * strides[0]
            + self.base[1] as usize * strides[1]
            + self.base[2] as usize
    }

    /// Visits the stencil's nodes: `f(node index, weight, x_i - x_p, (a, b, c))`, the weight
    /// formed as `(w_a w_b) w_c` in every transfer.
    #[inline(always)]
    pub fn for_each_node(
        &self,
        strides: &[usize; 3],
        mut f: impl FnMut(usize, f64, Vector3<f64>, (usize, usize, usize)),
    ) {
        let i0 = self.base_index(strides);
        for a in 0..N {
            for b in 0..N {
                let wab = self.w[0][a] * self.w[1][b];
                let row = i0 + a * strides[0] + b * strides[1];
                for c in 0..N {
                    let d = Vector3::new(self.dpos[0][a], self.dpos[1][b], self.dpos[2][c]);
                    f(row + c, wab * self.w[2][c], d, (a, b, c));
                }
            }
        }
    }

    /// Stencil of a particle at world position `x` on a grid with node 0 at `origin`.
    #[inline]
    pub fn new(x: &Vector3<f64>, origin: &Vector3<f64>, dx: f64) -> Self {
        let inv_dx = 1.0 / dx;
        let mut base = [0i64; 3];
        let mut w = [[0.0; N]; 3];
        let mut dw = [[0.0; N]; 3];
        let mut dpos = [[0.0; N]; 3];
        for a in 0..3 {
            let xg = (x[a] - origin[a]) * inv_dx;
            // Quadratic: fx in [0.5, 1.5); cubic: fx in [1, 2). In that range each node's
            // distance falls in a known piece of the B-spline, so the weights need no branches.
            let b = if N == 3 {
                floor(xg - 0.5)
            } else {
                floor(xg) - 1.0
            };
            let fx = xg - b;
            base[a] = b as i64;
            let (wk, dwk) = if N == 3 {
                quadratic_pieces(fx)
            } else {
                cubic_pieces(fx)
            };
            for k in 0..N {
                w[a][k] = wk[k];
                dw[a][k] = dwk[k] * inv_dx;
                dpos[a][k] = (k as f64 - fx) * dx;
            }
        }
        Stencil { base, w, dw, dpos }
    }
}

impl<const N: usize> Stencil<N> {
    /// The stencils of many particles (`out[i]` for `xs[i]`), four at a time on vector lanes
    /// ([`crate::lanes::Rows`]), each lane computed as [`Stencil::new`] computes it: the
    /// same bits.
    pub fn fill(
        simd: SimdLevel,
        xs: &[Vector3<f64>],
        origin: &Vector3<f64>,
        dx: f64,
        out: &mut [Stencil<N>],
    ) {
        assert_eq!(xs.len(), out.len());
        struct Kernel<'a, const N: usize> {
            xs: &'a [Vector3<f64>],
            origin: &'a Vector3<f64>,
            dx: f64,
            out: &'a mut [Stencil<N>],
        }
        impl<const N: usize> RowKernel for Kernel<'_, N> {
            type Output = ();
            #[inline(always)]
            fn run<R: Rows>(self, r: R) {
                let Kernel {
                    xs,
                    origin,
                    dx,
                    out,
                } = self;
                let inv_dx = 1.0 / dx;
                let whole = xs.len() / 4 * 4;
                for (x4, o4) in xs[..whole].chunks_exact(4).zip(out.chunks_exact_mut(4)) {
                    for a in 0..3 {
                        let x = r.array([x4[0][a], x4[1][a], x4[2][a], x4[3][a]]);
                        let xg = r.mul(r.sub(x, r.splat(origin[a])), r.splat(inv_dx));
                        let b = if N == 3 {
                            r.floor(r.sub(xg, r.splat(0.5)))
                        } else {
                            r.sub(r.floor(xg), r.splat(1.0))
                        };
                        let fx = r.sub(xg, b);
                        let (wk, dwk) = if N == 3 {
                            quadratic_pieces_lanes(r, fx)
                        } else {
                            cubic_pieces_lanes(r, fx)
                        };
                        let b = r.to_array(b);
                        for (o, b) in o4.iter_mut().zip(b) {
                            o.base[a] = b as i64;
                        }
                        for k in 0..N {
                            let w = r.to_array(wk[k]);
                            let dw = r.to_array(r.mul(dwk[k], r.splat(inv_dx)));
                            let dpos = r.to_array(r.mul(r.sub(r.splat(k as f64), fx), r.splat(dx)));
                            for l in 0..4 {
                                o4[l].w[a][k] = w[l];
                                o4[l].dw[a][k] = dw[l];
                                o4[l].dpos[a][k] = dpos[l];
                            }
                        }
                    }
                }
                for (x, o) in xs[whole..].iter().zip(&mut out[whole..]) {
                    *o = Stencil::new(x, origin, dx);
                }
            }
        }
        dispatch_rows(
            simd,
            Kernel {
                xs,
                origin,
                dx,
                out,
            },
        );
    }
}

/// [`quadratic_pieces`] on four lanes (the same operations in the same order).
#[inline(always)]
fn quadratic_pieces_lanes<R: Rows>(r: R, fx: R::V) -> ([R::V; 4], [R::V; 4]) {
    let (a, c) = (r.sub(r.splat(1.5), fx), r.sub(fx, r.splat(0.5)));
    let d1 = r.sub(fx, r.splat(1.0));
    let half = r.splat(0.5);
    (
        [
            r.mul(r.mul(half, a), a),
            r.sub(r.splat(0.75), r.mul(d1, d1)),
            r.mul(r.mul(half, c), c),
            r.zero(),
        ],
        [r.neg(a), r.mul(r.splat(-2.0), d1), c, r.zero()],
    )
}

/// [`cubic_pieces`] on four lanes (the same operations in the same order).
#[inline(always)]
fn cubic_pieces_lanes<R: Rows>(r: R, fx: R::V) -> ([R::V; 4], [R::V; 4]) {
    let one = r.splat(1.0);
    let t = r.sub(fx, one);
    let u = r.sub(one, t);
    let (half, six, two_thirds) = (r.splat(0.5), r.splat(6.0), r.splat(2.0 / 3.0));
    let (onehalf, two) = (r.splat(1.5), r.splat(2.0));
    (
        [
            r.div(r.mul(r.mul(u, u), u), six),
            r.add(r.mul(r.mul(r.sub(r.mul(half, t), one), t), t), two_thirds),
            r.add(r.mul(r.mul(r.sub(r.mul(half, u), one), u), u), two_thirds),
            r.div(r.mul(r.mul(t, t), t), six),
        ],
        [
            r.mul(r.mul(r.splat(-0.5), u), u),
            r.mul(r.sub(r.mul(onehalf, t), two), t),
            r.mul(r.neg(r.sub(r.mul(onehalf, u), two)), u),
            r.mul(r.mul(half, t), t),
        ],
    )
}

/// Quadratic weights and derivatives (d/dfx) of the 3 nodes for `fx` in [0.5, 1.5).
#[inline(always)]
fn quadratic_pieces(fx: f64) -> ([f64; 4], [f64; 4]) {
    let (a, c) = (1.5 - fx, fx - 0.5);
    let d1 = fx - 1.0;
    (
        [0.5 * a * a, 0.75 - d1 * d1, 0.5 * c * c, 0.0],
        [-a, -2.0 * d1, c, 0.0],
    )
}

/// Cubic weights and derivatives (d/dfx) of the 4 nodes for `fx` in [1, 2).
#[inline(always)]
fn cubic_pieces(fx: f64) -> ([f64; 4], [f64; 4]) {
    let t = fx - 1.0; // in [0, 1)
    let u = 1.0 - t;
    (
        [
            u * u * u / 6.0,
            (0.5 * t - 1.0) * t * t + 2.0 / 3.0,
            (0.5 * u - 1.0) * u * u + 2.0 / 3.0,
            t * t * t / 6.0,
        ],
        [
            -0.5 * u * u,
            (1.5 * t - 2.0) * t,
            -(1.5 * u - 2.0) * u,
            0.5 * t * t,
        ],
    )
}

/// Quadratic B-spline N(d) and N'(d) for the distance d (in cells) from node to particle
/// (reference for the tests of the branch-free pieces).
#[cfg(test)]
fn quadratic(d: f64) -> (f64, f64) {
    let a = d.abs();
    if a < 0.5 {
        (0.75 - d * d, -2.0 * d)
    } else if a < 1.5 {
        let t = 1.5 - a;
        (0.5 * t * t, -t * d.signum())
    } else {
        (0.0, 0.0)
    }
}

/// Cubic B-spline N(d) and N'(d) (reference for the tests).
#[cfg(test)]
fn cubic(d: f64) -> (f64, f64) {
    let a = d.abs();
    if a < 1.0 {
        (0.5 * a * a * a - a * a + 2.0 / 3.0, (1.5 * a - 2.0) * d)
    } else if a < 2.0 {
        let t = 2.0 - a;
        (t * t * t / 6.0, -0.5 * t * t * d.signum())
    } else {
        (0.0, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fill_matches_new<const N: usize>() {
        let origin = Vector3::new(-3.0, -2.5, -3.25);
        let dx = 0.37;
        let xs: Vec<Vector3<f64>> = (0..43)
            .map(|i| {
                let t = i as f64;
                Vector3::new(
                    (t * 0.731).sin(),
                    (t * 1.37).cos() * 1.5,
                    (t * 0.19).sin() * 2.0,
                )
            })
            .chain([
                Vector3::new(-2.0, -1.0, 0.0),
                Vector3::new(0.5 * dx - 3.0, 0.0, 1.0),
            ])
            .collect();
        let expected: Vec<Stencil<N>> = xs.iter().map(|x| Stencil::new(x, &origin, dx)).collect();
        for level in SimdLevel::available_levels() {
            let mut out = vec![Stencil::<N>::ZERO; xs.len()];
            Stencil::fill(level, &xs, &origin, dx, &mut out);
            for (p, (a, b)) in out.iter().zip(&expected).enumerate() {
                assert_eq!(a.base, b.base, "{level:?} particle {p}");
                let bits =
                    |s: &Stencil<N>| [s.w, s.dw, s.dpos].map(|m| m.map(|r| r.map(f64::to_bits)));
                assert_eq!(bits(a), bits(b), "{level:?} particle {p}");
            }
        }
    }

    #[test]
    fn stencils_filled_on_lanes_are_bitwise_those_made_one_by_one() {
        fill_matches_new::<3>();
        fill_matches_new::<4>();
    }

    fn check<const N: usize>(kind: KernelKind) {
        let origin = Vector3::new(-3.0, -3.0, -3.0);
        let dx = 0.7;
        for x in [0.013, 0.49, 0.5, 0.77, 1.0, 1.31] {
            let p = Vector3::new(x, -x, 0.3 * x);
            let s = Stencil::<N>::new(&p, &origin, dx);
            for a in 0..3 {
                // Partition of unity, linear reproduction, and the second moment behind D^-1.
                let sum: f64 = s.w[a].iter().sum();
                let first: f64 = (0..N).map(|k| s.w[a][k] * s.dpos[a][k]).sum();
                let second: f64 = (0..N).map(|k| s.w[a][k] * s.dpos[a][k].powi(2)).sum();
                assert!((sum - 1.0).abs() < 1e-14);
                assert!(first.abs() < 1e-14);
                assert!((second * kind.inv_d(dx) - 1.0).abs() < 1e-13);
                // Derivative against central differences.
                let h = 1e-7;
                let mut pp = p;
                pp[a] += h;
                let mut pm = p;
                pm[a] -= h;
                let sp = Stencil::<N>::new(&pp, &origin, dx);
                let sm = Stencil::<N>::new(&pm, &origin, dx);
                if sp.base == s.base && sm.base == s.base {
                    for k in 0..N {
                        let fd = (sp.w[a][k] - sm.w[a][k]) / (2.0 * h);
                        assert!((fd - s.dw[a][k]).abs() < 1e-6);
                    }
                }
            }
        }
    }

    #[test]
    fn fast_floor_equals_floor() {
        for v in [
            0.0,
            0.3,
            1.0,
            1.5,
            -0.2,
            -1.0,
            -1.5,
            2.999999999,
            1e10 + 0.5,
            -1e10 - 0.5,
            5e15,
            -5e15,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert_eq!(floor(v), v.floor(), "{v}");
        }
        assert!(floor(f64::NAN).is_nan());
        for i in 0..10_000 {
            let v = (i as f64 - 5000.0) * 0.0137;
            assert_eq!(floor(v), v.floor(), "{v}");
        }
    }

    #[test]
    fn pieces_match_the_b_spline_definition() {
        for i in 0..100 {
            let fq = 0.5 + i as f64 / 100.0;
            let (w, dw) = quadratic_pieces(fq);
            for k in 0..3 {
                let (a, b) = quadratic(fq - k as f64);
                assert!((w[k] - a).abs() < 1e-15 && (dw[k] - b).abs() < 1e-15);
            }
            let fc = 1.0 + i as f64 / 100.0;
            let (w, dw) = cubic_pieces(fc);
            for k in 0..4 {
                let (a, b) = cubic(fc - k as f64);
                assert!(
                    (w[k] - a).abs() < 1e-15 && (dw[k] - b).abs() < 1e-15,
                    "cubic k {k} fx {fc}"
                );
            }
        }
    }

    #[test]
    fn quadratic_moments_and_derivatives() {
        check::<3>(KernelKind::Quadratic);
    }

    #[test]
    fn cubic_moments_and_derivatives() {
        check::<4>(KernelKind::Cubic);
    }
}
