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
/// not before.
pub fn fit_to_field(
    vertices: &mut [Vector3<f64>],
    mesh: &FitMesh,
    field: &FillField,
    reach: f64,
    strength: f64,
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
