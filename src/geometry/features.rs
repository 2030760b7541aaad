//! Sharp edges and corners on the rebuilt surface: the source's tangent planes carried by the
//! particles near its surface, and the rebuilt surface's vertices moved onto them.
//!
//! A field marched on a lattice chamfers every sharp edge it crosses, whatever the field
//! (docs/geometry.md, "Sharp edges at rest": the exact distance of fandisk marched at the
//! particle spacing still measures 4.8 degrees). Dual contouring keeps edges by placing each
//! vertex where the tangent planes around it meet (Ju et al. 2002, "Dual contouring of
//! Hermite data"). Here the planes are not sampled from the field but carried by the
//! material: each particle near the source's surface keeps the source's closest point and
//! normal there, in its rest frame, and on every frame they follow the deformation fitted to
//! its neighbourhood (`q = x + F o`, `n ~ F^-T n0`), fading out as that strains. At rest they
//! are the source's own planes.
//!
//! [`sharpen`] keeps the marched mesh's connectivity (one closed manifold shell, as cleaned):
//! each vertex solves the least squares of the planes around it (the quadric error function
//! of dual contouring), moving only along the directions the planes constrain: a vertex on a
//! flat face moves along its normal onto the face, one near an edge onto the edge line, one
//! near a corner onto the corner. The triangles that a move leaves as slivers along an edge
//! are then collapsed or flipped by cleaning's own steps ([`super::cleanup::tidy`]), and the
//! two alternate for [`ROUNDS`] rounds.

use super::cleanup::tidy;
use super::fidelity::Reference;
use super::mesh::TriMesh;
use super::neighbourhood::RestNeighbourhood;
use super::point_grid::PointGrid;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

/// Particles deeper than this many spacings inside the source carry no plane.
pub const PLANE_DEPTH: f64 = 1.5;
/// A vertex takes the planes whose carried point lies within this many spacings, weighted by
/// `(1 - (d / r)^2)^2`.
const SNAP_RADIUS: f64 = 2.0;
/// ... and only the planes that pass within this many spacings of it (the kernels round an
/// edge by up to about a spacing; a vertex on one face farther than this from the other
/// face's plane does not feel it).
const SNAP_REACH: f64 = 2.0;
/// Directions whose weight is below this share of the largest are left free: the spread of
/// normals over a curved face is not an edge.
const RANK_SHARE: f64 = 0.1;
/// A vertex moves at most this many spacings in one round.
const MAX_MOVE: f64 = 1.0;
/// Rounds of snapping and tidying (docs/geometry.md, "Sharp edges": fandisk's frame 1 measures
/// 2.08, 1.89 and 1.84 degrees after 1, 2 and 3).
pub const ROUNDS: usize = 3;

/// Planes fade out with the strain of the material around the particle that carries them:
/// weight `(1 - e / FADE_STRAIN)^2` for the Green strain `e = |F^T F - I| / 2` (Frobenius) of
/// its neighbourhood's fitted deformation, none beyond; and the same with the fit's rms
/// residual against [`FADE_RESIDUAL`] spacings (neighbours that parted or mixed). The
/// particle's own `F` cannot carry them: the plastic control folds the flow into the rest
/// shape and elasticity takes `F` back toward a rotation, so after a flow `F` no longer maps
/// the source's planes to the body's boundary (docs/geometry.md, "Sharp edges").
pub const FADE_STRAIN: f64 = 0.03;
pub const FADE_RESIDUAL: f64 = 0.1;

fn fade(x: f64, limit: f64) -> f64 {
    (1.0 - x / limit).max(0.0).powi(2)
}

/// The Green strain's Frobenius norm of `f`.
fn green_strain(f: &Matrix3<f64>) -> f64 {
    0.5 * (f.transpose() * f - Matrix3::identity()).norm()
}

/// The source's surface as the particles near it carry it, made once at rest.
pub struct SourcePlanes {
    planes: Vec<PlaneParticle>,
    /// Every particle at rest (the neighbourhoods are fitted against them).
    rest: Vec<Vector3<f64>>,
}

/// A particle within [`PLANE_DEPTH`] spacings of the source's surface: `offset` from it to
/// the source's closest point and the source's unit normal there (rest frame), its rest
/// neighbours and their rest offsets' inverse Gram matrix (for the fit).
struct PlaneParticle {
    particle: u32,
    offset: Vector3<f64>,
    normal: Vector3<f64>,
    neighbourhood: RestNeighbourhood,
}

