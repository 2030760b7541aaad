//! Fixed-corotated elasticity (Stomakhin et al. 2012):
//! `Psi = mu sum_k (sigma_k - 1)^2 + lambda/2 (J - 1)^2`,
//! `P = 2 mu (F - R) + lambda (J - 1) cof F`, with `cof F = J F^-T`.

use super::svd::{
    M3s, Svd3, Svd3s, eigen, eigen_soa, lane_of, mul_lanes, mul_transpose_lanes,
    svd_from_eigen_lanes, svd3, svd3_from_eigen, to_lanes, transpose_mul_lanes,
};
use super::{ConstitutiveModel, cofactor, cofactor_differential};
use crate::lanes::F64s;
use crate::lanes::{self, SimdLevel};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct FixedCorotated {
    pub mu: f64,
    pub lambda: f64,
}

/// Numbers kept per particle for the reverse pass: the eigenvalues of `F^T F` and `V`.
const KEPT: usize = 12;

/// Smallest |sigma_i + sigma_j| allowed in the rotation differential. The sum only vanishes for
/// an inverted F with two singular values of opposite sign and equal size, a measure-zero set
/// where R itself is not differentiable; clamping keeps the gradient finite there.
const MIN_SIGMA_SUM: f64 = 1e-10;

impl FixedCorotated {
    pub fn new(mu: f64, lambda: f64) -> Self {
        Self { mu, lambda }
    }

    /// From Young's modulus and Poisson's ratio.
    pub fn from_young_poisson(e: f64, nu: f64) -> Self {
        let (mu, lambda) = super::lame_from_young_poisson(e, nu);
        Self { mu, lambda }
    }
}

/// Column `i` of `a` cross column `j` of `b`, per lane.
#[inline(always)]
fn cross_columns_of<const L: usize>(a: &M3s<L>, i: usize, b: &M3s<L>, j: usize) -> [F64s<L>; 3] {
    let (a, b) = ([a[0][i], a[1][i], a[2][i]], [b[0][j], b[1][j], b[2][j]]);
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `cof F` in lanes, its columns `f1 x f2, f2 x f0, f0 x f1` (`cof[column][row]`, each
/// entry as nalgebra's cross product forms it), and `J = f0 . cof0` as nalgebra's `dot` sums.
#[inline(always)]
fn cofactor_lanes<const L: usize>(f: &M3s<L>) -> ([[F64s<L>; 3]; 3], F64s<L>) {
    let cof = [
        cross_columns_of(f, 1, f, 2),
        cross_columns_of(f, 2, f, 0),
        cross_columns_of(f, 0, f, 1),
    ];
    let j = f[0][0] * cof[0][0] + f[1][0] * cof[0][1] + f[2][0] * cof[0][2];
    (cof, j)
}

#[inline(always)]
fn add3<const L: usize>(a: [F64s<L>; 3], b: [F64s<L>; 3]) -> [F64s<L>; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `(P(f[i]), dP(f[i])[df[i]])` for every particle, `L` at a time in vector lanes: the SVD
/// from the decompositions the forward pass kept (or from new Jacobi sweeps when `kept` is
/// empty), then [`FixedCorotated::stress_and_differential_lanes`]; the bits of one at a time.
struct DifferentialLanes<'a> {
    model: &'a FixedCorotated,
    f: &'a [Matrix3<f64>],
    kept: &'a [f64],
    df: &'a [Matrix3<f64>],
    p: &'a mut [Matrix3<f64>],
    dp: &'a mut [Matrix3<f64>],
}

impl lanes::LaneKernel for DifferentialLanes<'_> {
    type Output = ();

    #[inline(always)]
    fn run<const L: usize>(self) {
        let DifferentialLanes {
            model,
            f,
            kept,
            df,
            p,
            dp,
        } = self;
        let n = f.len();
        let mut i = 0;
        while i + L <= n {
            let fl = to_lanes::<L>(f[i..i + L].try_into().expect("L matrices"));
            let (e, v) = if kept.is_empty() {
                eigen_soa(&fl)
            } else {
                let zero = F64s::<L>::splat(0.0);
                let (mut e, mut v) = ([zero; 3], [[zero; 3]; 3]);
                for l in 0..L {
                    let k = &kept[(i + l) * KEPT..(i + l + 1) * KEPT];
                    for a in 0..3 {
                        e[a].0[l] = k[a];
                        for b in 0..3 {
                            v[b][a].0[l] = k[3 + 3 * a + b];
                        }
                    }
                }
                (e, v)
            };
            let svd = svd_from_eigen_lanes(&fl, e, v);
            let dfl = to_lanes::<L>(df[i..i + L].try_into().expect("L matrices"));
            let (pl, dpl) = model.stress_and_differential_lanes(&fl, &svd, &dfl);
            for l in 0..L {
                p[i + l] = lane_of(&pl, l);
                dp[i + l] = lane_of(&dpl, l);
            }
            i += L;
        }
        for j in i..n {
            let (e, v) = if kept.is_empty() {
                eigen(&f[j])
            } else {
                let k = &kept[j * KEPT..(j + 1) * KEPT];
                (
                    Vector3::from_column_slice(&k[..3]),
                    Matrix3::from_column_slice(&k[3..]),
                )
            };
            let svd = svd3_from_eigen(&f[j], e, v);
            (p[j], dp[j]) = model.stress_and_differential_with(&f[j], &svd, &df[j]);
        }
    }
}

/// `P(fe[i])` for every particle (and, unless `kept` is empty, the eigen-decomposition
/// behind each SVD), `L` particles at a time in vector lanes: the SVD
/// ([`eigen_soa`], [`svd_from_eigen_lanes`]) and the stress
/// ([`FixedCorotated::stress_lanes`]); the particles that do not fill a batch one at a time.
struct StressLanes<'a> {
    model: &'a FixedCorotated,
    fe: &'a [Matrix3<f64>],
    out: &'a mut [Matrix3<f64>],
    kept: &'a mut [f64],
}

