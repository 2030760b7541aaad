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
//! SVD is about 2x slower on 3x3 (`morph bench` times both). [`svd3_x4`] runs four matrices in
//! lockstep so their latency chains overlap. Near F = I, Jacobi needs about
//! 3 rotating sweeps (measured 4.2 sweeps per call including the final check sweep); the cost
//! is the latency of each rotation's sqrt/div chain, not flops.

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
/// latency-bound; interleaving lanes lets the CPU overlap their chains. Every lane does exactly
/// the arithmetic it would do alone (a converged lane is skipped), so results do not depend on
/// how matrices are grouped.
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

/// [`svd3`] of four matrices at once (same results, about twice the throughput).
pub fn svd3_x4(f: &[Matrix3<f64>; 4]) -> [Svd3; 4] {
    let ata = f.map(|m| m.transpose() * m);
    let eig = symmetric_eigen_lanes(&ata);
    std::array::from_fn(|l| finish(&f[l], eig[l].0, eig[l].1))
}

/// The eigen-decomposition of `F^T F` behind [`svd3_x4`]: `(eigenvalues, V)` per lane, as the
/// Jacobi sweeps leave them. [`svd3_from_eigen`] turns one into the SVD, bitwise what
/// [`svd3`] gives; the reverse pass keeps it rather than sweeping again.
pub fn eigen_x4(f: &[Matrix3<f64>; 4]) -> [(Vector3<f64>, Matrix3<f64>); 4] {
    symmetric_eigen_lanes(&f.map(|m| m.transpose() * m))
}

/// [`eigen_x4`] of one matrix.
pub fn eigen(f: &Matrix3<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let [e] = symmetric_eigen_lanes(&[f.transpose() * f]);
    e
}

/// The SVD of `f` from the eigen-decomposition of `F^T F` ([`eigen_x4`], [`eigen`]).
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
    fn four_lanes_give_the_same_bits_as_one() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
        for _ in 0..500 {
            let f: [Matrix3<f64>; 4] = std::array::from_fn(|i| {
                if i == 1 {
                    Matrix3::identity()
                } else {
                    Matrix3::from_fn(|_, _| rng.random_range(-2.0..2.0))
                }
            });
            let batch = svd3_x4(&f);
            for l in 0..4 {
                let one = svd3(&f[l]);
                assert_eq!(one.u, batch[l].u);
                assert_eq!(one.sigma, batch[l].sigma);
                assert_eq!(one.v, batch[l].v);
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
