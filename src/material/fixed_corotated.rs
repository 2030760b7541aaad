//! Fixed-corotated elasticity (Stomakhin et al. 2012):
//! `Psi = mu sum_k (sigma_k - 1)^2 + lambda/2 (J - 1)^2`,
//! `P = 2 mu (F - R) + lambda (J - 1) cof F`, with `cof F = J F^-T`.

use super::svd::{Svd3, eigen, eigen_x4, svd3, svd3_from_eigen, svd3_x4};
use super::{ConstitutiveModel, cofactor, cofactor_differential};
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

impl FixedCorotated {
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
    fn energy_density(&self, f: &Matrix3<f64>) -> f64 {
        let s = svd3(f);
        let j = f.determinant();
        self.mu * (s.sigma.add_scalar(-1.0)).norm_squared() + 0.5 * self.lambda * (j - 1.0).powi(2)
    }

    fn stress(&self, f: &Matrix3<f64>) -> Matrix3<f64> {
        self.stress_with_rotation(f, &svd3(f).rotation())
    }

    fn stress_batch(&self, fe: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
        let mut chunks = fe.chunks_exact(4);
        let mut outs = out.chunks_exact_mut(4);
        for (f4, p4) in (&mut chunks).zip(&mut outs) {
            let f4: &[Matrix3<f64>; 4] = f4.try_into().expect("chunk of 4");
            let svd = svd3_x4(f4);
            for l in 0..4 {
                p4[l] = self.stress_with_rotation(&f4[l], &svd[l].rotation());
            }
        }
        for (f, p) in chunks.remainder().iter().zip(outs.into_remainder()) {
            *p = self.stress(f);
        }
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
        f: &[Matrix3<f64>],
        df: &[Matrix3<f64>],
        p: &mut [Matrix3<f64>],
        dp: &mut [Matrix3<f64>],
    ) {
        let n = f.len();
        let whole = n - n % 4;
        for i in (0..whole).step_by(4) {
            let f4: &[Matrix3<f64>; 4] = f[i..i + 4].try_into().expect("chunk of 4");
            let svd = svd3_x4(f4);
            for l in 0..4 {
                (p[i + l], dp[i + l]) =
                    self.stress_and_differential_with(&f4[l], &svd[l], &df[i + l]);
            }
        }
        for i in whole..n {
            (p[i], dp[i]) = self.stress_and_differential(&f[i], &df[i]);
        }
    }

    fn kept_per_particle(&self) -> usize {
        KEPT
    }

    fn stress_batch_keeping(
        &self,
        fe: &[Matrix3<f64>],
        out: &mut [Matrix3<f64>],
        kept: &mut [f64],
    ) {
        let n = fe.len();
        let whole = n - n % 4;
        let mut keep = |i: usize, (eig, v): (Vector3<f64>, Matrix3<f64>)| {
            let k = &mut kept[i * KEPT..(i + 1) * KEPT];
            k[..3].copy_from_slice(eig.as_slice());
            k[3..].copy_from_slice(v.as_slice());
            svd3_from_eigen(&fe[i], eig, v)
        };
        for i in (0..whole).step_by(4) {
            let f4: &[Matrix3<f64>; 4] = fe[i..i + 4].try_into().expect("chunk of 4");
            for (l, e) in eigen_x4(f4).into_iter().enumerate() {
                let svd = keep(i + l, e);
                out[i + l] = self.stress_with_rotation(&f4[l], &svd.rotation());
            }
        }
        for i in whole..n {
            let svd = keep(i, eigen(&fe[i]));
            out[i] = self.stress_with_rotation(&fe[i], &svd.rotation());
        }
    }

    fn stress_and_differential_batch_kept(
        &self,
        f: &[Matrix3<f64>],
        kept: &[f64],
        df: &[Matrix3<f64>],
        p: &mut [Matrix3<f64>],
        dp: &mut [Matrix3<f64>],
    ) {
        for (i, k) in kept.chunks_exact(KEPT).enumerate() {
            let eig = Vector3::from_column_slice(&k[..3]);
            let v = Matrix3::from_column_slice(&k[3..]);
            let svd = svd3_from_eigen(&f[i], eig, v);
            (p[i], dp[i]) = self.stress_and_differential_with(&f[i], &svd, &df[i]);
        }
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

    #[test]
    fn batched_stress_equals_single() {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(21);
        let fe: Vec<Matrix3<f64>> = (0..11)
            .map(|_| Matrix3::identity() + random_matrix(&mut rng, 0.5))
            .collect();
        let mut out = vec![Matrix3::zeros(); fe.len()];
        m.stress_batch(&fe, &mut out);
        for (f, p) in fe.iter().zip(&out) {
            assert_eq!(*p, m.stress(f));
        }
    }

    #[test]
    fn batched_differential_equals_single() {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(22);
        let f: Vec<Matrix3<f64>> = (0..11)
            .map(|_| Matrix3::identity() + random_matrix(&mut rng, 0.5))
            .collect();
        let df: Vec<Matrix3<f64>> = (0..11).map(|_| random_matrix(&mut rng, 1.0)).collect();
        let (mut p, mut dp) = (vec![Matrix3::zeros(); 11], vec![Matrix3::zeros(); 11]);
        m.stress_and_differential_batch(&f, &df, &mut p, &mut dp);
        for i in 0..11 {
            assert_eq!((p[i], dp[i]), m.stress_and_differential(&f[i], &df[i]));
        }
    }

    #[test]
    fn kept_decompositions_give_the_same_bits() {
        let m = model();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(23);
        let f: Vec<Matrix3<f64>> = (0..11)
            .map(|_| Matrix3::identity() + random_matrix(&mut rng, 0.5))
            .collect();
        let df: Vec<Matrix3<f64>> = (0..11).map(|_| random_matrix(&mut rng, 1.0)).collect();
        let (mut p, mut kept) = (vec![Matrix3::zeros(); 11], vec![0.0; 11 * KEPT]);
        m.stress_batch_keeping(&f, &mut p, &mut kept);
        let (mut pk, mut dpk) = (vec![Matrix3::zeros(); 11], vec![Matrix3::zeros(); 11]);
        m.stress_and_differential_batch_kept(&f, &kept, &df, &mut pk, &mut dpk);
        for i in 0..11 {
            assert_eq!(p[i], m.stress(&f[i]));
            assert_eq!((pk[i], dpk[i]), m.stress_and_differential(&f[i], &df[i]));
        }
    }

    #[test]
    fn rest_and_rotations_are_stress_free() {
        checks::rest_and_rotations_are_stress_free(&model());
    }
}