impl SourcePlanes {
    /// For particles at rest at `rest` (`spacing` apart) inside `surface`, all in one frame.
    pub fn new(surface: &TriMesh, rest: &[Vector3<f64>], spacing: f64) -> SourcePlanes {
        let Some(reference) = Reference::new(surface) else {
            return SourcePlanes {
                planes: Vec::new(),
                rest: rest.to_vec(),
            };
        };
        let radius = super::neighbourhood::FIT_SPACINGS * spacing;
        let grid = PointGrid::new(rest, radius);
        let planes = (0..rest.len())
            .into_par_iter()
            .filter_map(|i| {
                let x = rest[i];
                let (q, normal) = reference.closest(&x);
                if (q - x).norm() >= PLANE_DEPTH * spacing {
                    return None;
                }
                // A particle whose neighbours do not span the space cannot be fitted.
                let neighbourhood = RestNeighbourhood::new(rest, &grid, i, radius)?;
                Some(PlaneParticle {
                    particle: i as u32,
                    offset: q - x,
                    normal,
                    neighbourhood,
                })
            })
            .collect();
        SourcePlanes {
            planes,
            rest: rest.to_vec(),
        }
    }
}

/// Moves the vertices of `mesh` onto the planes the particles carry (`positions` this frame,
/// `source` from [`SourcePlanes::new`], `spacing` the particles' rest spacing), tidying after
/// each round (the module doc). Returns the vertex moves made.
pub fn sharpen(
    mesh: &mut TriMesh,
    positions: &[Vector3<f64>],
    source: &SourcePlanes,
    spacing: f64,
) -> usize {
    let carried = CarriedPlanes::new(positions, source, spacing);
    if carried.normals.iter().all(|&(_, weight)| weight <= 0.0) {
        return 0;
    }
    let mut moves = 0;
    for _ in 0..ROUNDS {
        moves += carried.snap(mesh);
        tidy(mesh, spacing);
    }
    moves
}

/// One frame's planes: points, unit normals and weights.
struct CarriedPlanes {
    points: Vec<Vector3<f64>>,
    normals: Vec<(Vector3<f64>, f64)>,
    spacing: f64,
}

impl CarriedPlanes {
    fn new(positions: &[Vector3<f64>], source: &SourcePlanes, spacing: f64) -> CarriedPlanes {
        let rest = &source.rest;
        let planes: Vec<(Vector3<f64>, Vector3<f64>, f64)> = source
            .planes
            .par_iter()
            .filter_map(|s| {
                let i = s.particle as usize;
                let x = positions[i];
                let (f, residual) = s.neighbourhood.fit(rest, positions, i);
                let residual = residual / spacing;
                // A faded plane (weight 0) stays: it still counts in a vertex's confidence.
                let weight = fade(green_strain(&f), FADE_STRAIN) * fade(residual, FADE_RESIDUAL);
                // Normals are covectors: they follow F^-T.
                let normal = (f.try_inverse()?.transpose() * s.normal).try_normalize(1e-300)?;
                Some((x + f * s.offset, normal, weight))
            })
            .collect();
        let (points, normals) = planes.into_iter().map(|(q, n, w)| (q, (n, w))).unzip();
        CarriedPlanes {
            points,
            normals,
            spacing,
        }
    }

    /// One round: every vertex to its planes' least squares; the vertices moved.
    fn snap(&self, mesh: &mut TriMesh) -> usize {
        let grid = PointGrid::new(&self.points, SNAP_RADIUS * self.spacing);
        let normals = mesh.vertex_normals();
        let moved: Vec<Option<Vector3<f64>>> = mesh
            .vertices
            .par_iter()
            .zip(&normals)
            .map(|(v, n)| self.solve(&grid, v, n))
            .collect();
        let mut count = 0;
        for (v, m) in mesh.vertices.iter_mut().zip(moved) {
            if let Some(m) = m {
                *v = m;
                count += 1;
            }
        }
        count
    }