impl lanes::LaneKernel for StressLanes<'_> {
    type Output = ();

    #[inline(always)]
    fn run<const L: usize>(self) {
        let StressLanes {
            model,
            fe,
            out,
            kept,
        } = self;
        let n = fe.len();
        let mut i = 0;
        while i + L <= n {
            let f = to_lanes::<L>(fe[i..i + L].try_into().expect("L matrices"));
            let (e, v) = eigen_soa(&f);
            if !kept.is_empty() {
                for l in 0..L {
                    let k = &mut kept[(i + l) * KEPT..(i + l + 1) * KEPT];
                    for a in 0..3 {
                        k[a] = e[a].0[l];
                        // Column-major, as nalgebra stores V.
                        for b in 0..3 {
                            k[3 + 3 * a + b] = v[b][a].0[l];
                        }
                    }
                }
            }
            let p = model.stress_lanes(&f, &svd_from_eigen_lanes(&f, e, v).rotation());
            for l in 0..L {
                out[i + l] = lane_of(&p, l);
            }
            i += L;
        }
        for j in i..n {
            let (e, v) = eigen(&fe[j]);
            if !kept.is_empty() {
                let k = &mut kept[j * KEPT..(j + 1) * KEPT];
                k[..3].copy_from_slice(e.as_slice());
                k[3..].copy_from_slice(v.as_slice());
            }
            let svd = svd3_from_eigen(&fe[j], e, v);
            out[j] = model.stress_with_rotation(&fe[j], &svd.rotation());
        }
    }
}

impl FixedCorotated {
    /// [`Self::stress_with_rotation`] in lanes, summed in the same order (the cofactor's cross
    /// products and the dot product as nalgebra forms them): the scalar bits in every lane.
    #[inline(always)]
    fn stress_lanes<const L: usize>(&self, f: &M3s<L>, r: &M3s<L>) -> M3s<L> {
        let (cof, j) = cofactor_lanes(f);
        self.stress_from_cofactor(f, r, &cof, j)
    }

    /// `2 mu (F - R) + lambda (J - 1) cof F` in lanes, from the cofactor and `J`.
    #[inline(always)]
    fn stress_from_cofactor<const L: usize>(
        &self,
        f: &M3s<L>,
        r: &M3s<L>,
        cof: &[[F64s<L>; 3]; 3],
        j: F64s<L>,
    ) -> M3s<L> {
        let k1 = 2.0 * self.mu;
        let k2 = (j - 1.0) * self.lambda;
        let mut p = [[F64s::splat(0.0); 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                p[a][b] = (f[a][b] - r[a][b]) * k1 + k2 * cof[b][a];
            }
        }
        p
    }

