//! The reach cost: the target's thin parts pull the particles nearest to them.
//!
//! The mass loss only feels a particle within a kernel's width of where it should be, so a
//! horn or an ear two spacings from the body costs the mass loss little and pulls nothing
//! in. This cost samples the target's surface by area, each sample set half a spacing
//! inside along the surface's normal (where the centres of the particles that fill it
//! stand), and charges each sample whose nearest particle is farther than
//! [`REACH_TOLERANCE`] spacings:
//!
//! ```text
//!   reach = w * sum_s a_s 1/2 (d_s / h - tol)_+^2
//! ```
//!
//! with `a_s` the sample's area in square spacings, `d_s` the distance to its nearest
//! particle and `h` the particle spacing (so on a finer grid the same `w` weighs more
//! against the mass loss, which stays about the same: docs/morph.md, "Reach"). Its
//! gradient moves each charged sample's nearest particle straight toward it. It is the
//! quality judge's reach (`quality::Judge`, the target's surface to the nearest particle)
//! made an objective.

use crate::geometry::mesh::TriMesh;
use crate::geometry::point_grid::PointGrid;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Distance (spacings) within which a sample counts as reached and costs nothing: a
/// particle's centre half a spacing inside a filled surface is that far from the inset
/// sample at most on a lattice, with some slack.
pub const REACH_TOLERANCE: f64 = 0.75;
/// Samples are at most this many spacings apart along the surface.
const SAMPLE_GAP: f64 = 0.5;
/// A sample with no particle within this many spacings pulls nothing (a part of the target
/// the body is nowhere near is the mass loss's to reach, not this cost's).
const SEARCH_SPACINGS: i64 = 6;

/// The reach cost of one target (simulation coordinates).
#[derive(Clone, Debug)]
pub struct ReachLoss {
    /// Inset samples of the target's surface and the area each stands for (square spacings).
    samples: Vec<(Vector3<f64>, f64)>,
    spacing: f64,
    pub weight: f64,
}

impl ReachLoss {
    /// The reach cost of `target`'s surface for particles `spacing` apart.
    pub fn new(target: &TriMesh, spacing: f64, weight: f64) -> ReachLoss {
        // Set half a spacing inside; areas in square spacings.
        let samples = target
            .area_samples(SAMPLE_GAP * spacing)
            .into_iter()
            .map(|s| {
                (
                    s.point - 0.5 * spacing * s.normal,
                    s.area / (spacing * spacing),
                )
            })
            .collect();
        ReachLoss {
            samples,
            spacing,
            weight,
        }
    }

    /// For each sample beyond the tolerance: its nearest particle and the sample's excess
    /// distance in spacings, in sample order.
    fn charged(&self, x: &[Vector3<f64>]) -> Vec<Option<(usize, f64, f64)>> {
        let grid = PointGrid::new(x, self.spacing);
        self.samples
            .par_iter()
            .map(|(y, area)| {
                let (p, d) = grid.nearest_point(y, SEARCH_SPACINGS)?;
                let excess = d / self.spacing - REACH_TOLERANCE;
                (excess > 0.0).then_some((p, excess, *area))
            })
            .collect()
    }

    /// The cost for particles at `x`.
    pub fn value(&self, x: &[Vector3<f64>]) -> f64 {
        let sum: f64 = self
            .charged(x)
            .into_iter()
            .flatten()
            .map(|(_, e, a)| 0.5 * a * e * e)
            .sum();
        self.weight * sum
    }

    /// [`ReachLoss::value`] and its gradient with respect to `x` (summed in sample order:
    /// the same bits on any thread count).
    pub fn value_and_grad(&self, x: &[Vector3<f64>]) -> (f64, Vec<Vector3<f64>>) {
        let mut grad = vec![Vector3::zeros(); x.len()];
        let mut sum = 0.0;
        for (charge, (y, _)) in self.charged(x).into_iter().zip(&self.samples) {
            let Some((p, excess, area)) = charge else {
                continue;
            };
            sum += 0.5 * area * excess * excess;
            // d/dx_p of 1/2 a (|x_p - y| / h - tol)^2.
            let d = (x[p] - y).norm();
            grad[p] += (self.weight * area * excess / (self.spacing * d)) * (x[p] - y);
        }
        (self.weight * sum, grad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::assets::cube;

    /// The cube's surface, reached by a lattice that fills it and not by one that stops two
    /// spacings short on one side; the gradient matches central differences.
    #[test]
    fn reach_charges_what_no_particle_reaches_and_its_gradient_is_exact() {
        let h = 0.25;
        let mesh = cube(2.0, 4);
        let lattice = |x_end: f64| {
            let mut p = Vec::new();
            for i in 0..8 {
                for j in 0..8 {
                    for k in 0..8 {
                        let at = |n: usize| -1.0 + (n as f64 + 0.5) * h;
                        if at(i) < x_end {
                            p.push(Vector3::new(at(i), at(j), at(k)));
                        }
                    }
                }
            }
            p
        };
        let loss = ReachLoss::new(&mesh, h, 1.0);
        assert_eq!(loss.value(&lattice(1.0)), 0.0, "a filled cube is reached");
        let short = lattice(1.0 - 2.0 * h);
        let (value, grad) = loss.value_and_grad(&short);
        // The +x face (4 units^2 = 64 square spacings) is 2 spacings from the particles'
        // centres: about 1/2 * 64 * (2 - 0.75)^2 = 50, more toward its edges.
        assert!(value > 40.0 && value < 200.0, "{value}");
        // Every pull points toward +x, and only particles of the last layer are pulled.
        for (x, g) in short.iter().zip(&grad) {
            if *g != Vector3::zeros() {
                assert!(g.x < 0.0 && x.x > 0.0, "{x} {g}");
            }
        }
        // Central differences on a jittered copy (no ties between nearest particles).
        let mut x = short.clone();
        for (n, p) in x.iter_mut().enumerate() {
            let s = (n as f64 * 0.618).fract() - 0.5;
            *p += Vector3::new(0.03 * s, -0.02 * s, 0.025 * (0.5 - s));
        }
        let (_, grad) = loss.value_and_grad(&x);
        let eps = 1e-6;
        for p in [0, 100, 300, x.len() - 1, x.len() - 7] {
            for a in 0..3 {
                let mut plus = x.clone();
                plus[p][a] += eps;
                let mut minus = x.clone();
                minus[p][a] -= eps;
                let fd = (loss.value(&plus) - loss.value(&minus)) / (2.0 * eps);
                assert!(
                    (fd - grad[p][a]).abs() <= 1e-6 * (1.0 + fd.abs()),
                    "particle {p} axis {a}: fd {fd} grad {}",
                    grad[p][a]
                );
            }
        }
    }
}
