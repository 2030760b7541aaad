//! What an artist sees of a surface against its target: its silhouettes and its tips.
//!
//! The judge's fill weighs volume, and a leg or an ear is little volume: a horse without legs
//! still fills 0.88 of its target. These measures weigh what a render shows.
//!
//! - **Silhouette IoU**, seen along each axis: both meshes' triangles are projected onto the
//!   plane across the axis and rasterized ([`SILHOUETTE_PIXELS`] along the longer side of the
//!   two meshes' box); the IoU of the two covered pixel sets. A triangle covers the pixels
//!   whose centres lie in it, edges included, so a closed mesh's silhouette is its shadow.
//! - **Tip reach**: the target's extremities, the [`TIP_SHARE`] of its vertices farthest
//!   along a direction (up, +y, for the topmost: ears, horns, a head), and the distance from
//!   each to the surface; its 90th percentile over them, as a share of the target's size (its
//!   bounding box's diagonal). Reported for up, and as the worst of the six axis directions
//!   (legs below, a tail behind).

use super::fidelity::Reference;
use super::mesh::{Aabb, TriMesh};
use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Pixels along the longer side of the silhouettes' square frame.
pub const SILHOUETTE_PIXELS: usize = 256;

/// The share of the target's vertices that make an extremity.
pub const TIP_SHARE: f64 = 0.03;

/// The percentile of the tip distances reported.
pub const TIP_PERCENTILE: f64 = 0.9;

/// How a surface looks against its target ([module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Likeness {
    /// The silhouettes' IoU seen along x, y and z.
    pub silhouette_iou: [f64; 3],
    /// The tips' distance to the surface (90th percentile) as a share of the target's size,
    /// along each of [`DIRECTIONS`]: `tips[2]` are the topmost.
    pub tips: [f64; 6],
}

/// The directions of [`Likeness::tips`], as the report names them.
pub const DIRECTIONS: [&str; 6] = ["+x", "-x", "+y", "-y", "+z", "-z"];

impl Likeness {
    /// The least of the three views' IoU.
    pub fn min_silhouette_iou(&self) -> f64 {
        self.silhouette_iou
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }

    /// The topmost tips' reach (up is +y).
    pub fn top_tips(&self) -> f64 {
        self.tips[2]
    }

    /// The farthest direction's tips: their reach and the direction's name.
    pub fn worst_tips(&self) -> (f64, &'static str) {
        let d = (0..6)
            .max_by(|&a, &b| self.tips[a].total_cmp(&self.tips[b]))
            .unwrap_or(2);
        (self.tips[d], DIRECTIONS[d])
    }
}

/// `surface` against `target` (both in the same units and frame).
pub fn likeness(surface: &TriMesh, target: &TriMesh) -> Option<Likeness> {
    let reference = Reference::new(surface)?;
    let frame = surface.bounds().union(&target.bounds());
    let silhouette_iou = [0, 1, 2].map(|axis| {
        let a = silhouette(surface, &frame, axis);
        let b = silhouette(target, &frame, axis);
        iou(&a, &b)
    });
    let size = target.bounds().extent().norm();
    let tips = [0, 1, 2, 3, 4, 5].map(|d| {
        let mut along = Vector3::zeros();
        along[d / 2] = if d % 2 == 0 { 1.0 } else { -1.0 };
        tip_reach(target, &reference, &along) / size
    });
    Some(Likeness {
        silhouette_iou,
        tips,
    })
}

/// The pixels of a square frame over `frame`'s box seen along `axis` that `mesh` covers, row
/// by row.
pub fn silhouette(mesh: &TriMesh, frame: &Aabb, axis: usize) -> Vec<bool> {
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let side = frame.extent()[u]
        .max(frame.extent()[v])
        .max(f64::MIN_POSITIVE);
    let pixel = side / SILHOUETTE_PIXELS as f64;
    let n = SILHOUETTE_PIXELS;
    // Pixel coordinates: the frame's corner at 0, one pixel per unit.
    let to_pixels = |p: &Vector3<f64>| {
        Vector2::new((p[u] - frame.min[u]) / pixel, (p[v] - frame.min[v]) / pixel)
    };
    let rows: Vec<Vec<bool>> = (0..n)
        .into_par_iter()
        .map(|row| {
            let y = row as f64 + 0.5;
            let mut covered = vec![false; n];
            for t in &mesh.triangles {
                let [a, b, c] = mesh.corners(t).map(|p| to_pixels(&p));
                if y < a.y.min(b.y).min(c.y) || y > a.y.max(b.y).max(c.y) {
                    continue;
                }
                cover_row(&[a, b, c], y, &mut covered);
            }
            covered
        })
        .collect();
    rows.concat()
}

/// Marks the pixels of the row at height `y` whose centres lie in the triangle (edges in).
fn cover_row(t: &[Vector2<f64>; 3], y: f64, covered: &mut [bool]) {
    // The triangle's span on the line: where its edges cross it.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for k in 0..3 {
        let (p, q) = (t[k], t[(k + 1) % 3]);
        if (p.y - y) * (q.y - y) > 0.0 {
            continue;
        }
        let xs = if p.y == q.y {
            [p.x, q.x]
        } else {
            let x = p.x + (y - p.y) / (q.y - p.y) * (q.x - p.x);
            [x, x]
        };
        lo = lo.min(xs[0].min(xs[1]));
        hi = hi.max(xs[0].max(xs[1]));
    }
    if lo > hi {
        return;
    }
    let first = (lo - 0.5).ceil().max(0.0) as usize;
    let last = ((hi - 0.5).floor()).min(covered.len() as f64 - 1.0);
    if last < 0.0 {
        return;
    }
    for c in covered.iter_mut().take(last as usize + 1).skip(first) {
        *c = true;
    }
}