    /// [`Self::stress_and_differential_with`] in lanes, every sum in its order (nalgebra's
    /// products left to right, `sum()` column by column from zero), the clamp a select.
    #[inline(always)]
    fn stress_and_differential_lanes<const L: usize>(
        &self,
        f: &M3s<L>,
        s: &Svd3s<L>,
        df: &M3s<L>,
    ) -> (M3s<L>, M3s<L>) {
        let (cof, j) = cofactor_lanes(f);
        let p = self.stress_from_cofactor(f, &s.rotation(), &cof, j);
        let zero = F64s::<L>::splat(0.0);
        let g = mul_lanes(&transpose_mul_lanes(&s.u, df), &s.v);
        let mut w = [[zero; 3]; 3];
        for (i, jj) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let sum = s.sigma[i] + s.sigma[jj];
            let clamped = F64s::splat(MIN_SIGMA_SUM).copysign(sum);
            let denom = F64s::select(sum.abs().lt(F64s::splat(MIN_SIGMA_SUM)), clamped, sum);
            let wij = (g[i][jj] - g[jj][i]) / denom;
            w[i][jj] = wij;
            w[jj][i] = -wij;
        }
        let dr = mul_transpose_lanes(&mul_lanes(&s.u, &w), &s.v);
        // cof . dF summed column by column, as nalgebra's `sum()` does.
        let mut dj = zero;
        for b in 0..3 {
            for a in 0..3 {
                dj += cof[b][a] * df[a][b];
            }
        }
        // d cof[dF]: columns d1 x f2 + f1 x d2, d2 x f0 + f2 x d0, d0 x f1 + f0 x d1.
        let dcof = [
            add3(cross_columns_of(df, 1, f, 2), cross_columns_of(f, 1, df, 2)),
            add3(cross_columns_of(df, 2, f, 0), cross_columns_of(f, 2, df, 0)),
            add3(cross_columns_of(df, 0, f, 1), cross_columns_of(f, 0, df, 1)),
        ];
        let (k1, jm1) = (2.0 * self.mu, j - 1.0);
        let mut dp = [[zero; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                dp[a][b] =
                    (df[a][b] - dr[a][b]) * k1 + (dj * cof[b][a] + jm1 * dcof[b][a]) * self.lambda;
            }
        }
        (p, dp)
    }

    /// `(P(F), dP(F)[dF])` given the SVD of `F`.
    #[inline]
    fn stress_and_differential_with(
        &self,
        f: &Matrix3<f64>,
        s: &Svd3,
        df: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        let r = s.rotation();
        let cof = cofactor(f);
        let j = f.column(0).dot(&cof.column(0));
        let p = 2.0 * self.mu * (f - r) + self.lambda * (j - 1.0) * cof;

        // dR = U W V^T with W skew: W_ij = (G_ij - G_ji) / (sigma_i + sigma_j), G = U^T dF V.
        // This follows from F = R S: R^T dF - dF^T R = W' S + S W' (W' = R^T dR skew), solved in
        // the singular basis. It stays finite at repeated singular values (F near a rotation,
        // where the naive SVD derivative divides by sigma_i - sigma_j = 0).
        let g = s.u.transpose() * df * s.v;
        let mut w = Matrix3::zeros();
        for (i, jj) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let sum = s.sigma[i] + s.sigma[jj];
            let denom = if sum.abs() < MIN_SIGMA_SUM {
                MIN_SIGMA_SUM.copysign(sum)
            } else {
                sum
            };
            let wij = (g[(i, jj)] - g[(jj, i)]) / denom;
            w[(i, jj)] = wij;
            w[(jj, i)] = -wij;
        }
        let dr = s.u * w * s.v.transpose();
        let dj = cof.component_mul(df).sum();
        let dp = 2.0 * self.mu * (df - dr)
            + self.lambda * (dj * cof + (j - 1.0) * cofactor_differential(f, df));
        (p, dp)
    }

    /// `P` given the polar rotation `R` of `F`.
    #[inline]
    fn stress_with_rotation(&self, f: &Matrix3<f64>, r: &Matrix3<f64>) -> Matrix3<f64> {
        let cof = cofactor(f);
        let j = f.column(0).dot(&cof.column(0));
        2.0 * self.mu * (f - r) + self.lambda * (j - 1.0) * cof
    }
}

