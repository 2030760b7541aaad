//! How well the final particles fill the target.
//!
//! - `target_cells_filled`: of the grid cells that hold a target particle, the fraction that
//!   also hold a final source particle.
//! - `particles_outside`: the fraction of final particles farther than two particle spacings
//!   outside the target. Target particles sit on the sub-cell lattice (spacing h) and each
//!   stands for a cube of side h, so "outside by more than 2h" means no target particle
//!   within 2.5 h.

use crate::engine::mpm::GridSpec;
use nalgebra::Vector3;
use rustc_hash::FxHashSet;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct FillMetrics {
    pub target_cells: usize,
    pub target_cells_filled: f64,
    pub particles_outside: f64,
    /// Fraction of final particles in empty space: farther than two spacings outside both
    /// the target and the source's starting shape (flung out rather than not yet arrived).
    pub particles_ejected: f64,
}

pub fn fill_metrics(
    grid: &GridSpec,
    spacing: f64,
    target: &[Vector3<f64>],
    source_start: &[Vector3<f64>],
    particles: &[Vector3<f64>],
) -> FillMetrics {
    let origin = grid.origin_vec();
    let cell_of = |x: &Vector3<f64>, h: f64| -> [i64; 3] {
        let g = (x - origin) / h;
        [g.x.floor() as i64, g.y.floor() as i64, g.z.floor() as i64]
    };
    let target_cells: FxHashSet<[i64; 3]> = target.iter().map(|x| cell_of(x, grid.dx)).collect();
    let source_cells: FxHashSet<[i64; 3]> = particles.iter().map(|x| cell_of(x, grid.dx)).collect();
    let filled = target_cells.intersection(&source_cells).count();
    let far_from_target = far_from(&origin, spacing, target, particles);
    let far_from_source = far_from(&origin, spacing, source_start, particles);
    let outside = far_from_target.iter().filter(|f| **f).count();
    let ejected = far_from_target
        .iter()
        .zip(&far_from_source)
        .filter(|(t, s)| **t && **s)
        .count();
    FillMetrics {
        target_cells: target_cells.len(),
        target_cells_filled: filled as f64 / target_cells.len().max(1) as f64,
        particles_outside: outside as f64 / particles.len().max(1) as f64,
        particles_ejected: ejected as f64 / particles.len().max(1) as f64,
    }
}

/// For each particle: is it farther than 2 spacings outside the shape made of `lattice`
/// points (each standing for a cube of side h), i.e. no lattice point within 2.5 h?
fn far_from(
    origin: &Vector3<f64>,
    spacing: f64,
    lattice: &[Vector3<f64>],
    particles: &[Vector3<f64>],
) -> Vec<bool> {
    let cell = |x: &Vector3<f64>| -> [i64; 3] {
        let g = (x - origin) / spacing;
        [g.x.floor() as i64, g.y.floor() as i64, g.z.floor() as i64]
    };
    let occupied: FxHashSet<[i64; 3]> = lattice.iter().map(cell).collect();
    let reach = 2.5 * spacing;
    particles
        .iter()
        .map(|x| {
            let c = cell(x);
            for di in -3..=3 {
                for dj in -3..=3 {
                    for dk in -3..=3 {
                        let n = [c[0] + di, c[1] + dj, c[2] + dk];
                        if occupied.contains(&n) {
                            let centre = origin
                                + spacing
                                    * Vector3::new(
                                        n[0] as f64 + 0.5,
                                        n[1] as f64 + 0.5,
                                        n[2] as f64 + 0.5,
                                    );
                            if (x - centre).norm() <= reach {
                                return false;
                            }
                        }
                    }
                }
            }
            true
        })
        .collect()
}