/// The IoU of two pixel sets of one frame (1 when both are empty).
pub fn iou(a: &[bool], b: &[bool]) -> f64 {
    let both = a.iter().zip(b).filter(|(a, b)| **a && **b).count();
    let either = a.iter().zip(b).filter(|(a, b)| **a || **b).count();
    if either == 0 {
        1.0
    } else {
        both as f64 / either as f64
    }
}

/// The 90th percentile of the distances from `target`'s tips along `along` (the
/// [`TIP_SHARE`] of its vertices farthest that way) to `surface`.
pub fn tip_reach(target: &TriMesh, surface: &Reference, along: &Vector3<f64>) -> f64 {
    let mut order: Vec<usize> = (0..target.vertices.len()).collect();
    order.sort_by(|&a, &b| {
        let (pa, pb) = (target.vertices[a].dot(along), target.vertices[b].dot(along));
        pb.total_cmp(&pa).then(a.cmp(&b))
    });
    let count = ((TIP_SHARE * order.len() as f64).ceil() as usize).clamp(1, order.len().max(1));
    let mut distances: Vec<f64> = order[..count.min(order.len())]
        .par_iter()
        .map(|&i| surface.distance(&target.vertices[i]))
        .collect();
    percentile(&mut distances, TIP_PERCENTILE)
}

/// The `p` quantile of `values` (nearest rank; 0 when empty).
fn percentile(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    let rank = ((p * values.len() as f64).ceil() as usize).clamp(1, values.len());
    values[rank - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A UV sphere of `radius` about `centre`.
    fn sphere(centre: Vector3<f64>, radius: f64) -> TriMesh {
        let (rings, segments) = (48usize, 96usize);
        let mut vertices = vec![centre + Vector3::new(0.0, radius, 0.0)];
        for i in 1..rings {
            let t = std::f64::consts::PI * i as f64 / rings as f64;
            for j in 0..segments {
                let p = std::f64::consts::TAU * j as f64 / segments as f64;
                let d = Vector3::new(t.sin() * p.cos(), t.cos(), t.sin() * p.sin());
                vertices.push(centre + radius * d);
            }
        }
        vertices.push(centre - Vector3::new(0.0, radius, 0.0));
        let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
        let last = (vertices.len() - 1) as u32;
        let mut triangles = Vec::new();
        for j in 0..segments {
            triangles.push([0, ring(1, j + 1), ring(1, j)]);
            triangles.push([last, ring(rings - 1, j), ring(rings - 1, j + 1)]);
        }
        for i in 1..rings - 1 {
            for j in 0..segments {
                let (a, b) = (ring(i, j), ring(i, j + 1));
                let (c, d) = (ring(i + 1, j), ring(i + 1, j + 1));
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
        }
        TriMesh {
            vertices,
            triangles,
        }
    }

    #[test]
    fn a_shape_is_its_own_likeness() {
        let s = sphere(Vector3::zeros(), 1.0);
        let l = likeness(&s, &s).unwrap();
        assert_eq!(l.silhouette_iou, [1.0; 3]);
        assert!(l.worst_tips().0 < 1e-12, "{l:?}");
    }

    #[test]
    fn shifted_disks_have_the_iou_of_two_circles() {
        // Two unit spheres a radius apart along x: seen along y or z their silhouettes are
        // unit disks one radius apart (IoU from the lens area); along x they coincide.
        let a = sphere(Vector3::zeros(), 1.0);
        let b = sphere(Vector3::new(1.0, 0.0, 0.0), 1.0);
        let l = likeness(&a, &b).unwrap();
        let d: f64 = 1.0;
        let lens = 2.0 * (d / 2.0).acos() - (d / 2.0) * (4.0 - d * d).sqrt();
        let expected = lens / (2.0 * std::f64::consts::PI - lens);
        assert!((l.silhouette_iou[0] - 1.0).abs() < 0.01, "{l:?}");
        for view in [1, 2] {
            assert!(
                (l.silhouette_iou[view] - expected).abs() < 0.01,
                "{l:?} {expected}"
            );
        }
        // b's tips along +x are a radius beyond a's surface; its other tips near a's.
        let (worst, direction) = l.worst_tips();
        assert_eq!(direction, "+x");
        let size = b.bounds().extent().norm();
        assert!((worst * size - 1.0).abs() < 0.05, "{l:?}");
    }

    #[test]
    fn a_missing_ear_shows_in_the_top_tips_and_not_in_the_others() {
        // The target: a head with an ear on top; the surface: the head alone.
        let head = sphere(Vector3::zeros(), 1.0);
        let ear = sphere(Vector3::new(0.0, 1.6, 0.0), 0.3);
        let mut target = head.clone();
        let offset = target.vertices.len() as u32;
        target.vertices.extend(&ear.vertices);
        target
            .triangles
            .extend(ear.triangles.iter().map(|t| t.map(|i| i + offset)));
        let l = likeness(&head, &target).unwrap();
        let size = target.bounds().extent().norm();
        assert!(l.top_tips() * size > 0.6, "{l:?}");
        assert_eq!(l.worst_tips().1, "+y");
        assert!(
            l.silhouette_iou[1] > 0.99,
            "seen from above the ear hides in the head: {l:?}"
        );
        assert!(
            l.silhouette_iou[0] < 0.97 && l.silhouette_iou[2] < 0.97,
            "{l:?}"
        );
    }
}
