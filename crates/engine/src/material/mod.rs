//! Constitutive models: strain energy density, first Piola-Kirchhoff stress and its
//! differential, behind one trait so the MPM stages never depend on a particular material.

mod fixed_corotated;
mod stable_neo_hookean;
pub mod svd;

pub use fixed_corotated::FixedCorotated;
pub use stable_neo_hookean::StableNeoHookean;

use crate::lanes::SimdLevel;
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Which constitutive model a scene uses: plain data a scene or settings file names. Adding a
/// material is one file implementing [`ConstitutiveModel`] and one arm here.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MaterialModel {
    /// Stomakhin et al. 2012, the reference model.
    #[default]
    FixedCorotated,
    /// Smith et al. 2018, without an SVD, smooth through inversion.
    StableNeoHookean,
}

impl MaterialModel {
    /// Every value, in declaration order.
    pub const ALL: [MaterialModel; 2] = [
        MaterialModel::FixedCorotated,
        MaterialModel::StableNeoHookean,
    ];

    /// The model with Lamé parameters `mu` and `lambda` (the same small-strain stiffness for
    /// every model).
    pub fn build(self, mu: f64, lambda: f64) -> Arc<dyn ConstitutiveModel> {
        match self {
            MaterialModel::FixedCorotated => Arc::new(FixedCorotated::new(mu, lambda)),
            MaterialModel::StableNeoHookean => Arc::new(StableNeoHookean::from_lame(mu, lambda)),
        }
    }
}

/// The elastic time-step bound of a material on a grid: `(dx / c, c)` with the wave speed
/// `c = sqrt(modulus / density)` (infinite step for a material with no stiffness or mass).
/// The one formula both integrators and scene set-up use.
pub fn stable_dt(wave_modulus: f64, density: f64, dx: f64) -> (f64, f64) {
    let c = if density > 0.0 {
        (wave_modulus / density).sqrt()
    } else {
        0.0
    };
    (if c > 0.0 { dx / c } else { f64::INFINITY }, c)
}

/// Lamé parameters `(mu, lambda)` from Young's modulus and Poisson's ratio.
pub fn lame_from_young_poisson(e: f64, nu: f64) -> (f64, f64) {
    (
        e / (2.0 * (1.0 + nu)),
        e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
    )
}

#[cfg(test)]
mod young_poisson_tests {
    #[test]
    fn lame_round_trip() {
        let (mu, lambda) = super::lame_from_young_poisson(1.0e5, 0.3);
        let (e, nu) = super::young_poisson_from_lame(mu, lambda);
        assert!((e - 1.0e5).abs() < 1e-6 && (nu - 0.3).abs() < 1e-12);
    }
}

/// Young's modulus and Poisson's ratio `(E, nu)` from Lamé parameters (the inverse of
/// [`lame_from_young_poisson`]).
pub fn young_poisson_from_lame(mu: f64, lambda: f64) -> (f64, f64) {
    (
        mu * (3.0 * lambda + 2.0 * mu) / (lambda + mu),
        lambda / (2.0 * (lambda + mu)),
    )
}

/// A hyperelastic constitutive model `Psi(F)`.
///
/// Because the stress is the gradient of an energy, `dP/dF` is a symmetric linear map on 3x3
/// matrices; the reverse pass relies on this and applies [`Self::stress_differential`] to the
/// stress adjoint (tests check the symmetry `<dP[A], B> = <A, dP[B]>`).
pub trait ConstitutiveModel: Send + Sync + std::fmt::Debug {
    /// The model and Lamé parameters `(model, mu, lambda)` it is built from
    /// ([`MaterialModel::build`]): plain data, from which a device builds its own copy.
    fn spec(&self) -> (MaterialModel, f64, f64);
    /// Strain energy per unit rest volume.
    fn energy_density(&self, f: &Matrix3<f64>) -> f64;
    /// First Piola-Kirchhoff stress `P = dPsi/dF`.
    fn stress(&self, f: &Matrix3<f64>) -> Matrix3<f64>;
    /// Stress of many elastic gradients at once, `out[i] = P(fe[i])`. Models may override it to
    /// batch work across particles in vector lanes of the instruction set `simd` names
    /// (fixed-corotated: its SVDs, [`crate::lanes`]); the bits are the one-at-a-time call's.
    fn stress_batch(&self, simd: SimdLevel, fe: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
        let _ = simd;
        for (f, p) in fe.iter().zip(out) {
            *p = self.stress(f);
        }
    }
    /// Stress and its differential in one call: `(P(F), dP(F)[dF])` (shares the SVD).
    fn stress_and_differential(
        &self,
        f: &Matrix3<f64>,
        df: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>);
    /// [`Self::stress_and_differential`] of many particles at once: `(p[i], dp[i]) =
    /// (P(f[i]), dP(f[i])[df[i]])`. Models may override it to batch work across particles
    /// (fixed-corotated: its SVDs in vector lanes); the results equal the one-at-a-time call's.
    fn stress_and_differential_batch(
        &self,
        simd: SimdLevel,
        f: &[Matrix3<f64>],
        df: &[Matrix3<f64>],
        p: &mut [Matrix3<f64>],
        dp: &mut [Matrix3<f64>],
    ) {
        let _ = simd;
        for (((f, df), p), dp) in f.iter().zip(df).zip(p).zip(dp) {
            (*p, *dp) = self.stress_and_differential(f, df);
        }
    }
    /// Numbers per particle the stress stage can keep for the reverse pass, so that the
    /// reverse need not redo its costliest part (fixed-corotated: the eigen-decomposition
    /// behind its SVD, 12 numbers). 0: nothing is kept.
    fn kept_per_particle(&self) -> usize {
        0
    }
    /// [`Self::stress_batch`], also writing `kept` ([`Self::kept_per_particle`] numbers a
    /// particle).
    fn stress_batch_keeping(
        &self,
        simd: SimdLevel,
        fe: &[Matrix3<f64>],
        out: &mut [Matrix3<f64>],
        kept: &mut [f64],
    ) {
        debug_assert!(kept.is_empty());
        self.stress_batch(simd, fe, out)
    }
    /// [`Self::stress_and_differential_batch`] from what [`Self::stress_batch_keeping`] kept for
    /// the same `f`: the same results, bit for bit.
    fn stress_and_differential_batch_kept(
        &self,
        simd: SimdLevel,
        f: &[Matrix3<f64>],
        kept: &[f64],
        df: &[Matrix3<f64>],
        p: &mut [Matrix3<f64>],
        dp: &mut [Matrix3<f64>],
    ) {
        debug_assert!(kept.is_empty());
        self.stress_and_differential_batch(simd, f, df, p, dp)
    }
    /// The differential `dP(F)[dF]` alone.
    fn stress_differential(&self, f: &Matrix3<f64>, df: &Matrix3<f64>) -> Matrix3<f64> {
        self.stress_and_differential(f, df).1
    }
    /// P-wave modulus at rest (`lambda + 2 mu` for isotropic models); with the density it gives
    /// the elastic wave speed that bounds the stable time step.
    fn wave_modulus(&self) -> f64;
}

