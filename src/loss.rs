//! Losses on the nodal mass grid (design.md section 3).
//!
//! - L2:  `L = sum_i 1/2 (m_i - m*_i)^2`
//! - log: `L = sum_i 1/2 (ln(m_i + 1) - ln(m*_i + 1))^2` (default; less sensitive to outliers,
//!   so it ejects fewer particles when source and target overlap little)

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MassLossKind {
    L2,
    #[default]
    Log,
}

impl MassLossKind {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [MassLossKind; 2] = [MassLossKind::L2, MassLossKind::Log];
}

/// A mass loss against fixed target nodal masses.
#[derive(Clone, Debug)]
pub struct MassLoss {
    pub kind: MassLossKind,
    pub target: Vec<f64>,
}

impl MassLoss {
    pub fn new(kind: MassLossKind, target: Vec<f64>) -> Self {
        MassLoss { kind, target }
    }

    /// Loss value and dL/dm_i. Summed sequentially (the same for any thread count) with
    /// Neumaier compensation, so the value is accurate to a few ulps even over millions of nodes.
    pub fn value_and_grad(&self, mass: &[f64]) -> (f64, Vec<f64>) {
        assert_eq!(
            mass.len(),
            self.target.len(),
            "mass grid and target differ in size"
        );
        let mut loss = CompensatedSum::default();
        let grad = mass
            .iter()
            .zip(&self.target)
            .map(|(&m, &t)| match self.kind {
                MassLossKind::L2 => {
                    let r = m - t;
                    loss.add(0.5 * r * r);
                    r
                }
                MassLossKind::Log => {
                    let r = m.ln_1p() - t.ln_1p();
                    loss.add(0.5 * r * r);
                    r / (1.0 + m)
                }
            })
            .collect();
        (loss.value(), grad)
    }
}

/// Neumaier's compensated summation.
#[derive(Default, Clone, Copy)]
pub struct CompensatedSum {
    sum: f64,
    compensation: f64,
}

impl CompensatedSum {
    pub fn add(&mut self, x: f64) {
        let t = self.sum + x;
        if self.sum.abs() >= x.abs() {
            self.compensation += (self.sum - t) + x;
        } else {
            self.compensation += (x - t) + self.sum;
        }
        self.sum = t;
    }

    pub fn value(&self) -> f64 {
        self.sum + self.compensation
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradients_match_finite_differences() {
        let target = vec![0.0, 1.5, 3.0, 0.2];
        let mass = vec![0.3, 1.0, 4.0, 0.0];
        for kind in [MassLossKind::L2, MassLossKind::Log] {
            let loss = MassLoss::new(kind, target.clone());
            let (_, g) = loss.value_and_grad(&mass);
            for i in 0..mass.len() {
                let h = 1e-6;
                let mut mp = mass.clone();
                mp[i] += h;
                let mut mm = mass.clone();
                mm[i] -= h;
                let fd = (loss.value_and_grad(&mp).0 - loss.value_and_grad(&mm).0) / (2.0 * h);
                assert!(
                    (fd - g[i]).abs() < 1e-8,
                    "{kind:?} node {i}: {fd} vs {}",
                    g[i]
                );
            }
        }
    }
}