impl ConstitutiveModel for FixedCorotated {
    fn spec(&self) -> (super::MaterialModel, f64, f64) {
        (super::MaterialModel::FixedCorotated, self.mu, self.lambda)
    }

    fn energy_density(&self, f: &Matrix3<f64>) -> f64 {
        let s = svd3(f);
        let j = f.determinant();
        self.mu * (s.sigma.add_scalar(-1.0)).norm_squared() + 0.5 * self.lambda * (j - 1.0).powi(2)
    }

    fn stress(&self, f: &Matrix3<f64>) -> Matrix3<f64> {
        self.stress_with_rotation(f, &svd3(f).rotation())
    }

    fn stress_batch(&self, simd: SimdLevel, fe: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
        self.stress_batch_keeping(simd, fe, out, &mut []);
    }

    fn stress_and_differential(
        &self,
        f: &Matrix3<f64>,
        df: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        self.stress_and_differential_with(f, &svd3(f), df)
    }

    fn stress_and_differential_batch(
        &self,
        simd: SimdLevel,
        f: &[Matrix3<f64>],
        df: &[Matrix3<f64>],
        p: &mut [Matrix3<f64>],
        dp: &mut [Matrix3<f64>],
    ) {
        let kernel = DifferentialLanes {
            model: self,
            f,
            kept: &[],
            df,
            p,
            dp,
        };
        lanes::dispatch(simd, kernel);
    }

    fn kept_per_particle(&self) -> usize {
        KEPT
    }

    /// With `kept` empty, keeps nothing (the plain [`ConstitutiveModel::stress_batch`]).
    fn stress_batch_keeping(
        &self,
        simd: SimdLevel,
        fe: &[Matrix3<f64>],
        out: &mut [Matrix3<f64>],
        kept: &mut [f64],
    ) {
        lanes::dispatch(
            simd,
            StressLanes {
                model: self,
                fe,
                out,
                kept,
            },
        );
    }

    fn stress_and_differential_batch_kept(
        &self,
        simd: SimdLevel,
        f: &[Matrix3<f64>],
        kept: &[f64],
        df: &[Matrix3<f64>],
        p: &mut [Matrix3<f64>],
        dp: &mut [Matrix3<f64>],
    ) {
        assert_eq!(
            kept.len(),
            f.len() * KEPT,
            "kept decompositions for every particle"
        );
        let kernel = DifferentialLanes {
            model: self,
            f,
            kept,
            df,
            p,
            dp,
        };
        lanes::dispatch(simd, kernel);
    }

    fn wave_modulus(&self) -> f64 {
        self.lambda + 2.0 * self.mu
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::checks::{self, fd_error, random_matrix};
    use nalgebra::{Rotation3, Vector3};
    use rand::SeedableRng;

    fn model() -> FixedCorotated {
        FixedCorotated::new(38888.9, 58333.0)
    }

    fn assert_differential_matches(f: &Matrix3<f64>, label: &str) {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        for _ in 0..20 {
            let df = random_matrix(&mut rng, 1.0);
            let err = fd_error(&m, f, &df);
            assert!(err < 1e-6, "{label}: relative error {err:e}");
        }
    }

    #[test]
    fn stress_is_energy_gradient() {
        checks::stress_is_energy_gradient(&model(), 0.4);
    }

    #[test]
    fn differential_at_random_f() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        for _ in 0..50 {
            let f = Matrix3::identity() + random_matrix(&mut rng, 0.6);
            if f.determinant() > 0.05 {
                assert_differential_matches(&f, "random F");
            }
        }
    }

