//! The quality judge: how well a morph's final particles take the target's shape, measured the
//! same way for every run and independently of the simulation's grid and loss.
//!
//! On a judge lattice of [`JUDGE_ACROSS`] points along the longest side of the target's box:
//! - a point is **inside** if the target's winding number says so;
//! - a point is **covered** if a final particle lies within `0.75 h` of it (`h` the initial
//!   particle spacing);
//! - **fill** is `IoU(covered, inside)` divided by the IoU that a perfect fill reaches: the
//!   target's own particle lattice at the same spacing, judged the same way. 1 is perfect.
//!
//! - **material fill** is the same for the body's material: a point is covered when it lies in
//!   a particle's rest cell carried by the deformation fitted to its rest neighbours, divided by
//!   what the target lattice reaches that way. Stretched material whose particle layers have
//!   parted is whole by this measure and holed by `fill`.
//!
//! Also: the **ejected** share (particles farther than `2 h` outside the target: no target
//! lattice particle within `2.5 h`), the **surface gap** (area-weighted mean distance from the
//! target's surface to the nearest particle, in spacings), min/mean/max `J = det F` with the
//! share of inverted particles (`J <= 0`), and the **close-neighbour share**: particles with
//! another closer than half the initial spacing. It measures order below the grid: 0 for the
//! initial lattice, 41% for uniformly random points at the same density; a body whose
//! particles clump leaves gaps elsewhere that a renderer sees.

use crate::geometry::neighbourhood::RestNeighbourhood;
use crate::geometry::point_grid::PointGrid;
use crate::geometry::{Lattice, TriMesh, voxelize};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Judge points along the longest side of the target's box.
pub const JUDGE_ACROSS: usize = 96;

/// A point counts as covered by a particle within this many initial spacings.
pub const COVER_RADIUS: f64 = 0.75;

/// A neighbour closer than this many initial spacings counts as close.
pub const CLOSE: f64 = 0.5;

/// Share of `points` with another point closer than `CLOSE * spacing`.
pub fn close_neighbour_share(points: &[Vector3<f64>], spacing: f64) -> f64 {
    let radius = CLOSE * spacing;
    let grid = PointGrid::new(points, radius);
    let close = (0..points.len())
        .into_par_iter()
        .filter(|&i| grid.any_within_except(&points[i], radius, i))
        .count();
    close as f64 / points.len().max(1) as f64
}

/// Where the surface gap stops searching, in spacings (a gap this large is reported as it).
const GAP_CAP: f64 = 8.0;

/// The judged quality of one morph's final state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    /// `iou / perfect_iou`: 1 is as good as a lattice fill of the target.
    pub fill: f64,
    /// The fill of the body's material rather than of its particles: a judge point is covered
    /// when it lies in a particle's rest cell carried by the deformation fitted to its rest
    /// neighbours, normalised by the target lattice's own (docs/lab/2026-12-08-method-record.md, "Material fill").
    /// Where a morph stretches the body, its particle layers part (1.6 spacings apart
    /// along the README job's lobes) and `fill` counts the material between them as missed;
    /// this does not. 0 in reports older than 0.13.0.
    #[serde(default)]
    pub material_fill: f64,
    pub iou: f64,
    pub perfect_iou: f64,
    /// Share of particles farther than two spacings outside the target.
    pub ejected: f64,
    /// Mean distance from the target's surface to the nearest particle, in spacings.
    pub surface_gap: f64,
    /// Reach: the same distance's 99th percentile over the target's area, and its largest
    /// (capped at `GAP_CAP`), in spacings. A horn or an ear no particle reaches shows here,
    /// not in the IoU.
    #[serde(default)]
    pub reach_p99: f64,
    #[serde(default)]
    pub reach_max: f64,
    /// The reach of a perfect fill: the target's own particle lattice judged the same way
    /// (99th percentile and largest). Lattice particles stand up to about a spacing from a
    /// curved surface, so this is the floor `reach_p99` is read against (sphere -> spot: about
    /// 1.0). 0 in reports older than 0.13.0.
    #[serde(default)]
    pub perfect_reach_p99: f64,
    #[serde(default)]
    pub perfect_reach_max: f64,
    pub min_j: f64,
    #[serde(default)]
    pub mean_j: f64,
    pub max_j: f64,
    /// Share of particles with a neighbour closer than [`CLOSE`] initial spacings.
    #[serde(default)]
    pub close_share: f64,
    /// Share of particles with `J <= 0`.
    pub inverted: f64,
    /// Judge lattice points.
    pub judge_points: usize,
}

