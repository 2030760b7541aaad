//! Coarse-to-fine: a morph is solved first on a grid half as fine (an eighth of the
//! particles, half the substeps: about a sixteenth of the cost), and each segment of the
//! finer morph starts its optimization from the coarse solution's controls instead of from
//! none, the way multigrid and image pyramids carry a coarse solution up.
//!
//! A control belongs to the material (each particle's `Fc` factors its rest shape), so it is
//! carried up in material space: a fine particle takes the mean of the coarse controls
//! around its rest position, weighted by a quadratic B-spline one coarse particle spacing
//! wide ([`Prolongation`]). Both levels fill the same source, so every fine particle has
//! coarse neighbours, except where a feature thinner than a coarse spacing got no coarse
//! particle: there the nearest coarse particle within two spacings gives its control, and
//! beyond that the particle starts from no control.

use super::segment::Layers;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::collections::HashMap;

/// The map from a coarse level's per-particle controls to a finer level's particles.
pub struct Prolongation {
    /// Per fine particle: (coarse particle, weight), the weights summing to 1 (none: the
    /// particle has no coarse neighbour and starts from no control).
    weights: Vec<Vec<(u32, f64)>>,
    coarse: usize,
}

/// Quadratic B-spline of a distance in spacings (support 1.5).
fn bspline(u: f64) -> f64 {
    let u = u.abs();
    if u < 0.5 {
        0.75 - u * u
    } else if u < 1.5 {
        0.5 * (1.5 - u) * (1.5 - u)
    } else {
        0.0
    }
}

/// How far the nearest-neighbour fallback looks, in coarse spacings.
const FALLBACK_SPACINGS: f64 = 2.0;

impl Prolongation {
    /// `coarse` and `fine` are rest positions in one frame of reference; `spacing` is the
    /// coarse particles' spacing there.
    pub fn new(coarse: &[Vector3<f64>], fine: &[Vector3<f64>], spacing: f64) -> Prolongation {
        let cell = |x: &Vector3<f64>| x.map(|c| (c / spacing).floor() as i64);
        let mut buckets: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (q, x) in coarse.iter().enumerate() {
            let c = cell(x);
            buckets.entry([c.x, c.y, c.z]).or_default().push(q as u32);
        }
        // Cells within `reach` spacings of `x`, in a fixed order, and their particles in
        // index order: the sums below do not depend on the thread count.
        let around = |x: &Vector3<f64>, reach: f64, visit: &mut dyn FnMut(u32)| {
            let lo = (x.map(|c| c / spacing - reach)).map(|c| c.floor() as i64);
            let hi = (x.map(|c| c / spacing + reach)).map(|c| c.floor() as i64);
            for i in lo.x..=hi.x {
                for j in lo.y..=hi.y {
                    for k in lo.z..=hi.z {
                        for &q in buckets.get(&[i, j, k]).into_iter().flatten() {
                            visit(q);
                        }
                    }
                }
            }
        };
        let weights = fine
            .par_iter()
            .map(|x| {
                let mut w = Vec::new();
                around(x, 1.5, &mut |q| {
                    let d = (x - coarse[q as usize]) / spacing;
                    let weight = bspline(d.x) * bspline(d.y) * bspline(d.z);
                    if weight > 0.0 {
                        w.push((q, weight));
                    }
                });
                let total: f64 = w.iter().map(|(_, v)| v).sum();
                if total > 0.0 {
                    w.iter_mut().for_each(|(_, v)| *v /= total);
                    return w;
                }
                let mut nearest: Option<(f64, u32)> = None;
                around(x, FALLBACK_SPACINGS, &mut |q| {
                    let d = (x - coarse[q as usize]).norm() / spacing;
                    if d <= FALLBACK_SPACINGS && nearest.is_none_or(|(best, _)| d < best) {
                        nearest = Some((d, q));
                    }
                });
                nearest.map(|(_, q)| vec![(q, 1.0)]).unwrap_or_default()
            })
            .collect();
        Prolongation {
            weights,
            coarse: coarse.len(),
        }
    }

    /// Fine particles.
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }

    /// Fine particles that got no coarse control (none within the fallback's reach).
    pub fn unreached(&self) -> usize {
        self.weights.iter().filter(|w| w.is_empty()).count()
    }

    /// One segment's coarse controls carried to the fine particles, layer by layer.
    pub fn apply(&self, coarse: &Layers) -> Layers {
        coarse
            .iter()
            .map(|layer| {
                assert_eq!(layer.len(), self.coarse, "controls of another level");
                self.weights
                    .par_iter()
                    .map(|w| {
                        w.iter()
                            .fold(Matrix3::zeros(), |sum, &(q, v)| sum + layer[q as usize] * v)
                    })
                    .collect()
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice(n: usize, spacing: f64, offset: f64) -> Vec<Vector3<f64>> {
        let mut x = Vec::new();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    x.push(
                        Vector3::new(i as f64, j as f64, k as f64) * spacing
                            + Vector3::repeat(offset),
                    );
                }
            }
        }
        x
    }

    #[test]
    fn a_linear_control_field_is_carried_up_exactly_inside_the_body() {
        // Coarse particles 1 apart, fine ones 0.5 apart inside them: a control varying
        // linearly in space is reproduced wherever a fine particle's whole stencil is in.
        let coarse = lattice(8, 1.0, 0.25);
        let fine = lattice(14, 0.5, 0.5);
        let p = Prolongation::new(&coarse, &fine, 1.0);
        let field =
            |x: &Vector3<f64>| Matrix3::from_diagonal(&Vector3::new(x.x, 2.0 * x.y, -x.z)) * 0.01;
        let layer: Vec<_> = coarse.iter().map(field).collect();
        let carried = p.apply(&vec![layer]);
        assert_eq!(p.unreached(), 0);
        for (x, c) in fine.iter().zip(&carried[0]) {
            if x.iter().all(|&v| (2.0..=6.0).contains(&v)) {
                assert!(
                    (c - field(x)).norm() < 1e-12,
                    "at {x:?}: {c} vs {}",
                    field(x)
                );
            }
        }
    }

    #[test]
    fn a_fine_particle_far_from_the_coarse_body_starts_from_no_control() {
        let coarse = lattice(3, 1.0, 0.0);
        let fine = vec![Vector3::new(1.0, 1.0, 3.5), Vector3::new(1.0, 1.0, 9.0)];
        let p = Prolongation::new(&coarse, &fine, 1.0);
        let layer = vec![Matrix3::identity(); coarse.len()];
        let carried = p.apply(&vec![layer]);
        assert!(
            (carried[0][0] - Matrix3::identity()).norm() < 1e-12,
            "the nearest within reach"
        );
        assert_eq!(carried[0][1], Matrix3::zeros());
        assert_eq!(p.unreached(), 1);
    }
}
