//! How thick a solid's thin parts are: what decides how many particles a leg or an ear gets.
//!
//! The **local thickness** of a point inside a solid is the diameter of the largest ball
//! inside the solid that contains the point (Hildebrand and Rueegsegger's definition, the
//! one bone morphometry uses): a leg's points have the leg's width, a body's the body's, a
//! sharp edge's the body's too (a big ball still reaches into it). On a lattice of
//! [`THICKNESS_ACROSS`] samples along the solid's longest side, with exact Euclidean distance
//! transforms (Felzenszwalb and Huttenlocher): the distance `r` from each inside sample to the
//! outside, then for each radius of a ladder the samples within it of a centre at least that
//! deep (the solid opened by a ball of that radius).
//!
//! A solid's **thin-part thickness** is the local thickness below which [`THIN_SHARE`] of its
//! volume lies: the thinnest parts that hold a visible share of it (legs, ears, a tail), not
//! a crease or a fin.

use super::mesh::{Aabb, TriMesh};
use super::voxelize::{Lattice, voxelize};
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Lattice samples along the solid's longest side.
pub const THICKNESS_ACROSS: usize = 96;

/// The share of the volume below the thin-part thickness.
pub const THIN_SHARE: f64 = 0.03;

/// A solid's thickness, in its own units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Thickness {
    /// The local thickness below which [`THIN_SHARE`] of the volume lies.
    pub thin: f64,
    /// The median local thickness (the body's).
    pub median: f64,
    /// The volume measured (the inside samples').
    pub volume: f64,
}

/// The thickness of `mesh`'s inside ([module docs](self)); `None` when the lattice finds no
/// inside.
pub fn thickness(mesh: &TriMesh) -> Option<Thickness> {
    let bounds = mesh.bounds();
    // One sample of outside around the box, so that every inside sample has an outside.
    let pad = bounds.longest_side() / THICKNESS_ACROSS as f64;
    let padded = Aabb {
        min: bounds.min - Vector3::repeat(2.0 * pad),
        max: bounds.max + Vector3::repeat(2.0 * pad),
    };
    let lattice = Lattice::covering(&padded, THICKNESS_ACROSS + 4);
    let inside = voxelize(mesh, &lattice).inside;
    let local = local_thickness(&inside, lattice.dims);
    let mut values: Vec<f64> = local.iter().copied().filter(|t| *t > 0.0).collect();
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let at = |share: f64| values[((share * values.len() as f64) as usize).min(values.len() - 1)];
    Some(Thickness {
        thin: at(THIN_SHARE) * lattice.spacing,
        median: at(0.5) * lattice.spacing,
        volume: values.len() as f64 * lattice.sample_volume(),
    })
}

/// Each sample's local thickness in samples (0 outside), on a lattice of `dims` (x slowest).
pub fn local_thickness(inside: &[bool], dims: [usize; 3]) -> Vec<f64> {
    // Depth: the distance to the nearest outside sample, less half a sample (the surface
    // lies between the two).
    let depth: Vec<f64> = squared_distance_to(dims, |i| !inside[i])
        .into_iter()
        .map(|d2| (d2.sqrt() - 0.5).max(0.0))
        .collect();
    let deepest = depth.iter().copied().fold(0.0, f64::max);
    let mut local = vec![0.0; inside.len()];
    for (i, t) in local.iter_mut().enumerate() {
        if inside[i] {
            // No ball fits: the sample's own depth is all there is.
            *t = 2.0 * depth[i].max(0.5);
        }
    }
    // A ladder of radii, 15% apart: each sample takes the largest whose opening holds it.
    let mut radius = 0.75;
    while radius <= deepest {
        let reach = squared_distance_to(dims, |i| depth[i] >= radius);
        // Half a sample of slack: depths are to sample centres, a surface lies between.
        let within = (radius + 0.5) * (radius + 0.5);
        local.par_iter_mut().zip(&reach).for_each(|(t, d2)| {
            if *t > 0.0 && *d2 <= within {
                *t = t.max(2.0 * radius);
            }
        });
        radius *= 1.15;
    }
    local
}

/// The squared Euclidean distance, in samples, from every sample to the nearest where `seed`
/// holds (infinite where none does): the exact 1D transform along z, then y, then x.
fn squared_distance_to(dims: [usize; 3], seed: impl Fn(usize) -> bool + Sync) -> Vec<f64> {
    let [nx, ny, nz] = dims;
    let mut d: Vec<f64> = (0..nx * ny * nz)
        .into_par_iter()
        .map(|i| if seed(i) { 0.0 } else { f64::INFINITY })
        .collect();
    // Along z: each line is contiguous.
    d.par_chunks_mut(nz).for_each(|line| {
        let t = transform_1d(line);
        line.copy_from_slice(&t);
    });
    // Along y: within each x plane, lines `nz` apart.
    d.par_chunks_mut(ny * nz).for_each(|plane| {
        let mut line = vec![0.0; ny];
        for k in 0..nz {
            for (j, v) in line.iter_mut().enumerate() {
                *v = plane[j * nz + k];
            }
            for (j, v) in transform_1d(&line).into_iter().enumerate() {
                plane[j * nz + k] = v;
            }
        }
    });
    // Along x: lines `ny * nz` apart, gathered per (y, z) and written back.
    let columns: Vec<Vec<f64>> = (0..ny * nz)
        .into_par_iter()
        .map(|jk| transform_1d(&(0..nx).map(|i| d[i * ny * nz + jk]).collect::<Vec<_>>()))
        .collect();
    d.par_chunks_mut(ny * nz)
        .enumerate()
        .for_each(|(i, plane)| {
            for (jk, v) in plane.iter_mut().enumerate() {
                *v = columns[jk][i];
            }
        });
    d
}

