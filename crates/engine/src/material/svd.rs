//! Fast, inversion-safe 3x3 singular value decomposition in f64.
//!
//! `F = U diag(sigma) V^T` with `U` and `V` proper rotations (det = +1). The sign of `det F`
//! is carried by the smallest singular value `sigma[2]`, so an inverted element yields a
//! negative `sigma[2]` instead of a reflection in `U` or `V`. That is what fixed-corotated
//! elasticity needs: `R = U V^T` is then always a rotation.
//!
//! Method (McAdams et al. 2011, without their float tricks): cyclic Jacobi eigen-decomposition
//! of the symmetric `F^T F` gives `V`; a Givens QR of `F V` gives `U` and the signed singular
//! values. The QR step reads the singular values off `F V` directly instead of taking square
//! roots of eigenvalues, so small singular values keep their precision. nalgebra's general
//! SVD is about 2x slower on 3x3 (`morph bench` times both). The stress stage runs the
//! same arithmetic across vector lanes ([`eigen_soa`], [`svd_from_eigen_lanes`],
//! [`svd3_batch`]): many matrices at once, so their latency chains overlap, with the bits of
//! [`svd3`] in every lane. Near F = I, Jacobi needs about
//! 3 rotating sweeps (measured 4.2 sweeps per call including the final check sweep); the cost
//! is the latency of each rotation's sqrt/div chain, not flops.

use crate::lanes::{F64s, LaneKernel, Mask, SimdLevel};
use nalgebra::{Matrix3, Vector3};

/// Result of [`svd3`]: `F = u * diag(sigma) * v^T`.
#[derive(Clone, Copy, Debug)]
pub struct Svd3 {
    pub u: Matrix3<f64>,
    pub sigma: Vector3<f64>,
    pub v: Matrix3<f64>,
}

impl Svd3 {
    /// The rotation of the polar decomposition `F = R S`.
    pub fn rotation(&self) -> Matrix3<f64> {
        self.u * self.v.transpose()
    }
}

