//! Losses on the nodal mass grid (design.md section 3).
//!
//! - L2:  `L = sum_i 1/2 (m_i - m*_i)^2`
//! - log: `L = sum_i 1/2 (ln(m_i + 1) - ln(m*_i + 1))^2` (default; less sensitive to outliers,
//!   so it ejects fewer particles when source and target overlap little)

use crate::engine::mpm::{GridSpec, KernelKind, SimError, transfer};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How much more the body's total volume counts in [`volume_cost`] than one particle's: a
/// body squeezed as a whole changes the volume its rendered surface encloses, while a
/// particle squeezed among others that stretch does not.
pub const GLOBAL_VOLUME: f64 = 1.0;

/// The volume cost of particles of equal rest volume,
/// `sum_p 1/2 (ln J_p)^2 + GLOBAL_VOLUME * N * 1/2 (ln Jbar)^2` with `J_p = det F_p` and
/// `Jbar` their mean, and its gradient `(ln J_p + GLOBAL_VOLUME ln Jbar J_p / Jbar) F_p^-T`:
/// zero for a body at its rest volume, symmetric in compression and expansion, and unbounded
/// as a particle nears inversion. `Err(p)` names the first particle with `J <= 0` (where it
/// is undefined).
pub fn volume_cost(f: &[Matrix3<f64>]) -> Result<(f64, Vec<Matrix3<f64>>), usize> {
    // Each particle's J, ln J and F^-T in parallel; the sums in particle order (the same
    // bits on any thread count).
    let parts: Vec<Option<(f64, f64, Matrix3<f64>)>> = f
        .par_iter()
        .with_min_len(1024)
        .map(|f| {
            let j = f.determinant();
            let inv_t = f.try_inverse().filter(|_| j > 0.0)?.transpose();
            Some((j, j.ln(), inv_t))
        })
        .collect();
    let mut sum = CompensatedSum::default();
    let mut j_sum = CompensatedSum::default();
    for (p, part) in parts.iter().enumerate() {
        let (j, ln_j, _) = part.ok_or(p)?;
        sum.add(0.5 * ln_j * ln_j);
        j_sum.add(j);
    }
    let n = f.len().max(1) as f64;
    let mean = j_sum.value() / n;
    let ln_mean = if f.is_empty() { 0.0 } else { mean.ln() };
    let value = sum.value() + GLOBAL_VOLUME * n * 0.5 * ln_mean * ln_mean;
    let global = GLOBAL_VOLUME * ln_mean / mean;
    let grad = parts
        .into_par_iter()
        .with_min_len(1024)
        .map(|part| {
            let (j, ln_j, inv_t) = part.expect("checked above");
            (ln_j + global * j) * inv_t
        })
        .collect();
    Ok((value, grad))
}

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

/// The mass loss again on a finer grid (the simulation grid's cells split `refine` times per
/// axis, quadratic kernel): where the simulation grid cannot see how particles are arranged
/// within a cell, this one sees the holes and clumps that arrangement leaves.
#[derive(Clone, Debug)]
pub struct FineMassLoss {
    pub grid: GridSpec,
    pub loss: MassLoss,
    /// Weight of this loss in the objective.
    pub weight: f64,
}

/// The finer grid's kernel.
pub const FINE_KERNEL: KernelKind = KernelKind::Quadratic;

impl FineMassLoss {
    /// The grid `grid` with each cell split `refine` times per axis.
    pub fn refine(grid: &GridSpec, refine: usize) -> GridSpec {
        GridSpec {
            origin: grid.origin,
            dx: grid.dx / refine as f64,
            cells: grid.cells.map(|c| c * refine),
        }
    }

    /// `weight * loss(m(x))` for particles at `x` with masses `masses`.
    pub fn value(&self, x: &[Vector3<f64>], masses: &[f64]) -> Result<f64, SimError> {
        let m = transfer::mass_grid(&self.grid, FINE_KERNEL, x, masses)?;
        Ok(self.weight * self.loss.value_and_grad(&m).0)
    }

    /// [`FineMassLoss::value`] and its gradient with respect to `x`.
    pub fn value_and_grad(
        &self,
        x: &[Vector3<f64>],
        masses: &[f64],
    ) -> Result<(f64, Vec<Vector3<f64>>), SimError> {
        let m = transfer::mass_grid(&self.grid, FINE_KERNEL, x, masses)?;
        let (value, grad_m) = self.loss.value_and_grad(&m);
        let mut grad = transfer::mass_grid_reverse(&self.grid, FINE_KERNEL, x, masses, &grad_m);
        for g in &mut grad {
            *g *= self.weight;
        }
        Ok((self.weight * value, grad))
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
    fn volume_cost_gradient_matches_central_differences() {
        let f: Vec<Matrix3<f64>> = (0..4)
            .map(|p| {
                Matrix3::from_fn(|r, c| {
                    f64::from(u8::from(r == c)) + 0.1 * ((p * 9 + r * 3 + c) as f64).sin()
                })
            })
            .collect();
        let (value, grad) = volume_cost(&f).unwrap();
        assert!(value > 0.0);
        let h = 1e-6;
        for p in 0..f.len() {
            for k in 0..9 {
                let at = |d: f64| {
                    let mut g = f.clone();
                    g[p][k] += d;
                    volume_cost(&g).unwrap().0
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                assert!(
                    (fd - grad[p][k]).abs() < 1e-7,
                    "F[{p}][{k}]: {fd} vs {}",
                    grad[p][k]
                );
            }
        }
        // At rest: zero. Inverted: an error naming the particle.
        let rest = vec![Matrix3::identity(); 3];
        assert_eq!(volume_cost(&rest).unwrap().0, 0.0);
        let mut flipped = rest.clone();
        flipped[1][(0, 0)] = -1.0;
        assert_eq!(volume_cost(&flipped).err(), Some(1));
    }

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