    /// Where vertex `v` (normal `n`) goes: `v + sum_k e_k (e_k . r) / l_k` over the planes'
    /// quadric `A = sum w m m^T` (eigenpairs `l_k, e_k` above [`RANK_SHARE`] of the largest)
    /// and `r = sum w m (m . (q - v))`; `None` where no plane is near.
    fn solve(&self, grid: &PointGrid, v: &Vector3<f64>, n: &Vector3<f64>) -> Option<Vector3<f64>> {
        let (radius, reach) = (SNAP_RADIUS * self.spacing, SNAP_REACH * self.spacing);
        let mut a = Matrix3::zeros();
        let mut r = Vector3::zeros();
        let (mut faded, mut full) = (0.0, 0.0);
        grid.for_each_within(v, radius, |i| {
            let (q, (m, strain)) = (self.points[i], self.normals[i]);
            let off = m.dot(&(q - v));
            // A plane facing away is the far side of a thin part.
            if off.abs() < reach && m.dot(n) > 0.0 {
                let near = (1.0 - ((q - v).norm() / radius).powi(2)).powi(2);
                let w = strain * near;
                a += w * m * m.transpose();
                r += w * off * m;
                faded += w;
                full += near;
            }
        });
        let eigen = SymmetricEigen::new(a);
        let largest = eigen.eigenvalues.max();
        if largest <= 0.0 {
            return None;
        }
        let mut step = Vector3::zeros();
        for k in 0..3 {
            let l = eigen.eigenvalues[k];
            if l > RANK_SHARE * largest {
                let e = eigen.eigenvectors.column(k);
                step += e * (e.dot(&r) / l);
            }
        }
        // The least squares is the same for any scale of the weights, so the fade alone would
        // move a vertex whose planes are all nearly faded as far as one at rest; scaled by the
        // planes' mean fade the move fades with them, and the surface has no step where the
        // planes give out.
        step *= faded / full;
        let len = step.norm();
        if len > MAX_MOVE * self.spacing {
            step *= MAX_MOVE * self.spacing / len;
        }
        Some(v + step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::mpm::GridSpec;
    use crate::geometry::cleanup::clean;
    use crate::geometry::surface::{deformed_fill_field, edge_weights};
    use crate::geometry::{assets, particles_in};

    /// A cube's particles at rest, `deformation` applied to positions and `F` alike: the
    /// rebuilt surface (as the `deformed` method makes it, cleaned) and the planes.
    fn cube_surface(deformation: Matrix3<f64>) -> (TriMesh, Vec<Vector3<f64>>, SourcePlanes, f64) {
        let cube = assets::cube(2.0, 8);
        let grid = GridSpec::centred_cube(16, 0.25);
        let particles = particles_in(&cube, &grid, 2, None);
        let spacing = grid.dx / 2.0;
        let weights = edge_weights(&cube, &particles.positions, spacing);
        let planes = SourcePlanes::new(&cube, &particles.positions, spacing);
        let x: Vec<Vector3<f64>> = particles
            .positions
            .iter()
            .map(|p| deformation * p)
            .collect();
        let f = vec![deformation; x.len()];
        let field = deformed_fill_field(&x, &f, particles.volume, Some(&weights), spacing).unwrap();
        let (mesh, _) = clean(&field.march(), spacing);
        (mesh, x, planes, spacing)
    }

    /// Share of the area whose face normal is within `deg` of a coordinate axis.
    fn axis_aligned_share(mesh: &TriMesh, deg: f64) -> f64 {
        let cos = deg.to_radians().cos();
        let (mut aligned, mut total) = (0.0, 0.0);
        for t in &mesh.triangles {
            let [a, b, c] = mesh.corners(t);
            let n = (b - a).cross(&(c - a));
            let area = n.norm();
            total += area;
            if n.iter().any(|c| c.abs() >= cos * area) {
                aligned += area;
            }
        }
        aligned / total
    }

    /// At rest the cube's edges and corners come back: the kernels round them (a third of
    /// the area more than 10 degrees off the faces' axes; measured 0.68 within), the snap
    /// puts every triangle but a few back on a face (0.99995 within), and every vertex within
    /// a tenth of a spacing of the cube.
    #[test]
    fn a_cube_at_rest_gets_its_edges_back() {
        let (mut mesh, x, planes, spacing) = cube_surface(Matrix3::identity());
        let rounded = axis_aligned_share(&mesh, 10.0);
        let moves = sharpen(&mut mesh, &x, &planes, spacing);
        let sharp = axis_aligned_share(&mesh, 10.0);
        assert!(moves > 0);
        assert!(rounded < 0.8, "{rounded}");
        assert!(sharp > 0.999, "{rounded} -> {sharp}");
        let off = mesh
            .vertices
            .iter()
            .map(|v| (v.abs().max() - 1.0).abs())
            .fold(0.0, f64::max);
        assert!(off < 0.1 * spacing, "a vertex {off} off the cube");
        assert!(mesh.topology().is_closed());
    }

    /// A strained body's planes do not move the surface: stretched by half along x, every
    /// neighbourhood's fitted strain is past [`FADE_STRAIN`]. Turned (no strain), the cube's
    /// planes turn with it and its edges come back as at rest.
    #[test]
    fn planes_fade_out_with_the_strain_and_turn_with_the_body() {
        let stretch = Matrix3::from_diagonal(&Vector3::new(1.5, 1.0, 1.0));
        assert!(green_strain(&stretch) > FADE_STRAIN);
        let (mut mesh, x, planes, spacing) = cube_surface(stretch);
        let before = mesh.clone();
        assert_eq!(sharpen(&mut mesh, &x, &planes, spacing), 0);
        assert_eq!(mesh, before);
        let turn = *nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 0.3).matrix();
        let (mut mesh, x, planes, spacing) = cube_surface(turn);
        let unturned = |mesh: &TriMesh| TriMesh {
            vertices: mesh.vertices.iter().map(|v| turn.transpose() * v).collect(),
            triangles: mesh.triangles.clone(),
        };
        let rounded = axis_aligned_share(&unturned(&mesh), 10.0);
        assert!(sharpen(&mut mesh, &x, &planes, spacing) > 0);
        // The lattice now crosses the edges at a slant: 0.9990 measured.
        let sharp = axis_aligned_share(&unturned(&mesh), 10.0);
        assert!(rounded < 0.8 && sharp > 0.995, "{rounded} -> {sharp}");
    }

    /// A vertex moves as far as its planes are trusted. Planes half a spacing above a flat
    /// sheet pull it all the way at full weight, a tenth of the way faded to a tenth, and
    /// with the weight ramping down across the sheet the surface ramps down with it. (Before,
    /// the least squares, blind to the weights' scale, moved every vertex all the way while
    /// any plane was left, and the surface stepped where the planes gave out: the creases
    /// mid-shot of docs/geometry.md.)
    #[test]
    fn a_vertex_moves_as_far_as_its_planes_are_trusted() {
        let (n, spacing) = (21usize, 0.1);
        let at = |i: usize| Vector3::new((i % n) as f64 * spacing, (i / n) as f64 * spacing, 0.0);
        let mut triangles = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let (v, m) = ((y * n + x) as u32, n as u32);
                triangles.extend([[v, v + 1, v + m + 1], [v, v + m + 1, v + m]]);
            }
        }
        let sheet = TriMesh {
            vertices: (0..n * n).map(at).collect(),
            triangles,
        };
        let lift = 0.5 * spacing;
        let snapped = |weight: &dyn Fn(f64) -> f64| {
            let planes = CarriedPlanes {
                points: (0..n * n).map(|i| at(i) + Vector3::z() * lift).collect(),
                normals: (0..n * n)
                    .map(|i| (Vector3::z(), weight(at(i).x)))
                    .collect(),
                spacing,
            };
            let mut mesh = sheet.clone();
            planes.snap(&mut mesh);
            mesh
        };
        // Interior vertices (the snapping radius inside the edges).
        let inner = |i: &usize| (3..n - 3).contains(&(i % n)) && (3..n - 3).contains(&(i / n));
        for w in [1.0, 0.1] {
            let mesh = snapped(&|_| w);
            for i in (0..n * n).filter(inner) {
                let z = mesh.vertices[i].z;
                assert!((z - w * lift).abs() < 1e-9 * spacing, "weight {w}: {z}");
            }
        }
        let width = (n - 1) as f64 * spacing;
        let mesh = snapped(&|x| 1.0 - x / width);
        for i in (0..n * n).filter(inner) {
            let (z, x) = (mesh.vertices[i].z, mesh.vertices[i].x);
            // The weights' mean over the snapping radius: within a few percent of the ramp.
            assert!(
                (z - (1.0 - x / width) * lift).abs() < 0.05 * lift,
                "at x {x}: {z}"
            );
        }
    }
}