    #[test]
    fn differential_near_rotation_repeated_singular_values() {
        let rot = Rotation3::from_euler_angles(0.4, 1.2, -0.7).into_inner();
        assert_differential_matches(&Matrix3::identity(), "F = I");
        assert_differential_matches(&rot, "F = rotation");
        let s = Matrix3::from_diagonal(&Vector3::new(1.1, 1.1, 0.9));
        assert_differential_matches(&(rot * s), "two equal singular values");
        let s = Matrix3::from_diagonal(&Vector3::new(1.0 + 1e-9, 1.0, 1.0 - 1e-9));
        assert_differential_matches(&(rot * s), "nearly equal singular values");
    }

    #[test]
    fn differential_at_inverted_f() {
        let rot = Rotation3::from_euler_angles(-0.3, 0.5, 2.2).into_inner();
        for diag in [[1.2, 0.8, -0.3], [1.0, 1.0, -1.0 + 0.3], [0.9, 0.6, -0.1]] {
            let f = rot * Matrix3::from_diagonal(&Vector3::from(diag));
            assert!(f.determinant() < 0.0);
            assert_differential_matches(&f, "inverted F");
        }
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        let mut tested = 0;
        while tested < 30 {
            let f = random_matrix(&mut rng, 1.5);
            if f.determinant() < -0.05 {
                assert_differential_matches(&f, "random inverted F");
                tested += 1;
            }
        }
    }

    #[test]
    fn differential_is_self_adjoint() {
        checks::differential_is_self_adjoint(&model());
    }

    /// More particles than two batches of the widest lanes, so every width runs whole
    /// batches and a remainder; some at rest, rotated, inverted or singular.
    const N: usize = 75;

    fn batch_of(rng: &mut rand_pcg::Pcg64, n: usize) -> Vec<Matrix3<f64>> {
        let rot = Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
        (0..n)
            .map(|i| match i % 7 {
                0 => Matrix3::identity(),
                1 => rot,
                2 => Matrix3::from_diagonal(&Vector3::new(1.2, 0.9, -0.7)),
                3 => Matrix3::from_diagonal(&Vector3::new(2.0, 0.0, 1.0)),
                _ => Matrix3::identity() + random_matrix(rng, 0.5),
            })
            .collect()
    }

    #[test]
    fn batched_stress_equals_single() {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(21);
        let fe = batch_of(&mut rng, N);
        for simd in SimdLevel::available_levels() {
            let mut out = vec![Matrix3::zeros(); fe.len()];
            m.stress_batch(simd, &fe, &mut out);
            for (f, p) in fe.iter().zip(&out) {
                assert_eq!(*p, m.stress(f), "{simd:?} {f}");
            }
        }
    }

    #[test]
    fn batched_differential_equals_single() {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(22);
        let f = batch_of(&mut rng, N);
        let df: Vec<Matrix3<f64>> = (0..N).map(|_| random_matrix(&mut rng, 1.0)).collect();
        for simd in SimdLevel::available_levels() {
            let (mut p, mut dp) = (vec![Matrix3::zeros(); N], vec![Matrix3::zeros(); N]);
            m.stress_and_differential_batch(simd, &f, &df, &mut p, &mut dp);
            for i in 0..N {
                assert_eq!((p[i], dp[i]), m.stress_and_differential(&f[i], &df[i]));
            }
        }
    }

    #[test]
    fn kept_decompositions_give_the_same_bits() {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(23);
        let f = batch_of(&mut rng, N);
        let df: Vec<Matrix3<f64>> = (0..N).map(|_| random_matrix(&mut rng, 1.0)).collect();
        for simd in SimdLevel::available_levels() {
            let (mut p, mut kept) = (vec![Matrix3::zeros(); N], vec![0.0; N * KEPT]);
            m.stress_batch_keeping(simd, &f, &mut p, &mut kept);
            let (mut pk, mut dpk) = (vec![Matrix3::zeros(); N], vec![Matrix3::zeros(); N]);
            m.stress_and_differential_batch_kept(simd, &f, &kept, &df, &mut pk, &mut dpk);
            for i in 0..N {
                assert_eq!(p[i], m.stress(&f[i]), "{simd:?}");
                assert_eq!((pk[i], dpk[i]), m.stress_and_differential(&f[i], &df[i]));
            }
        }
    }

    #[test]
    fn rest_and_rotations_are_stress_free() {
        checks::rest_and_rotations_are_stress_free(&model());
    }
}
