//! How a deformation-gradient control `Fc` acts on a particle's `F` at the step it is applied
//! (forward and reverse side by side). Both integrators call this, so the control means the
//! same whichever runs it.
//!
//! - [`ControlForm::Plastic`] (the default): the control reshapes the particle's rest shape
//!   by a volume-preserving factor, `Fe = F G`, `G = (I + Fc) / det(I + Fc)^(1/3)`. It can
//!   make the body flow into any shape of the same volume, but it cannot change volume: a
//!   compressed particle is resisted by the material's pressure, `det F` stays the ratio of
//!   current to rest volume, and no particle can be turned inside out by the control.
//! - [`ControlForm::Additive`]: the reference paper's `Fe = F + Fc`. `F` then stops
//!   measuring the body's deformation (the control can set any volume, or a negative one),
//!   so the optimizer is free to compact and disorder particles below the grid's scale; kept
//!   for comparison (docs/morph.md).

use super::SimError;
use super::boundary::ControlParams;
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

/// Per-step deformation-gradient controls: `controls[s]`, when present and `Some`, is the
/// `Fc` (one per particle) of local step `s`. Shared: the steps of one control layer hold the
/// same values without a copy each.
pub type StepControls = [Option<StepControl>];

/// One step's controls (see [`StepControls`]).
pub type StepControl = std::sync::Arc<[Matrix3<f64>]>;

/// What drives a run, the one notion of a control both integrators take: the per-step
/// deformation-gradient controls `f` (the morph's) and the knots of the model's boundary
/// controls (body forces, clamps: [`super::boundary`]; the rope's), either of them empty.
#[derive(Clone, Copy, Debug)]
pub struct Controls<'a> {
    pub f: &'a StepControls,
    pub knots: Option<&'a ControlParams>,
}

impl<'a> Controls<'a> {
    /// Deformation-gradient controls alone.
    pub fn of_f(f: &'a StepControls) -> Controls<'a> {
        Controls { f, knots: None }
    }

    /// The boundary controls' knots alone.
    pub fn of_knots(knots: &'a ControlParams) -> Controls<'a> {
        Controls {
            f: &[],
            knots: Some(knots),
        }
    }
}

/// How `Fc` enters `F`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ControlForm {
    /// `Fe = F (I + Fc) / det(I + Fc)^(1/3)`: a volume-preserving change of the rest shape.
    #[default]
    Plastic,
    /// `Fe = F + Fc` (the reference).
    Additive,
}

/// `det(I + Fc)` below this is refused: the factor would stretch the rest shape more than
/// 100:1 along some axis within one control layer, which no sane optimizer step asks for.
pub const MIN_FACTOR_DET: f64 = 1e-2;

impl ControlForm {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [ControlForm; 2] = [ControlForm::Plastic, ControlForm::Additive];

    /// Checks that `fc` can be applied (the plastic factor needs `det(I + Fc) > 0`).
    pub fn check(self, fc: &Matrix3<f64>, step: usize, particle: usize) -> Result<(), SimError> {
        match self {
            ControlForm::Additive => Ok(()),
            ControlForm::Plastic => {
                let det = (Matrix3::identity() + fc).determinant();
                if det >= MIN_FACTOR_DET {
                    Ok(())
                } else {
                    Err(SimError::DegenerateControl {
                        step,
                        particle,
                        det,
                    })
                }
            }
        }
    }

    /// Forward: the elastic deformation gradient after the control.
    #[inline]
    pub fn apply(self, f: &Matrix3<f64>, fc: &Matrix3<f64>) -> Matrix3<f64> {
        self.apply_scaled(f, fc, self.scale(fc))
    }

    /// The plastic form's volume factor `det(I + Fc)^(-1/3)` (1 for the additive form): the
    /// Euler step keeps it on the tape, so that its reverse takes no cube roots.
    #[inline]
    pub fn scale(self, fc: &Matrix3<f64>) -> f64 {
        match self {
            ControlForm::Additive => 1.0,
            ControlForm::Plastic => plastic_factor(fc).2,
        }
    }