/// `|a and b| / |a or b|`.
fn iou(a: &[bool], b: &[bool]) -> f64 {
    let (mut both, mut either) = (0usize, 0usize);
    for (x, y) in a.iter().zip(b) {
        both += usize::from(*x && *y);
        either += usize::from(*x || *y);
    }
    both as f64 / either.max(1) as f64
}

/// How far a body has come toward a target, frame by frame: its IoU with the target's inside
/// on a coarse lattice ([`super::motion::PROGRESS_ACROSS`] points along the longest side)
/// over the box of the target and the body at rest, a point covered by a particle within
/// [`COVER_RADIUS`] spacings.
pub struct Progress {
    lattice: Lattice,
    inside: Vec<bool>,
    spacing: f64,
}

impl Progress {
    /// For `target` and a body at rest at `rest` (sim coordinates), particles `spacing` apart.
    pub fn new(target: &TriMesh, rest: &[Vector3<f64>], spacing: f64) -> Progress {
        let mut bounds = target.bounds();
        for p in rest {
            bounds.grow(p);
        }
        let lattice = Lattice::covering(&bounds, super::motion::PROGRESS_ACROSS);
        let inside = voxelize(target, &lattice).inside;
        Progress {
            lattice,
            inside,
            spacing,
        }
    }

    /// The IoU of particles `x` with the target's inside.
    pub fn iou(&self, x: &[Vector3<f64>]) -> f64 {
        iou(
            &covered(&self.lattice, x, COVER_RADIUS * self.spacing),
            &self.inside,
        )
    }
}

/// The material cover's half-width: a particle stands for its rest cell (`h` wide), widened
/// by a tenth so that neighbouring deformed cells, fitted apart, leave no cracks.
pub const MATERIAL_HALF_WIDTH: f64 = 0.55;
/// A fit whose rms residual is above this many spacings (neighbours that parted or mixed)
/// is not a continuum there: the particle covers its undeformed cell.
const MATERIAL_FIT_RESIDUAL: f64 = 0.25;
/// A fitted cell reaching further than this many spacings from its particle along an axis is
/// not trusted either (the same fallback).
const MATERIAL_MAX_REACH: f64 = 4.0;

/// The deformation of the material around each particle since rest ([`RestNeighbourhood`]):
/// the identity where no fit holds.
fn fitted_deformation(
    rest: &[Vector3<f64>],
    x: &[Vector3<f64>],
    spacing: f64,
) -> Vec<Matrix3<f64>> {
    let radius = crate::geometry::neighbourhood::FIT_SPACINGS * spacing;
    let grid = PointGrid::new(rest, radius);
    (0..rest.len())
        .into_par_iter()
        .map(|i| {
            let Some(neighbourhood) = RestNeighbourhood::new(rest, &grid, i, radius) else {
                return Matrix3::identity();
            };
            let (f, residual) = neighbourhood.fit(rest, x, i);
            let fits = residual <= MATERIAL_FIT_RESIDUAL * spacing
                && f.determinant() > 0.0
                && f.iter().all(|v| v.is_finite());
            if fits { f } else { Matrix3::identity() }
        })
        .collect()
}

