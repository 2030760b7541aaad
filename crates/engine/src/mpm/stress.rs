//! Stage P1: elastic stress and the affine momentum each particle hands to the grid.
//!
//! Forward: `Fe` (`F` after the control, [`super::control`]), `A = m C - dt V D^-1 P(Fe) Fe^T` (MLS-MPM fuses the APIC affine
//! momentum and the stress force into one matrix that P2G spreads as `A (x_i - x_p)`).

use crate::material::ConstitutiveModel;
use nalgebra::Matrix3;

/// Constants of the stress stage for one particle.
pub struct StressInputs<'a> {
    pub model: &'a dyn ConstitutiveModel,
    pub mass: f64,
    pub volume: f64,
    pub dt: f64,
    pub inv_d: f64,
}

impl StressInputs<'_> {
    /// Scale of the stress term, `-dt V D^-1`.
    #[inline]
    fn k(&self) -> f64 {
        -self.dt * self.volume * self.inv_d
    }

    /// Forward: the affine momentum `A` for affine velocity `c`, elastic gradient `fe` and its
    /// stress `p = P(fe)` (computed beforehand, batched across particles).
    #[inline]
    pub fn affine_from_stress(
        &self,
        c: &Matrix3<f64>,
        fe: &Matrix3<f64>,
        p: &Matrix3<f64>,
    ) -> Matrix3<f64> {
        self.mass * c + self.k() * p * fe.transpose()
    }

    /// Reverse: from dL/dA, returns (dL/dC, dL/dFe).
    /// `A = m C + k P Fe^T` gives `dL/dC = m gA`, `gP = k gA Fe`,
    /// `dL/dFe = k gA^T P + dP(Fe)[gP]` (dP/dF is self-adjoint for a hyperelastic model).
    #[inline]
    pub fn affine_momentum_reverse(
        &self,
        fe: &Matrix3<f64>,
        grad_a: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        let (p, dp) = self
            .model
            .stress_and_differential(fe, &self.stress_adjoint(fe, grad_a));
        self.affine_momentum_reverse_with(grad_a, &p, &dp)
    }

    /// The first half of [`Self::affine_momentum_reverse`]: dL/dP = `k gA Fe`, the direction
    /// in which the stress differential is taken (batched across particles by the caller).
    #[inline]
    pub fn stress_adjoint(&self, fe: &Matrix3<f64>, grad_a: &Matrix3<f64>) -> Matrix3<f64> {
        self.k() * grad_a * fe
    }

    /// The second half: (dL/dC, dL/dFe) from dL/dA, `P(Fe)` and `dP(Fe)[dL/dP]`.
    #[inline]
    pub fn affine_momentum_reverse_with(
        &self,
        grad_a: &Matrix3<f64>,
        p: &Matrix3<f64>,
        dp: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        (self.mass * grad_a, self.k() * grad_a.transpose() * p + dp)
    }
}