    /// [`ControlForm::apply`] given [`ControlForm::scale`]`(fc)`.
    #[inline]
    pub fn apply_scaled(self, f: &Matrix3<f64>, fc: &Matrix3<f64>, scale: f64) -> Matrix3<f64> {
        match self {
            ControlForm::Additive => f + fc,
            ControlForm::Plastic => f * ((Matrix3::identity() + fc) * scale),
        }
    }

    /// Reverse of [`ControlForm::apply`]: `(dL/dF, dL/dFc)` from `dL/dFe`.
    #[inline]
    pub fn apply_reverse(
        self,
        f: &Matrix3<f64>,
        fc: &Matrix3<f64>,
        grad_fe: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        self.apply_reverse_scaled(f, fc, self.scale(fc), grad_fe)
    }

    /// [`ControlForm::apply_reverse`] given [`ControlForm::scale`]`(fc)`.
    #[inline]
    pub fn apply_reverse_scaled(
        self,
        f: &Matrix3<f64>,
        fc: &Matrix3<f64>,
        scale: f64,
        grad_fe: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        match self {
            ControlForm::Additive => (*grad_fe, *grad_fe),
            ControlForm::Plastic => {
                let m = Matrix3::identity() + fc;
                let g = m * scale;
                let grad_g = f.transpose() * grad_fe;
                // G = M d^(-1/3), d = det M: dG = d^(-1/3) (dM - M tr(M^-1 dM) / 3).
                let m_inv_t = m
                    .try_inverse()
                    .expect("checked: det(I + Fc) >= MIN_FACTOR_DET")
                    .transpose();
                let grad_m = scale * (grad_g - (grad_g.dot(&m) / 3.0) * m_inv_t);
                (grad_fe * g.transpose(), grad_m)
            }
        }
    }
}

/// `(G, M, d^(-1/3))` with `M = I + Fc`, `d = det M` and `G = M d^(-1/3)`.
#[inline]
fn plastic_factor(fc: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>, f64) {
    let m = Matrix3::identity() + fc;
    let scale = m.determinant().cbrt().recip();
    (m * scale, m, scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> (Matrix3<f64>, Matrix3<f64>, Matrix3<f64>) {
        let f = Matrix3::new(1.1, 0.2, -0.1, 0.05, 0.9, 0.3, -0.2, 0.1, 1.2);
        let fc = Matrix3::new(0.1, -0.3, 0.2, 0.15, -0.2, 0.05, 0.3, 0.1, 0.25);
        let w = Matrix3::new(0.3, -1.0, 0.7, 0.2, 0.5, -0.4, 1.1, 0.6, -0.9);
        (f, fc, w)
    }

    #[test]
    fn the_plastic_factor_keeps_volume() {
        let (f, fc, _) = sample();
        let fe = ControlForm::Plastic.apply(&f, &fc);
        assert!((fe.determinant() - f.determinant()).abs() < 1e-13);
        assert_eq!(ControlForm::Additive.apply(&f, &fc), f + fc);
        assert!(ControlForm::Plastic.check(&fc, 0, 0).is_ok());
        let flat = -Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 0.0, 0.0));
        assert!(matches!(
            ControlForm::Plastic.check(&flat, 3, 7),
            Err(SimError::DegenerateControl {
                step: 3,
                particle: 7,
                ..
            })
        ));
    }

    #[test]
    fn reverse_matches_central_differences() {
        let (f, fc, w) = sample();
        for form in ControlForm::ALL {
            let objective = |f: &Matrix3<f64>, fc: &Matrix3<f64>| form.apply(f, fc).dot(&w);
            let (gf, gfc) = form.apply_reverse(&f, &fc, &w);
            let h = 1e-6;
            for k in 0..9 {
                let mut e = Matrix3::zeros();
                e[k] = h;
                let df = (objective(&(f + e), &fc) - objective(&(f - e), &fc)) / (2.0 * h);
                let dfc = (objective(&f, &(fc + e)) - objective(&f, &(fc - e))) / (2.0 * h);
                assert!(
                    (df - gf[k]).abs() < 1e-8,
                    "{form:?} F[{k}]: {df} vs {}",
                    gf[k]
                );
                assert!(
                    (dfc - gfc[k]).abs() < 1e-8,
                    "{form:?} Fc[{k}]: {dfc} vs {}",
                    gfc[k]
                );
            }
        }
    }
}