/// Which points of `lattice` lie in a particle's material: its rest cell ([`MATERIAL_HALF_WIDTH`]
/// spacings either side) carried by the deformation `f` fitted around it, centred on it.
fn materially_covered(
    lattice: &Lattice,
    x: &[Vector3<f64>],
    f: &[Matrix3<f64>],
    spacing: f64,
) -> Vec<bool> {
    let half = MATERIAL_HALF_WIDTH * spacing;
    let d = lattice.dims;
    let hits: Vec<Vec<usize>> = x
        .par_iter()
        .zip(f)
        .map(|(p, f)| {
            // A particle that is not anywhere covers nothing (and must not sweep the lattice).
            if !p.iter().all(|c| c.is_finite()) {
                return Vec::new();
            }
            let mut f = *f;
            let mut reach = Vector3::from_fn(|a, _| f.row(a).abs().sum() * half);
            if reach.max() > MATERIAL_MAX_REACH * spacing {
                f = Matrix3::identity();
                reach = Vector3::repeat(half);
            }
            let Some(inverse) = f.try_inverse() else {
                return Vec::new();
            };
            let range = |a: usize| {
                let lo = ((p[a] - reach[a] - lattice.origin[a]) / lattice.spacing - 0.5).ceil();
                let hi = ((p[a] + reach[a] - lattice.origin[a]) / lattice.spacing - 0.5).floor();
                let lo = lo.max(0.0) as usize;
                let hi = hi.min(d[a] as f64 - 1.0);
                (lo, hi)
            };
            let ((i0, i1), (j0, j1), (k0, k1)) = (range(0), range(1), range(2));
            let mut inside = Vec::new();
            if i1 < 0.0 || j1 < 0.0 || k1 < 0.0 {
                return inside;
            }
            for i in i0..=i1 as usize {
                for j in j0..=j1 as usize {
                    for k in k0..=k1 as usize {
                        let rest = inverse * (lattice.point(i, j, k) - p);
                        if rest.amax() <= half {
                            inside.push((i * d[1] + j) * d[2] + k);
                        }
                    }
                }
            }
            inside
        })
        .collect();
    let mut covered = vec![false; lattice.len()];
    for index in hits.into_iter().flatten() {
        covered[index] = true;
    }
    covered
}

/// Which points of `lattice` lie within `radius` of a particle: each particle marks the
/// points in its box, so a frame costs its particles times the few points each reaches,
/// not the whole lattice times 27 cube lookups (3 ms a frame of the progress measure even
/// for 8 particles). Non-finite particles cover nothing.
fn covered(lattice: &Lattice, particles: &[Vector3<f64>], radius: f64) -> Vec<bool> {
    let d = lattice.dims;
    let mut out = vec![false; lattice.len()];
    // The points with an index in lo..=hi along an axis may lie within `radius` of `c`: one
    // more on each side than the box's own bounds, so rounding never leaves one out (the
    // distance test decides).
    let span = |c: f64, a: usize| {
        let at = |x: f64| (x - lattice.origin[a]) / lattice.spacing - 0.5;
        let lo = (at(c - radius).floor() - 1.0).max(0.0);
        let hi = (at(c + radius).ceil() + 1.0).min(d[a] as f64 - 1.0);
        if hi < lo {
            #[allow(clippy::reversed_empty_ranges)]
            return 1..=0;
        }
        lo as usize..=hi as usize
    };
    for p in particles.iter().filter(|p| p.iter().all(|c| c.is_finite())) {
        for i in span(p[0], 0) {
            for j in span(p[1], 1) {
                for k in span(p[2], 2) {
                    let index = (i * d[1] + j) * d[2] + k;
                    if !out[index] && (p - lattice.point(i, j, k)).norm() <= radius {
                        out[index] = true;
                    }
                }
            }
        }
    }
    out
}

/// The judge lattice over the target's box and which of its points are inside the target.
pub struct Judge {
    lattice: Lattice,
    inside: Vec<bool>,
    /// Area-weighted samples of the target's surface, at most [`SAMPLE_SPACINGS`] apart.
    surface: Vec<(Vector3<f64>, f64)>,
    spacing: f64,
    /// The perfect fill's IoU: the target lattice particles judged the same way.
    perfect_iou: f64,
    /// The same for the material cover (the target lattice at rest: every `F` the identity).
    perfect_material_iou: f64,
    /// The target lattice's reach (p99, max).
    perfect_reach: (f64, f64),
    target_lattice: Vec<Vector3<f64>>,
}

/// Target surface samples are at most this many initial spacings apart (reach must see a
/// horn a particle spacing wide on a mesh of large triangles).
const SAMPLE_SPACINGS: f64 = 0.5;

