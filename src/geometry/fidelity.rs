//! How true a written surface is to a reference surface, and whether it folds.
//!
//! - [`fidelity`]: for every face of the surface, the angle between its normal and the
//!   reference's normal at the closest point of the reference (the normal of the reference
//!   face that point lies on), and its distance to the reference: area-weighted means, the
//!   share of the area beyond 20 degrees, and the largest distance over faces and vertices.
//!   Distances are in particle spacings, what a viewer compares a bump with.
//! - [`fold_share`]: the share of faces whose normal turns more than 60 degrees from the mean
//!   normal of their edge neighbours: a crease or a fold, not a smooth bend; and
//!   [`crease_share`], the same past 30 degrees, where a rendered surface already shows a
//!   crack-like line (measured on the rebuilt surface, which has no source mesh to fold from).
//!
//! The closest-point queries go through parry's bounding-volume hierarchy (`parry3d-f64`,
//! the dimforge collision library beside nalgebra).

use super::mesh::TriMesh;
use nalgebra::Vector3;
use parry3d_f64::math::Vector as PVector;
use parry3d_f64::query::PointQueryWithLocation;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// Normals farther than this from the reference's count as visibly wrong.
pub const OFF_DEGREES: f64 = 20.0;
/// A face whose normal turns more than this from its neighbours' mean is a fold.
pub const FOLD_DEGREES: f64 = 60.0;
/// A face whose normal turns more than this from its neighbours' mean shows as a crease when
/// rendered (docs/lab/2026-12-08-surfaces-record.md, "Creases mid-shot"): a smooth surface marched at the particle
/// spacing turns by a few degrees from face to face.
pub const CREASE_DEGREES: f64 = 30.0;

/// A reference surface ready for closest-point queries.
pub struct Reference {
    mesh: parry3d_f64::shape::TriMesh,
    normals: Vec<Vector3<f64>>,
}

impl Reference {
    /// `None` for a mesh without a triangle of non-zero area.
    pub fn new(mesh: &TriMesh) -> Option<Reference> {
        let vertices: Vec<PVector> = mesh
            .vertices
            .iter()
            .map(|v| PVector::new(v.x, v.y, v.z))
            .collect();
        let normals = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
                (b - a)
                    .cross(&(c - a))
                    .try_normalize(0.0)
                    .unwrap_or_default()
            })
            .collect::<Vec<_>>();
        if normals.iter().all(|n| *n == Vector3::zeros()) {
            return None;
        }
        let mesh = parry3d_f64::shape::TriMesh::new(vertices, mesh.triangles.clone()).ok()?;
        Some(Reference { mesh, normals })
    }

    /// The distance from `p` to the reference surface.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        (self.closest(p).0 - p).norm()
    }

    /// The closest point of the reference to `p`, and the normal there.
    pub fn closest(&self, p: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let (proj, (face, _)) = self
            .mesh
            .project_local_point_and_get_location(PVector::new(p.x, p.y, p.z), false);
        let q = Vector3::new(proj.point.x, proj.point.y, proj.point.z);
        (q, self.normals[face as usize])
    }
}

/// What [`fidelity`] measures.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fidelity {
    /// Area-weighted mean angle between the faces' normals and the reference's, degrees.
    pub mean_normal_deg: f64,
    /// Share of the area whose normal is more than [`OFF_DEGREES`] off.
    pub off_share: f64,
    /// Area-weighted mean distance of the faces' centres to the reference, in spacings.
    pub mean_distance: f64,
    /// Largest distance of a face centre or a vertex to the reference, in spacings.
    pub max_distance: f64,
}

/// Per face of the surface (`vertices`, `triangles`), in face order: its area, the angle in
/// degrees between its normal and `reference`'s at the closest point to its centre, and that
/// point's distance from the centre (zeros for a face of no area). What [`fidelity`] sums.
pub fn face_deviations(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    reference: &Reference,
) -> Vec<(f64, f64, f64)> {
    triangles
        .par_iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i]);
            let cross = (b - a).cross(&(c - a));
            let area = 0.5 * cross.norm();
            if area == 0.0 {
                return (0.0, 0.0, 0.0);
            }
            let centre = (a + b + c) / 3.0;
            let (q, n_ref) = reference.closest(&centre);
            let cos = (cross / (2.0 * area)).dot(&n_ref).clamp(-1.0, 1.0);
            (area, cos.acos().to_degrees(), (centre - q).norm())
        })
        .collect()
}