/// Cofactor matrix `cof F = det(F) F^-T`, columns `f1 x f2, f2 x f0, f0 x f1`; defined (and
/// smooth) for singular and inverted F, unlike `F^-T`.
#[inline]
pub(crate) fn cofactor(f: &Matrix3<f64>) -> Matrix3<f64> {
    let (f0, f1, f2) = (f.column(0), f.column(1), f.column(2));
    Matrix3::from_columns(&[f1.cross(&f2), f2.cross(&f0), f0.cross(&f1)])
}

/// Differential of the cofactor matrix: `d cof(F)[dF]` (bilinear in F and dF).
#[inline]
pub(crate) fn cofactor_differential(f: &Matrix3<f64>, df: &Matrix3<f64>) -> Matrix3<f64> {
    let (f0, f1, f2) = (f.column(0), f.column(1), f.column(2));
    let (d0, d1, d2) = (df.column(0), df.column(1), df.column(2));
    Matrix3::from_columns(&[
        d1.cross(&f2) + f1.cross(&d2),
        d2.cross(&f0) + f2.cross(&d0),
        d0.cross(&f1) + f0.cross(&d1),
    ])
}

/// Checks every constitutive model must pass, shared by the models' unit tests.
#[cfg(test)]
pub(crate) mod checks {
    use super::ConstitutiveModel;
    use nalgebra::Matrix3;
    use rand::{RngExt, SeedableRng};

    pub fn random_matrix(rng: &mut impl rand::Rng, scale: f64) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| rng.random_range(-scale..scale))
    }

    pub fn rng(seed: u64) -> rand_pcg::Pcg64 {
        rand_pcg::Pcg64::seed_from_u64(seed)
    }

    /// Relative error of dP[dF] against central differences of P (h = 1e-6).
    pub fn fd_error(m: &dyn ConstitutiveModel, f: &Matrix3<f64>, df: &Matrix3<f64>) -> f64 {
        let h = 1e-6;
        let fd = (m.stress(&(f + h * df)) - m.stress(&(f - h * df))) / (2.0 * h);
        let an = m.stress_differential(f, df);
        (fd - an).norm() / an.norm().max(1e-30)
    }

    /// `P = dPsi/dF` by central differences of the energy, at `samples` random F of entries
    /// within `spread` of the identity's.
    pub fn stress_is_energy_gradient(m: &dyn ConstitutiveModel, spread: f64) {
        let mut rng = rng(3);
        for _ in 0..50 {
            let f = Matrix3::identity() + random_matrix(&mut rng, spread);
            let p = m.stress(&f);
            let h = 1e-6;
            for i in 0..3 {
                for j in 0..3 {
                    let mut e = Matrix3::zeros();
                    e[(i, j)] = h;
                    let fd = (m.energy_density(&(f + e)) - m.energy_density(&(f - e))) / (2.0 * h);
                    assert!((fd - p[(i, j)]).abs() < 1e-5 * p.norm().max(1.0));
                }
            }
        }
    }

    /// `<dP[A], B> = <A, dP[B]>` at random (also inverted) F.
    pub fn differential_is_self_adjoint(m: &dyn ConstitutiveModel) {
        let mut rng = rng(13);
        for _ in 0..100 {
            let f = random_matrix(&mut rng, 1.5);
            let (a, b) = (random_matrix(&mut rng, 1.0), random_matrix(&mut rng, 1.0));
            let lhs = m.stress_differential(&f, &a).dot(&b);
            let rhs = a.dot(&m.stress_differential(&f, &b));
            assert!(
                (lhs - rhs).abs() <= 1e-10 * lhs.abs().max(1.0),
                "{lhs} vs {rhs}"
            );
        }
    }

    /// The rest shape and rotations carry no stress.
    pub fn rest_and_rotations_are_stress_free(m: &dyn ConstitutiveModel) {
        let rot = nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.9).into_inner();
        assert!(m.stress(&Matrix3::identity()).norm() < 1e-9);
        assert!(m.stress(&rot).norm() < 1e-9);
    }
}