/// The area-weighted 99th percentile and the largest of distances `(distance, area)`.
fn reach(mut gaps: Vec<(f64, f64)>) -> (f64, f64) {
    gaps.sort_by(|p, q| p.0.total_cmp(&q.0));
    let total: f64 = gaps.iter().map(|g| g.1).sum();
    let mut below = 0.0;
    let mut p99 = gaps.last().map_or(0.0, |g| g.0);
    for &(d, a) in &gaps {
        below += a;
        if below >= 0.99 * total {
            p99 = d;
            break;
        }
    }
    (p99, gaps.last().map_or(0.0, |g| g.0))
}

impl Judge {
    /// A judge for `target` (sim coordinates), particles of initial spacing `spacing`, and
    /// the target's own particle lattice at that spacing.
    pub fn new(target: &TriMesh, spacing: f64, target_lattice: &[Vector3<f64>]) -> Judge {
        let lattice = Lattice::covering(&target.bounds(), JUDGE_ACROSS);
        let inside = voxelize(target, &lattice).inside;
        let surface = target
            .area_samples(SAMPLE_SPACINGS * spacing)
            .into_iter()
            .map(|s| (s.point, s.area))
            .collect();
        let mut judge = Judge {
            lattice,
            inside,
            surface,
            spacing,
            perfect_iou: 1.0,
            perfect_material_iou: 1.0,
            perfect_reach: (0.0, 0.0),
            target_lattice: target_lattice.to_vec(),
        };
        judge.perfect_iou = iou(&judge.covered(target_lattice), &judge.inside);
        let at_rest = vec![Matrix3::identity(); target_lattice.len()];
        judge.perfect_material_iou = iou(
            &materially_covered(&judge.lattice, target_lattice, &at_rest, spacing),
            &judge.inside,
        );
        judge.perfect_reach = reach(judge.surface_gaps(target_lattice));
        judge
    }

    /// Each target surface sample's distance to the nearest of `particles` (in spacings,
    /// capped at [`GAP_CAP`]) and the area it stands for.
    fn surface_gaps(&self, particles: &[Vector3<f64>]) -> Vec<(f64, f64)> {
        let grid = PointGrid::new(particles, self.spacing);
        let rings = GAP_CAP.ceil() as i64;
        self.surface
            .par_iter()
            .map(|(c, a)| {
                let d = grid
                    .nearest(c, rings)
                    .map_or(GAP_CAP, |d| (d / self.spacing).min(GAP_CAP));
                (d, *a)
            })
            .collect()
    }

    /// Which judge points lie within [`COVER_RADIUS`] spacings of a particle.
    fn covered(&self, particles: &[Vector3<f64>]) -> Vec<bool> {
        covered(&self.lattice, particles, COVER_RADIUS * self.spacing)
    }