/// How true the surface (`vertices`, `triangles`) is to `reference`; `spacing` is the
/// particle spacing in the same units. The same for any thread count.
pub fn fidelity(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    reference: &Reference,
    spacing: f64,
) -> Fidelity {
    // Sums are taken in face order below.
    let faces = face_deviations(vertices, triangles, reference);
    let vertex_max = vertices
        .par_iter()
        .map(|v| (v - reference.closest(v).0).norm())
        .reduce(|| 0.0, f64::max);
    let total: f64 = faces.iter().map(|f| f.0).sum();
    let total = total.max(f64::MIN_POSITIVE);
    let weighted = |pick: &dyn Fn(&(f64, f64, f64)) -> f64| {
        faces.iter().map(|f| f.0 * pick(f)).sum::<f64>() / total
    };
    Fidelity {
        mean_normal_deg: weighted(&|f| f.1),
        off_share: weighted(&|f| if f.1 > OFF_DEGREES { 1.0 } else { 0.0 }),
        mean_distance: weighted(&|f| f.2) / spacing,
        max_distance: faces.iter().map(|f| f.2).fold(vertex_max, f64::max) / spacing,
    }
}

/// [`fidelity`] of a [`TriMesh`].
pub fn mesh_fidelity(mesh: &TriMesh, reference: &Reference, spacing: f64) -> Fidelity {
    let triangles: Vec<[usize; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| i as usize))
        .collect();
    fidelity(&mesh.vertices, &triangles, reference, spacing)
}

/// The triangles sharing an edge with each triangle, in triangle order.
pub fn edge_neighbours(triangles: &[[usize; 3]]) -> Vec<Vec<usize>> {
    let mut by_edge: FxHashMap<(usize, usize), Vec<usize>> = FxHashMap::default();
    for (f, t) in triangles.iter().enumerate() {
        for e in 0..3 {
            let (u, v) = (t[e], t[(e + 1) % 3]);
            by_edge.entry((u.min(v), u.max(v))).or_default().push(f);
        }
    }
    triangles
        .iter()
        .enumerate()
        .map(|(f, t)| {
            (0..3)
                .flat_map(|e| {
                    let (u, v) = (t[e], t[(e + 1) % 3]);
                    by_edge[&(u.min(v), u.max(v))].iter().copied()
                })
                .filter(|&g| g != f)
                .collect()
        })
        .collect()
}

/// Share of the faces (of non-zero area, with a neighbour) whose normal turns more than
/// [`FOLD_DEGREES`] from the mean unit normal of the faces sharing an edge with them
/// (`neighbours`: [`edge_neighbours`] of `triangles`).
pub fn fold_share(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    neighbours: &[Vec<usize>],
) -> f64 {
    turned_share(vertices, triangles, neighbours, FOLD_DEGREES)
}

/// [`fold_share`] past [`CREASE_DEGREES`], of a [`TriMesh`].
pub fn crease_share(mesh: &TriMesh) -> f64 {
    let triangles: Vec<[usize; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| i as usize))
        .collect();
    let neighbours = edge_neighbours(&triangles);
    turned_share(&mesh.vertices, &triangles, &neighbours, CREASE_DEGREES)
}

/// Share of the faces whose normal turns more than `degrees` from their edge neighbours' mean.
fn turned_share(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    neighbours: &[Vec<usize>],
    degrees: f64,
) -> f64 {
    let turned = turned_faces(vertices, triangles, neighbours, degrees);
    let counted = turned.iter().filter(|t| t.is_some()).count();
    let count = turned.iter().filter(|t| **t == Some(true)).count();
    count as f64 / counted.max(1) as f64
}