/// Symmetric eigen-decompositions of `L` matrices by cyclic Jacobi sweeps, run in lockstep;
/// returns (eigenvalues, V) per lane with V a rotation whose columns are the eigenvectors.
///
/// Works on the six unique entries: a rotation in the (p, q) plane zeroes `a_pq` and mixes the
/// remaining off-diagonals `a_rp`, `a_rq`, about 4x fewer flops than updating a full 3x3.
/// Convergence is quadratic; a pair is skipped once `a_pq` is below 1e-18 of its diagonal.
/// Each rotation is a dependent chain of divisions and square roots, so a single matrix is
/// latency-bound. This is the scalar reference (`L = 1` in [`eigen`] and [`svd3`]);
/// [`eigen_soa`] runs the same arithmetic across vector lanes, where the chains of many
/// matrices overlap, and gives the same bits.
fn symmetric_eigen_lanes<const L: usize>(
    a: &[Matrix3<f64>; L],
) -> [(Vector3<f64>, Matrix3<f64>); L] {
    let mut d: [[f64; 3]; L] = std::array::from_fn(|l| [a[l][(0, 0)], a[l][(1, 1)], a[l][(2, 2)]]);
    // off[k] is the entry opposite diagonal k: off[0] = a12, off[1] = a02, off[2] = a01.
    let mut off: [[f64; 3]; L] =
        std::array::from_fn(|l| [a[l][(1, 2)], a[l][(0, 2)], a[l][(0, 1)]]);
    let mut v = [Matrix3::identity(); L];
    let mut done = [false; L];
    for _sweep in 0..16 {
        let mut rotated = [false; L];
        for r in [2usize, 1, 0] {
            // Plane (p, q) is the pair without r.
            let (p, q) = match r {
                2 => (0, 1),
                1 => (0, 2),
                _ => (1, 2),
            };
            for l in 0..L {
                let (d, off, v) = (&mut d[l], &mut off[l], &mut v[l]);
                let apq = off[r];
                if done[l] || apq.abs() <= 1e-18 * (d[p].abs() + d[q].abs()) || apq == 0.0 {
                    continue;
                }
                rotated[l] = true;
                let theta = (d[q] - d[p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                d[p] -= t * apq;
                d[q] += t * apq;
                off[r] = 0.0;
                // The off-diagonals a_rp (opposite q) and a_rq (opposite p).
                let arp = off[q];
                let arq = off[p];
                off[q] = c * arp - s * arq;
                off[p] = s * arp + c * arq;
                for k in 0..3 {
                    let vkp = v[(k, p)];
                    let vkq = v[(k, q)];
                    v[(k, p)] = c * vkp - s * vkq;
                    v[(k, q)] = s * vkp + c * vkq;
                }
            }
        }
        for l in 0..L {
            done[l] |= !rotated[l];
        }
        if done.iter().all(|&x| x) {
            break;
        }
    }
    std::array::from_fn(|l| (Vector3::new(d[l][0], d[l][1], d[l][2]), v[l]))
}

/// A 3x3 matrix per lane, `m[row][column]`.
pub type M3s<const L: usize> = [[F64s<L>; 3]; 3];

/// `L` matrices in lanes.
#[inline(always)]
pub fn to_lanes<const L: usize>(m: &[Matrix3<f64>; L]) -> M3s<L> {
    let mut out = [[F64s::splat(0.0); 3]; 3];
    for (l, m) in m.iter().enumerate() {
        for i in 0..3 {
            for j in 0..3 {
                out[i][j].0[l] = m[(i, j)];
            }
        }
    }
    out
}

/// Lane `l` of `m` as a matrix.
#[inline(always)]
pub fn lane_of<const L: usize>(m: &M3s<L>, l: usize) -> Matrix3<f64> {
    let mut out = Matrix3::zeros();
    for i in 0..3 {
        for j in 0..3 {
            out[(i, j)] = m[i][j].0[l];
        }
    }
    out
}

/// `a b` per lane, each entry summed left to right as nalgebra's 3x3 product does.
#[inline(always)]
pub fn mul_lanes<const L: usize>(a: &M3s<L>, b: &M3s<L>) -> M3s<L> {
    let mut out = [[F64s::splat(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    out
}

/// `a^T b` per lane (summed as [`mul_lanes`]).
#[inline(always)]
pub fn transpose_mul_lanes<const L: usize>(a: &M3s<L>, b: &M3s<L>) -> M3s<L> {
    let mut out = [[F64s::splat(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = a[0][i] * b[0][j] + a[1][i] * b[1][j] + a[2][i] * b[2][j];
        }
    }
    out
}

/// `a b^T` per lane (summed as [`mul_lanes`]).
#[inline(always)]
pub fn mul_transpose_lanes<const L: usize>(a: &M3s<L>, b: &M3s<L>) -> M3s<L> {
    let mut out = [[F64s::splat(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = a[i][0] * b[j][0] + a[i][1] * b[j][1] + a[i][2] * b[j][2];
        }
    }
    out
}

/// The SVD of `L` matrices in lanes: `f = u diag(sigma) v^T` per lane.
#[derive(Clone, Copy, Debug)]
pub struct Svd3s<const L: usize> {
    pub u: M3s<L>,
    pub sigma: [F64s<L>; 3],
    pub v: M3s<L>,
}

impl<const L: usize> Svd3s<L> {
    /// The polar rotation `u v^T` per lane ([`Svd3::rotation`]'s bits).
    #[inline(always)]
    pub fn rotation(&self) -> M3s<L> {
        mul_transpose_lanes(&self.u, &self.v)
    }
}

/// The Jacobi sweeps of [`eigen`] on `f^T f` for `L` matrices in vector lanes
/// ([`crate::lanes`]): (eigenvalues, V). Lane `l` does exactly the arithmetic the scalar
/// sweeps do on matrix `l` (a rotation a lane would skip is computed and discarded by a
/// select), so each lane gets [`eigen`]'s bits.
#[inline(always)]
pub fn eigen_soa<const L: usize>(f: &M3s<L>) -> ([F64s<L>; 3], M3s<L>) {
    // f^T f, each entry summed as nalgebra sums `f.transpose() * f`.
    let mut a = [[F64s::splat(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            a[i][j] = f[0][i] * f[0][j] + f[1][i] * f[1][j] + f[2][i] * f[2][j];
        }
    }
    let mut d = [a[0][0], a[1][1], a[2][2]];
    // off[k] is the entry opposite diagonal k, as in the scalar sweeps.
    let mut off = [a[1][2], a[0][2], a[0][1]];
    let (zero, one) = (F64s::<L>::splat(0.0), F64s::<L>::splat(1.0));
    let mut v = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    let mut done = Mask::<L>::splat(false);
    for _sweep in 0..16 {
        let mut rotated = Mask::<L>::splat(false);
        for r in [2usize, 1, 0] {
            let (p, q) = match r {
                2 => (0, 1),
                1 => (0, 2),
                _ => (1, 2),
            };
            let apq = off[r];
            let skip = done
                .or(apq.abs().le((d[p].abs() + d[q].abs()) * 1e-18))
                .or(apq.eq(zero));
            let act = skip.negate();
            if !act.any() {
                continue;
            }
            rotated = rotated.or(act);
            let theta = (d[q] - d[p]) / (apq * 2.0);
            let t = one.copysign(theta) / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = F64s::select(theta.eq(zero), one, t);
            let c = one / (t * t + 1.0).sqrt();
            let s = t * c;
            d[p] = F64s::select(act, d[p] - t * apq, d[p]);
            d[q] = F64s::select(act, d[q] + t * apq, d[q]);
            off[r] = F64s::select(act, zero, off[r]);
            let (arp, arq) = (off[q], off[p]);
            off[q] = F64s::select(act, c * arp - s * arq, arp);
            off[p] = F64s::select(act, s * arp + c * arq, arq);
            for row in &mut v {
                let (vkp, vkq) = (row[p], row[q]);
                row[p] = F64s::select(act, c * vkp - s * vkq, vkp);
                row[q] = F64s::select(act, s * vkp + c * vkq, vkq);
            }
        }
        done = done.or(rotated.negate());
        if done.all() {
            break;
        }
    }
    (d, v)
}

/// [`svd3_from_eigen`] in lanes: sort, then the Givens QR of `F V`, every branch of the
/// scalar code a select, so each lane gets the scalar bits.
#[inline(always)]
pub fn svd_from_eigen_lanes<const L: usize>(
    f: &M3s<L>,
    eig: [F64s<L>; 3],
    mut v: M3s<L>,
) -> Svd3s<L> {
    let mut e = eig;
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let m = e[i].lt(e[j]);
        (e[i], e[j]) = (F64s::select(m, e[j], e[i]), F64s::select(m, e[i], e[j]));
        for row in &mut v {
            let (vi, vj) = (row[i], row[j]);
            row[i] = F64s::select(m, vj, vi);
            row[j] = F64s::select(m, -vi, vj);
        }
    }
    let mut b = mul_lanes(f, &v);
    let (zero, one) = (F64s::<L>::splat(0.0), F64s::<L>::splat(1.0));
    let mut u = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    for (i, j, col) in [(0, 1, 0), (0, 2, 0), (1, 2, 1)] {
        let (a, c_) = (b[i][col], b[j][col]);
        let r = (a * a + c_ * c_).sqrt();
        let act = r.eq(zero).or(c_.eq(zero)).negate();
        if !act.any() {
            continue;
        }
        let (c, s) = (a / r, c_ / r);
        let (row_i, row_j) = (b[i], b[j]);
        for k in 0..3 {
            let (bi, bj) = (row_i[k], row_j[k]);
            b[i][k] = F64s::select(act, c * bi + s * bj, bi);
            b[j][k] = F64s::select(act, -s * bi + c * bj, bj);
        }
        for row in &mut u {
            let (qi, qj) = (row[i], row[j]);
            row[i] = F64s::select(act, c * qi + s * qj, qi);
            row[j] = F64s::select(act, -s * qi + c * qj, qj);
        }
    }
    let mut sigma = [b[0][0], b[1][1], b[2][2]];
    for k in 0..2 {
        let m = sigma[k].lt(zero);
        sigma[k] = F64s::select(m, -sigma[k], sigma[k]);
        sigma[2] = F64s::select(m, -sigma[2], sigma[2]);
        for row in &mut u {
            row[k] = F64s::select(m, -row[k], row[k]);
            row[2] = F64s::select(m, -row[2], row[2]);
        }
    }
    Svd3s { u, sigma, v }
}

/// Givens rotation acting on rows (i, j) of `b` that zeroes `b[(j, col)]` into `b[(i, col)]`;
/// the same rotation is accumulated into the columns of `q` so that `q * b` is invariant.
#[inline]
fn givens_zero(b: &mut Matrix3<f64>, q: &mut Matrix3<f64>, i: usize, j: usize, col: usize) {
    let a = b[(i, col)];
    let c_ = b[(j, col)];
    let r = (a * a + c_ * c_).sqrt();
    if r == 0.0 || c_ == 0.0 {
        return;
    }
    let (c, s) = (a / r, c_ / r);
    for k in 0..3 {
        let bi = b[(i, k)];
        let bj = b[(j, k)];
        b[(i, k)] = c * bi + s * bj;
        b[(j, k)] = -s * bi + c * bj;
    }
    for k in 0..3 {
        let qi = q[(k, i)];
        let qj = q[(k, j)];
        q[(k, i)] = c * qi + s * qj;
        q[(k, j)] = -s * qi + c * qj;
    }
}

/// Inversion-safe SVD of a 3x3 matrix (see module docs).
pub fn svd3(f: &Matrix3<f64>) -> Svd3 {
    let [(eig, v)] = symmetric_eigen_lanes(&[f.transpose() * f]);
    finish(f, eig, v)
}

/// [`svd3`] of every matrix of `f`, in the vector lanes of `simd` ([`crate::lanes`]; the
/// matrices that do not fill a batch one at a time): bitwise [`svd3`]'s results.
pub fn svd3_batch(simd: SimdLevel, f: &[Matrix3<f64>]) -> Vec<Svd3> {
    struct Batch<'a>(&'a [Matrix3<f64>]);
    impl LaneKernel for Batch<'_> {
        type Output = Vec<Svd3>;
        #[inline(always)]
        fn run<const L: usize>(self) -> Vec<Svd3> {
            let mut out = Vec::with_capacity(self.0.len());
            let mut i = 0;
            while i + L <= self.0.len() {
                let f = to_lanes::<L>(self.0[i..i + L].try_into().expect("L matrices"));
                let (e, v) = eigen_soa(&f);
                let s = svd_from_eigen_lanes(&f, e, v);
                for l in 0..L {
                    out.push(Svd3 {
                        u: lane_of(&s.u, l),
                        sigma: Vector3::new(s.sigma[0].0[l], s.sigma[1].0[l], s.sigma[2].0[l]),
                        v: lane_of(&s.v, l),
                    });
                }
                i += L;
            }
            for f in &self.0[i..] {
                out.push(svd3(f));
            }
            out
        }
    }
    crate::lanes::dispatch(simd, Batch(f))
}

/// The eigen-decomposition of `F^T F` behind [`svd3`]: `(eigenvalues, V)` as the Jacobi
/// sweeps leave them. [`svd3_from_eigen`] turns it into the SVD, bitwise what [`svd3`] gives;
/// the reverse pass keeps it rather than sweeping again.
pub fn eigen(f: &Matrix3<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let [e] = symmetric_eigen_lanes(&[f.transpose() * f]);
    e
}

/// The SVD of `f` from the eigen-decomposition of `F^T F` ([`eigen`]).
pub fn svd3_from_eigen(f: &Matrix3<f64>, eig: Vector3<f64>, v: Matrix3<f64>) -> Svd3 {
    finish(f, eig, v)
}

/// From the eigen-decomposition of `F^T F` to the SVD: sort, then Givens QR of `F V`.
fn finish(f: &Matrix3<f64>, eig: Vector3<f64>, mut v: Matrix3<f64>) -> Svd3 {
    // Sort eigenvalues in descending order; each column swap flips det V, so negate the
    // swapped-in column to keep V a rotation.
    let mut e = [eig[0], eig[1], eig[2]];
    let swap = |e: &mut [f64; 3], v: &mut Matrix3<f64>, i: usize, j: usize| {
        if e[i] < e[j] {
            e.swap(i, j);
            v.swap_columns(i, j);
            v.set_column(j, &(-v.column(j)));
        }
    };
    swap(&mut e, &mut v, 0, 1);
    swap(&mut e, &mut v, 0, 2);
    swap(&mut e, &mut v, 1, 2);

    // QR of B = F V by Givens rotations: B = U R, R upper triangular with (numerically)
    // zero off-diagonals because the columns of B are orthogonal.
    let mut b = f * v;
    let mut u = Matrix3::identity();
    givens_zero(&mut b, &mut u, 0, 1, 0);
    givens_zero(&mut b, &mut u, 0, 2, 0);
    givens_zero(&mut b, &mut u, 1, 2, 1);
    let mut sigma = Vector3::new(b[(0, 0)], b[(1, 1)], b[(2, 2)]);
    // Givens keeps the first two diagonals non-negative except for degenerate zero columns;
    // move any stray sign onto sigma[2] by flipping matching columns of U.
    for k in 0..2 {
        if sigma[k] < 0.0 {
            sigma[k] = -sigma[k];
            sigma[2] = -sigma[2];
            u.set_column(k, &(-u.column(k)));
            u.set_column(2, &(-u.column(2)));
        }
    }
    Svd3 { u, sigma, v }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn check(f: &Matrix3<f64>) {
        let s = svd3(f);
        let rec = s.u * Matrix3::from_diagonal(&s.sigma) * s.v.transpose();
        let scale = f.norm().max(1.0);
        assert!(
            (rec - f).norm() <= 1e-13 * scale,
            "reconstruction {}",
            (rec - f).norm()
        );
        assert!((s.u.transpose() * s.u - Matrix3::identity()).norm() < 1e-13);
        assert!((s.v.transpose() * s.v - Matrix3::identity()).norm() < 1e-13);
        assert!((s.u.determinant() - 1.0).abs() < 1e-12);
        assert!((s.v.determinant() - 1.0).abs() < 1e-12);
        assert!(s.sigma[0] >= s.sigma[1].abs() - 1e-12 && s.sigma[1] >= s.sigma[2].abs() - 1e-12);
        assert_eq!(
            s.sigma[2] < 0.0,
            f.determinant() < 0.0,
            "sign carried by sigma[2]"
        );
    }

    #[test]
    fn the_batch_svd_gives_the_scalar_bits_at_every_width() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
        // Enough for whole batches and a remainder at every width; at rest, near rest,
        // inverted, with repeated singular values, singular, and at random.
        let f: Vec<Matrix3<f64>> = (0..203)
            .map(|i| match i % 6 {
                0 => Matrix3::identity(),
                1 => Matrix3::identity() + Matrix3::from_fn(|_, _| rng.random_range(-0.05..0.05)),
                2 => Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)),
                3 => Matrix3::from_diagonal(&Vector3::new(0.5, 2.0, 2.0)),
                4 => Matrix3::zeros(),
                _ => Matrix3::from_fn(|_, _| rng.random_range(-2.0..2.0)),
            })
            .collect();
        for simd in SimdLevel::available_levels() {
            for (m, s) in f.iter().zip(svd3_batch(simd, &f)) {
                let one = svd3(m);
                assert_eq!((one.u, one.sigma, one.v), (s.u, s.sigma, s.v), "{simd:?}");
            }
        }
    }

    #[test]
    fn random_identity_rotations_inverted_and_degenerate() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for _ in 0..2000 {
            let f = Matrix3::from_fn(|_, _| rng.random_range(-2.0..2.0));
            check(&f);
        }
        check(&Matrix3::identity());
        check(&Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)));
        check(&Matrix3::from_diagonal(&Vector3::new(2.0, 2.0, 0.5)));
        let rot = nalgebra::Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
        check(&rot);
        check(&(rot * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0 + 1e-9, 1.0))));
    }
}