    /// Judges final particle positions `x` with volume ratios `j`, the particles at rest at
    /// `rest` (same order).
    pub fn judge(&self, rest: &[Vector3<f64>], x: &[Vector3<f64>], j: &[f64]) -> Quality {
        assert_eq!(rest.len(), x.len(), "one rest position per particle");
        let iou_final = iou(&self.covered(x), &self.inside);
        let deformation = fitted_deformation(rest, x, self.spacing);
        let material_iou = iou(
            &materially_covered(&self.lattice, x, &deformation, self.spacing),
            &self.inside,
        );
        // Ejected: no target lattice particle within 2.5 spacings.
        let target = PointGrid::new(&self.target_lattice, self.spacing);
        let ejected = x
            .par_iter()
            .filter(|p| target.nearest(p, 3).is_none_or(|d| d > 2.5 * self.spacing))
            .count();
        // Surface gap: the area-weighted mean distance to the nearest particle.
        let gaps = self.surface_gaps(x);
        let area: f64 = gaps.iter().map(|g| g.1).sum();
        let weighted: f64 = gaps.iter().map(|(d, a)| d * a).sum();
        let (reach_p99, reach_max) = reach(gaps);
        let n = x.len().max(1) as f64;
        Quality {
            fill: iou_final / self.perfect_iou.max(1e-300),
            material_fill: material_iou / self.perfect_material_iou.max(1e-300),
            iou: iou_final,
            perfect_iou: self.perfect_iou,
            ejected: ejected as f64 / n,
            surface_gap: weighted / area.max(1e-300),
            reach_p99,
            reach_max,
            perfect_reach_p99: self.perfect_reach.0,
            perfect_reach_max: self.perfect_reach.1,
            min_j: j.iter().copied().fold(f64::INFINITY, f64::min),
            mean_j: j.iter().sum::<f64>() / n,
            close_share: close_neighbour_share(x, self.spacing),
            max_j: j.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            inverted: j.iter().filter(|j| **j <= 0.0).count() as f64 / n,
            judge_points: self.lattice.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::mpm::GridSpec;
    use crate::geometry::{assets, particles_in};

    /// The particles' marks agree with asking every lattice point for a particle near it,
    /// particles outside the lattice and non-finite ones included.
    #[test]
    fn covered_matches_the_point_by_point_query() {
        let lattice = Lattice {
            origin: Vector3::new(-1.0, -2.0, 0.5),
            spacing: 0.3,
            dims: [11, 7, 9],
        };
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut particles: Vec<Vector3<f64>> = (0..300)
            .map(|_| Vector3::new(next() * 6.0 - 2.5, next() * 5.0 - 3.5, next() * 5.0 - 1.0))
            .collect();
        particles.push(Vector3::new(f64::NAN, 0.0, 1.0));
        particles.push(Vector3::new(f64::INFINITY, 0.0, 1.0));
        // Exactly on a point, and exactly the radius from one.
        particles.push(lattice.point(3, 2, 1));
        particles.push(lattice.point(5, 5, 5) + Vector3::new(0.2, 0.0, 0.0));
        for radius in [0.05, 0.2, 0.31, 0.9] {
            let grid = PointGrid::new(&particles, radius);
            let d = lattice.dims;
            let expected: Vec<bool> = (0..lattice.len())
                .map(|index| {
                    let (i, j, k) = (index / (d[1] * d[2]), (index / d[2]) % d[1], index % d[2]);
                    grid.any_within(&lattice.point(i, j, k), radius)
                })
                .collect();
            assert_eq!(
                covered(&lattice, &particles, radius),
                expected,
                "radius {radius}"
            );
        }
    }

    fn sphere() -> (TriMesh, GridSpec) {
        let mesh = assets::uv_sphere(5.0, 24, 48, |_, _| 1.0);
        (mesh, GridSpec::centred_cube(16, 1.0))
    }

    /// A horn the particles do not reach: the sphere's own particles judged against the
    /// sphere with a horn (2.5 units long, 5 spacings) have a small mean gap but a reach of
    /// the horn's length; the horned target's own lattice reaches it.
    #[test]
    fn reach_sees_a_horn_the_particles_miss() {
        let (plain, grid) = sphere();
        let horned = assets::uv_sphere(5.0, 48, 96, |theta, _| {
            1.0 + 0.5 * (-(theta / 0.2).powi(2)).exp()
        });
        let ball = particles_in(&plain, &grid, 2, None).positions;
        let lattice = particles_in(&horned, &grid, 2, None).positions;
        let judge = Judge::new(&horned, 0.5, &lattice);
        let missed = judge.judge(&ball, &ball, &vec![1.0; ball.len()]);
        let reached = judge.judge(&lattice, &lattice, &vec![1.0; lattice.len()]);
        assert!(missed.reach_max > 4.0, "{missed:?}");
        assert!(reached.reach_max < 1.5, "{reached:?}");
        assert!(reached.reach_p99 <= reached.reach_max, "{reached:?}");
        // The mean hardly moves: what the horn costs is in the reach.
        assert!(missed.surface_gap < 1.0, "{missed:?}");
        // The floor to read reach against: the lattice's own, whatever is judged, and
        // about a spacing (lattice particles stand back from a curved surface).
        assert_eq!(reached.reach_p99, reached.perfect_reach_p99);
        assert_eq!(reached.reach_max, reached.perfect_reach_max);
        assert_eq!(missed.perfect_reach_p99, reached.perfect_reach_p99);
        assert!(
            (0.5..1.2).contains(&reached.perfect_reach_p99),
            "{reached:?}"
        );
    }

    #[test]
    fn a_lattice_fill_is_perfect_and_a_shrunken_one_is_not() {
        let (mesh, grid) = sphere();
        let lattice = particles_in(&mesh, &grid, 2, None).positions;
        let judge = Judge::new(&mesh, 0.5, &lattice);
        let ones = vec![1.0; lattice.len()];
        let q = judge.judge(&lattice, &lattice, &ones);
        assert!((q.fill - 1.0).abs() < 1e-12, "{q:?}");
        assert!((q.material_fill - 1.0).abs() < 1e-12, "{q:?}");
        assert!(q.perfect_iou > 0.8, "{q:?}");
        assert_eq!(q.ejected, 0.0);
        assert!(q.surface_gap < 1.0, "{q:?}");
        // The same particles squeezed to 80% of the size: a worse fill and a larger gap.
        let small: Vec<_> = lattice.iter().map(|p| 0.8 * p).collect();
        let s = judge.judge(&lattice, &small, &ones);
        assert!(s.fill < 0.7 * q.fill, "{s:?}");
        assert!(s.material_fill < 0.7, "{s:?}");
        assert!(s.surface_gap > q.surface_gap + 1.0, "{s:?}");
        // Moved far away: every particle ejected, nothing covered.
        let away: Vec<_> = lattice
            .iter()
            .map(|p| p + Vector3::new(20.0, 0.0, 0.0))
            .collect();
        let a = judge.judge(&lattice, &away, &ones);
        assert_eq!(a.ejected, 1.0);
        assert_eq!(a.fill, 0.0);
        assert_eq!(a.material_fill, 0.0);
        assert_eq!(a.surface_gap, GAP_CAP);
        assert_eq!(q.close_share, 0.0);
    }

    /// A sphere's particles stretched 1.6 times along x (and 1/sqrt(1.6) across, the volume
    /// kept) into the ellipsoid of the same map: every bit of the ellipsoid is material, but
    /// its particle layers are 1.6 spacings apart along x, so the particle cover misses the
    /// judge points between them. The material cover does not; a body that fails to reach
    /// the ellipsoid's tips (the sphere's particles merely moved) still loses it.
    #[test]
    fn the_material_fill_sees_a_stretched_body_as_whole() {
        let (mesh, grid) = sphere();
        let rest = particles_in(&mesh, &grid, 2, None).positions;
        let across = 1.6f64.sqrt().recip();
        let stretch = Matrix3::from_diagonal(&Vector3::new(1.6, across, across));
        let ellipsoid = TriMesh {
            vertices: mesh.vertices.iter().map(|v| stretch * v).collect(),
            triangles: mesh.triangles.clone(),
        };
        let target_lattice = particles_in(&ellipsoid, &grid, 2, None).positions;
        let judge = Judge::new(&ellipsoid, 0.5, &target_lattice);
        let stretched: Vec<_> = rest.iter().map(|p| stretch * p).collect();
        let ones = vec![1.0; rest.len()];
        let q = judge.judge(&rest, &stretched, &ones);
        assert!(q.fill < 0.9, "{q:?}");
        assert!(q.material_fill > 0.97, "{q:?}");
        let unmoved = judge.judge(&rest, &rest, &ones);
        assert!(unmoved.material_fill < 0.8, "{unmoved:?}");
    }

    #[test]
    fn close_neighbours_are_counted() {
        let (mesh, grid) = sphere();
        let mut lattice = particles_in(&mesh, &grid, 2, None).positions;
        assert_eq!(close_neighbour_share(&lattice, 0.5), 0.0);
        // Move particle 1 next to particle 0: both now have a close neighbour.
        lattice[1] = lattice[0] + Vector3::new(0.2, 0.0, 0.0);
        let share = close_neighbour_share(&lattice, 0.5);
        assert!(
            (share - 2.0 / lattice.len() as f64).abs() < 1e-15,
            "{share}"
        );
    }

    #[test]
    fn j_statistics() {
        let (mesh, grid) = sphere();
        let lattice = particles_in(&mesh, &grid, 2, None).positions;
        let judge = Judge::new(&mesh, 0.5, &lattice);
        let mut j = vec![1.0; lattice.len()];
        j[0] = -0.5;
        j[1] = 2.0;
        let q = judge.judge(&lattice, &lattice, &j);
        assert_eq!((q.min_j, q.max_j), (-0.5, 2.0));
        assert!((q.inverted - 1.0 / lattice.len() as f64).abs() < 1e-15);
    }
}
