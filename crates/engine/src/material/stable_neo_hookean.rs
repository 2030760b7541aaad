//! Stable Neo-Hookean elasticity (Smith, de Goes and Kim 2018, eq. 13):
//! `Psi = mu/2 (tr(F^T F) - 3) + lam/2 (J - alpha)^2`, `alpha = 1 + mu/lam`,
//! `P = mu F + lam (J - alpha) cof F`.
//!
//! Unlike the textbook Neo-Hookean it has no `log J`, so it is defined and smooth for
//! inverted and collapsed elements, and `alpha` makes the rest shape stress-free. It needs no
//! SVD. Its `lam` is not the Lamé parameter: matching linear elasticity at rest needs
//! `lam = lambda + mu`, which [`StableNeoHookean::from_lame`] does, so a scene's `mu` and
//! `lambda` mean the same for every material.

use super::{ConstitutiveModel, cofactor, cofactor_differential};
use nalgebra::Matrix3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StableNeoHookean {
    pub mu: f64,
    /// The model's own volume stiffness (`lambda + mu` for Lamé `lambda`).
    pub lam: f64,
    /// `1 + mu / lam`: the rest volume ratio the volume term aims at, so that `P(I) = 0`.
    pub alpha: f64,
}

impl StableNeoHookean {
    /// From the Lamé parameters `mu` and `lambda` (the same small-strain behaviour as
    /// fixed-corotated with those parameters).
    pub fn from_lame(mu: f64, lambda: f64) -> Self {
        let lam = lambda + mu;
        StableNeoHookean {
            mu,
            lam,
            alpha: 1.0 + mu / lam,
        }
    }
}

impl ConstitutiveModel for StableNeoHookean {
    fn spec(&self) -> (super::MaterialModel, f64, f64) {
        (
            super::MaterialModel::StableNeoHookean,
            self.mu,
            self.lam - self.mu,
        )
    }

    fn energy_density(&self, f: &Matrix3<f64>) -> f64 {
        let j = f.determinant();
        0.5 * self.mu * (f.norm_squared() - 3.0) + 0.5 * self.lam * (j - self.alpha).powi(2)
    }

    fn stress(&self, f: &Matrix3<f64>) -> Matrix3<f64> {
        let cof = cofactor(f);
        let j = f.column(0).dot(&cof.column(0));
        self.mu * f + self.lam * (j - self.alpha) * cof
    }

    fn stress_and_differential(
        &self,
        f: &Matrix3<f64>,
        df: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        let cof = cofactor(f);
        let j = f.column(0).dot(&cof.column(0));
        let p = self.mu * f + self.lam * (j - self.alpha) * cof;
        // dJ = cof F : dF; d cof F is bilinear in F and dF.
        let dj = cof.component_mul(df).sum();
        let dp =
            self.mu * df + self.lam * (dj * cof + (j - self.alpha) * cofactor_differential(f, df));
        (p, dp)
    }

    fn wave_modulus(&self) -> f64 {
        // Linearized at rest: mu (dF + dF^T) + (lam - mu) tr(dF) I, so lambda + 2 mu.
        self.lam + self.mu
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::checks::{self, fd_error, random_matrix};
    use nalgebra::{Rotation3, Vector3};

    fn model() -> StableNeoHookean {
        StableNeoHookean::from_lame(38888.9, 58333.0)
    }

    #[test]
    fn stress_is_energy_gradient() {
        checks::stress_is_energy_gradient(&model(), 1.5); // inverted F included
    }

    #[test]
    fn differential_matches_fd_everywhere() {
        let m = model();
        let mut rng = checks::rng(5);
        let rot = Rotation3::from_euler_angles(0.4, 1.2, -0.7).into_inner();
        let mut cases = vec![
            Matrix3::identity(),
            rot,
            rot * Matrix3::from_diagonal(&Vector3::new(1.2, 0.8, -0.3)), // inverted
            Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0)),        // collapsed
        ];
        cases.extend((0..40).map(|_| random_matrix(&mut rng, 1.5)));
        for f in cases {
            for _ in 0..5 {
                let df = random_matrix(&mut rng, 1.0);
                let err = fd_error(&m, &f, &df);
                assert!(err < 1e-6, "relative error {err:e} at {f}");
            }
        }
    }

    #[test]
    fn differential_is_self_adjoint() {
        checks::differential_is_self_adjoint(&model());
    }

    #[test]
    fn rest_and_rotations_are_stress_free() {
        checks::rest_and_rotations_are_stress_free(&model());
    }

    /// At small strain it is linear elasticity with the given Lamé parameters, like
    /// fixed-corotated: the two stresses agree to first order.
    #[test]
    fn small_strain_matches_fixed_corotated() {
        let (mu, lambda) = (38888.9, 58333.0);
        let snh = StableNeoHookean::from_lame(mu, lambda);
        let fcr = crate::material::FixedCorotated::new(mu, lambda);
        let mut rng = checks::rng(17);
        for _ in 0..20 {
            let e = random_matrix(&mut rng, 1.0);
            let f = Matrix3::identity() + 1e-6 * e;
            let (a, b) = (snh.stress(&f), fcr.stress(&f));
            assert!((a - b).norm() < 1e-4 * b.norm(), "{a} vs {b}");
        }
        let (a, b) = (snh.wave_modulus(), fcr.wave_modulus());
        assert!((a - b).abs() < 1e-9 * b);
    }
}
