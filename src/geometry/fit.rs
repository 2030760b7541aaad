//! A carried surface fitted to the body's own boundary, as a DCC shrink-wrap does: each vertex
//! moves along its normal to the nearest crossing of the fill field's surface level within a
//! reach, and the moves are smoothed over the mesh so that its parameterization (UVs, the
//! spacing of its vertices) holds.

use super::surface::FillField;
use nalgebra::Vector3;
use rayon::prelude::*;

/// How far (in particle spacings) a vertex looks along its normal for the body's boundary.
pub const REACH_SPACINGS: f64 = 3.0;
/// Rounds of smoothing the moves over each vertex's neighbours.
pub const SMOOTHING_ROUNDS: usize = 2;

/// Rounds of the fold guard: a move that folds a face the unfitted surface did not fold is
/// halved, round after round, and dropped after the last.
pub const GUARD_ROUNDS: usize = 6;

/// The mesh a fit moves: its triangles, each triangle's edge neighbours, and each vertex's
/// ([`vertex_neighbours`]); the topology is fixed, so they are found once.
pub struct FitMesh<'a> {
    pub triangles: &'a [[usize; 3]],
    pub faces: &'a [Vec<usize>],
    pub rings: &'a [Vec<usize>],
}

/// `vertices` (sim units, of `mesh`) moved by `strength` (0 to 1) of their way to the body's
/// boundary in `field`, looking up to `reach` along each vertex normal; no face folds that did
/// not before. With `volume` (a closed mesh), the boundary is taken one even distance farther
/// out, the one that makes the fitted mesh enclose `volume`: the field's level lies a thin
/// layer inside the body, and the rebuilt surface is put back to the body's volume the same way.
pub fn fit_to_field(
    vertices: &mut [Vector3<f64>],
    mesh: &FitMesh,
    field: &FillField,
    reach: f64,
    strength: f64,
    volume: Option<f64>,
) {
    if strength <= 0.0 || vertices.is_empty() {
        return;
    }
    let (triangles, faces, neighbours) = (mesh.triangles, mesh.faces, mesh.rings);
    let normals = super::mesh::area_weighted_normals(vertices, triangles.iter().copied());
    let step = 0.25 * field.h;
    let mut moves: Vec<Vector3<f64>> = vertices
        .par_iter()
        .zip(&normals)
        .map(|(x, n)| crossing(field, x, n, reach, step).map_or(Vector3::zeros(), |t| t * n))
        .collect();
    for _ in 0..SMOOTHING_ROUNDS {
        moves = (0..vertices.len())
            .map(|i| {
                let ring = &neighbours[i];
                let sum: Vector3<f64> = ring.iter().map(|&j| moves[j]).sum();
                (moves[i] + sum) / (1 + ring.len()) as f64
            })
            .collect();
    }
    if let Some(volume) = volume {
        let fitted = super::mesh::TriMesh::indexed(
            vertices.iter().zip(&moves).map(|(x, d)| x + d).collect(),
            triangles,
        );
        let (current, area) = (fitted.signed_volume(), fitted.surface_area());
        if current > 0.0 && area > 0.0 && volume > 0.0 {
            let out = (volume - current) / area;
            for (d, n) in moves.iter_mut().zip(&normals) {
                *d += out * n;
            }
        }
    }
    let unfitted = vertices.to_vec();
    let folded_before = turned(&unfitted, triangles, faces);
    let mut share = vec![strength; vertices.len()];
    for round in 0..=GUARD_ROUNDS {
        for ((x, x0), (d, s)) in vertices
            .iter_mut()
            .zip(&unfitted)
            .zip(moves.iter().zip(&share))
        {
            *x = x0 + *s * d;
        }
        let folded = turned(vertices, triangles, faces);
        let mut any = false;
        for (f, t) in triangles.iter().enumerate() {
            if folded[f] && !folded_before[f] {
                any = true;
                for &v in t {
                    share[v] = if round == GUARD_ROUNDS {
                        0.0
                    } else {
                        0.5 * share[v]
                    };
                }
            }
        }
        if !any {
            return;
        }
    }
    for ((x, x0), (d, s)) in vertices
        .iter_mut()
        .zip(&unfitted)
        .zip(moves.iter().zip(&share))
    {
        *x = x0 + *s * d;
    }
}