/// Per face: whether its normal turns more than `degrees` from the mean unit normal of the
/// faces sharing an edge with it (`None`: no area, or no neighbour with one).
pub fn turned_faces(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    neighbours: &[Vec<usize>],
    degrees: f64,
) -> Vec<Option<bool>> {
    let normals: Vec<Option<Vector3<f64>>> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i]);
            (b - a).cross(&(c - a)).try_normalize(0.0)
        })
        .collect();
    let cos_turn = degrees.to_radians().cos();
    neighbours
        .iter()
        .enumerate()
        .map(|(f, near)| {
            let n = normals[f]?;
            let mean: Vector3<f64> = near.iter().filter_map(|&g| normals[g]).sum();
            let mean = mean.try_normalize(0.0)?;
            Some(n.dot(&mean) < cos_turn)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::assets;

    #[test]
    fn a_surface_measured_against_itself_is_exact() {
        let sphere = assets::uv_sphere(1.0, 24, 48, |_, _| 1.0);
        let reference = Reference::new(&sphere).unwrap();
        let f = mesh_fidelity(&sphere, &reference, 0.1);
        assert!(f.mean_normal_deg < 1e-6 && f.off_share == 0.0, "{f:?}");
        assert!(f.max_distance < 1e-9, "{f:?}");
    }

    #[test]
    fn a_shifted_surface_is_that_far_and_a_flipped_one_is_off() {
        let sphere = assets::uv_sphere(1.0, 24, 48, |_, _| 1.0);
        let reference = Reference::new(&sphere).unwrap();
        let mut bigger = sphere.clone();
        bigger.vertices.iter_mut().for_each(|v| *v *= 1.05);
        let f = mesh_fidelity(&bigger, &reference, 0.01);
        // 0.05 out, give or take the facets: about 5 spacings of 0.01.
        assert!((f.mean_distance - 5.0).abs() < 0.6, "{f:?}");
        let mut flipped = sphere.clone();
        flipped.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        let f = mesh_fidelity(&flipped, &reference, 0.01);
        assert!(f.mean_normal_deg > 170.0 && f.off_share > 0.99, "{f:?}");
    }

    #[test]
    fn a_crease_folds_and_a_sphere_does_not() {
        let sphere = assets::uv_sphere(1.0, 24, 48, |_, _| 1.0);
        let tris: Vec<[usize; 3]> = sphere
            .triangles
            .iter()
            .map(|t| t.map(|i| i as usize))
            .collect();
        assert_eq!(
            fold_share(&sphere.vertices, &tris, &edge_neighbours(&tris)),
            0.0
        );
        // A flat sheet with one vertex dragged past its neighbours: the faces it drags over
        // turn upside down, a fold.
        let n = 10;
        let mut sheet: Vec<Vector3<f64>> = (0..n * n)
            .map(|i| Vector3::new((i % n) as f64, (i / n) as f64, 0.0))
            .collect();
        let mut tris = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x;
                tris.extend([[v, v + 1, v + n + 1], [v, v + n + 1, v + n]]);
            }
        }
        let near = edge_neighbours(&tris);
        assert_eq!(fold_share(&sheet, &tris, &near), 0.0);
        sheet[5 * n + 5].x += 1.6;
        let share = fold_share(&sheet, &tris, &near);
        assert!(share > 0.0 && share < 0.1, "{share}");
    }

    /// A sheet bent sharply along a line creases there and only there; bent gently, nowhere.
    #[test]
    fn a_sharp_bend_creases_and_a_gentle_one_does_not() {
        let sheet = |bend_deg: f64| {
            let n = 12;
            let slope = bend_deg.to_radians().tan();
            let vertices = (0..n * n)
                .map(|i| {
                    let (x, y) = ((i % n) as f64, (i / n) as f64);
                    Vector3::new(x, y, (x - 6.0).max(0.0) * slope)
                })
                .collect();
            let mut triangles = Vec::new();
            for y in 0..n - 1 {
                for x in 0..n - 1 {
                    let v = (y * n + x) as u32;
                    let m = n as u32;
                    triangles.extend([[v, v + 1, v + m + 1], [v, v + m + 1, v + m]]);
                }
            }
            TriMesh {
                vertices,
                triangles,
            }
        };
        assert_eq!(crease_share(&sheet(0.0)), 0.0);
        assert_eq!(crease_share(&sheet(20.0)), 0.0);
        // Only faces along the bend, in the two columns that meet there (2 of 11 at most); a
        // face with one neighbour across a clean bend sees a third of it, so only a bend
        // past about 70 degrees (or a jagged crack) counts.
        let share = crease_share(&sheet(80.0));
        assert!(share > 0.0 && share <= 2.0 / 11.0, "{share}");
        assert_eq!(crease_share(&sheet(60.0)), 0.0);
    }
}