/// The lower envelope of parabolas `(x - q)^2 + f(q)`, sampled at each `x` (Felzenszwalb and
/// Huttenlocher, "Distance transforms of sampled functions", 2012).
fn transform_1d(f: &[f64]) -> Vec<f64> {
    let n = f.len();
    let finite: Vec<usize> = (0..n).filter(|&q| f[q].is_finite()).collect();
    if finite.is_empty() {
        return vec![f64::INFINITY; n];
    }
    let mut hull: Vec<usize> = Vec::with_capacity(finite.len());
    let mut starts: Vec<f64> = Vec::with_capacity(finite.len());
    let cross = |p: usize, q: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64))
    };
    for &q in &finite {
        while let Some(&p) = hull.last() {
            let s = cross(p, q);
            if s <= *starts.last().expect("one per hull parabola") {
                hull.pop();
                starts.pop();
            } else {
                starts.push(s);
                hull.push(q);
                break;
            }
        }
        if hull.is_empty() {
            hull.push(q);
            starts.push(f64::NEG_INFINITY);
        }
    }
    let mut out = vec![0.0; n];
    let mut k = 0;
    for (x, o) in out.iter_mut().enumerate() {
        while k + 1 < hull.len() && starts[k + 1] < x as f64 {
            k += 1;
        }
        let q = hull[k];
        *o = (x as f64 - q as f64).powi(2) + f[q];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_1d_transform_is_the_brute_force_one() {
        let f = [
            f64::INFINITY,
            0.0,
            f64::INFINITY,
            f64::INFINITY,
            2.0,
            f64::INFINITY,
            0.0,
        ];
        let got = transform_1d(&f);
        for (x, g) in got.iter().enumerate() {
            let want = (0..f.len())
                .map(|q| (x as f64 - q as f64).powi(2) + f[q])
                .fold(f64::INFINITY, f64::min);
            assert_eq!(*g, want, "at {x}");
        }
    }

    /// A box of `[w, h, d]` samples inside a padded lattice, and its lattice's dims.
    fn slab(size: [usize; 3]) -> (Vec<bool>, [usize; 3]) {
        let dims = size.map(|s| s + 4);
        let inside = (0..dims.iter().product())
            .map(|i: usize| {
                let c = [
                    i / (dims[1] * dims[2]),
                    (i / dims[2]) % dims[1],
                    i % dims[2],
                ];
                (0..3).all(|a| c[a] >= 2 && c[a] < 2 + size[a])
            })
            .collect();
        (inside, dims)
    }

    #[test]
    fn a_plate_is_as_thick_as_it_is_thin() {
        // A plate 8 samples thick and 40 wide: its local thickness is about 8 but at its
        // square rims, where no ball reaches the corner samples.
        let (inside, dims) = slab([40, 8, 40]);
        let t = local_thickness(&inside, dims);
        let values: Vec<f64> = t.into_iter().filter(|t| *t > 0.0).collect();
        let near = values.iter().filter(|t| (6.0..=8.5).contains(*t)).count();
        assert!(
            near as f64 >= 0.9 * values.len() as f64,
            "{near} of {}",
            values.len()
        );
        assert!(values.iter().all(|t| *t <= 8.5));
    }

    #[test]
    fn a_leg_is_thinner_than_its_body() {
        // A cube of 30 samples with a leg 4 samples square and 20 long below it.
        let dims = [34, 54, 34];
        let inside: Vec<bool> = (0..dims.iter().product())
            .map(|i: usize| {
                let (x, y, z) = (
                    i / (dims[1] * dims[2]),
                    (i / dims[2]) % dims[1],
                    i % dims[2],
                );
                let body = (2..32).contains(&x) && (22..52).contains(&y) && (2..32).contains(&z);
                let leg = (15..19).contains(&x) && (2..22).contains(&y) && (15..19).contains(&z);
                body || leg
            })
            .collect();
        let t = local_thickness(&inside, dims);
        let at = |x: usize, y: usize, z: usize| t[(x * dims[1] + y) * dims[2] + z];
        assert!(at(16, 10, 16) <= 5.0, "leg {}", at(16, 10, 16));
        assert!(at(16, 37, 16) >= 25.0, "body {}", at(16, 37, 16));
        // Beside a face the body is as thick as the body: the big ball reaches there.
        assert!(at(3, 37, 17) >= 25.0, "beside a face {}", at(3, 37, 17));
    }
}