/// Per face: whether it folds ([`super::fidelity::FOLD_DEGREES`]).
fn turned(vertices: &[Vector3<f64>], triangles: &[[usize; 3]], faces: &[Vec<usize>]) -> Vec<bool> {
    let degrees = super::fidelity::FOLD_DEGREES;
    super::fidelity::turned_faces(vertices, triangles, faces, degrees)
        .into_iter()
        .map(|t| t == Some(true))
        .collect()
}

/// The distance along unit normal `n` from `x` to the nearest crossing of the field's level,
/// within `reach` either way (`None`: no crossing there, or no normal). Each sample is taken
/// once: the two directions keep their last one.
fn crossing(
    field: &FillField,
    x: &Vector3<f64>,
    n: &Vector3<f64>,
    reach: f64,
    step: f64,
) -> Option<f64> {
    if n.norm_squared() == 0.0 {
        return None;
    }
    let level = |t: f64| field.sample(&(x + t * n)) - FillField::LEVEL;
    let at0 = level(0.0);
    let mut last = [at0, at0];
    let mut t = 0.0;
    while t < reach {
        let next = t + step;
        for (k, sign) in [1.0, -1.0].into_iter().enumerate() {
            let (fa, fb) = (last[k], level(sign * next));
            if (fa > 0.0) != (fb > 0.0) {
                return Some(sign * (t + fa / (fa - fb) * step));
            }
            last[k] = fb;
        }
        t = next;
    }
    None
}

/// Each vertex's neighbours along the triangles' edges.
pub fn vertex_neighbours(n: usize, triangles: &[[usize; 3]]) -> Vec<Vec<usize>> {
    let mut out = vec![Vec::new(); n];
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if !out[a].contains(&b) {
                out[a].push(b);
            }
            if !out[b].contains(&a) {
                out[b].push(a);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::fidelity::{edge_neighbours, fold_share};

    /// A sphere's mesh fitted to a body stretched to an ellipsoid twice as long (3 x 0.7 x 0.7
    /// its radius): it reaches the body's ends, keeps the body's volume, and no face folds
    /// (the source folds none).
    #[test]
    fn a_stretched_body_is_reached_without_folds_and_at_its_volume() {
        let spacing: f64 = 0.05;
        let (a, b): (f64, f64) = (1.5, 0.55);
        let mut particles = Vec::new();
        let n = (a / spacing).ceil() as i64;
        for i in -n..=n {
            for j in -n..=n {
                for k in -n..=n {
                    let p = Vector3::new(i as f64, j as f64, k as f64) * spacing;
                    if (p.x / a).powi(2) + (p.y / b).powi(2) + (p.z / b).powi(2) <= 1.0 {
                        particles.push(p);
                    }
                }
            }
        }
        let volumes = vec![spacing.powi(3); particles.len()];
        let field = crate::geometry::surface::fill_field(&particles, &volumes, spacing).unwrap();
        // The sphere carried to the stretched shape by the particles' mean stretch, short of
        // the ends, as a binding leaves it.
        let sphere = crate::geometry::assets::uv_sphere(1.0, 24, 48, |_, _| 1.0);
        let triangles: Vec<[usize; 3]> = sphere
            .triangles
            .iter()
            .map(|t| t.map(|v| v as usize))
            .collect();
        let mut vertices: Vec<Vector3<f64>> = (sphere.vertices.iter())
            .map(|v| Vector3::new(0.85 * a * v.x, 0.85 * b * v.y, 0.85 * b * v.z))
            .collect();
        let faces = edge_neighbours(&triangles);
        let rings = vertex_neighbours(vertices.len(), &triangles);
        let mesh = FitMesh {
            triangles: &triangles,
            faces: &faces,
            rings: &rings,
        };
        let body = 4.0 / 3.0 * std::f64::consts::PI * a * b * b;
        assert_eq!(fold_share(&vertices, &triangles, &faces), 0.0);
        fit_to_field(
            &mut vertices,
            &mesh,
            &field,
            REACH_SPACINGS * spacing * 4.0,
            1.0,
            Some(body),
        );
        assert_eq!(
            fold_share(&vertices, &triangles, &faces),
            0.0,
            "a face folds"
        );
        let volume =
            crate::geometry::mesh::TriMesh::indexed(vertices.clone(), &triangles).signed_volume();
        assert!(
            (volume / body - 1.0).abs() < 0.03,
            "volume {volume} against {body}"
        );
        let reach = vertices.iter().map(|v| v.x).fold(f64::MIN, f64::max);
        assert!(
            (reach - a).abs() < 1.5 * spacing,
            "the end at {reach}, the body's at {a}"
        );
    }
}
