//! The source's own surface carried through the morph: every vertex of the source mesh is
//! bound, at rest, to the particles around it, and follows their local deformation. On a
//! frame a vertex at rest position `X` is at
//!
//! ```text
//!   x = X + sum_p w_p (x_p - X_p) + G (X - C),   G = sum_p w_p H_p,   C = sum_p w_p X_p
//! ```
//!
//! (sim units; `x_p` the particle's position, `X_p` its rest position, `H_p` the gradient of
//! the material's displacement at the particle; `w_p` the binding's weights, summing to 1):
//! the particles' mean motion, plus their mean deformation applied to the vertex's offset
//! from their rest centroid. It is exact for any affine motion of the particles, and at rest
//! every term is exactly zero, so frame 1 is the source asset, bit for bit: its vertex lines
//! are written as they were read.
//!
//! `H_p` is the deformation since rest fitted to the particle's rest neighbours
//! ([`RestNeighbourhood::fit_displacement`]), not the particle's own `F_p - I`: the plastic
//! control folds the flow into the rest shape and elasticity takes `F_p` back toward a
//! rotation, so after a flow `F_p` no longer says how the material around the particle has
//! changed shape (with the fit the carried surface ends 2-10% nearer the target on average:
//! docs/lab/2026-12-08-surfaces-record.md, "What turns the carried surface"). Where the fit fails (the neighbours
//! parted or mixed: an rms residual toward [`FIT_TRUST_SPACINGS`]) the particle's own
//! `F_p - I` takes over, faded in.
//!
//! Why this form and this radius (`BIND_SPACINGS`): where the body's surface compresses
//! (sphere -> spot's neck, 30x in one direction) neighbouring vertices come closer than the
//! particles' own jitter, and the carried mesh creases. 0.3.0 applied each particle's own
//! `F_p` to the vertex's offset from that particle, `sum_p w_p F_p (X - X_p)`, within 2.5
//! spacings: the jitter of the particles' motion, and their `F_p` times offsets up to the
//! radius, folded 3.3% of sphere -> spot's faces. Averaging motion and deformation first, over
//! 4.5 spacings, folds none there (docs/geometry.md, "The carried surface"); and over at least
//! three of the vertex's own edge lengths, so that a finer body (more particles, the same mesh)
//! does not fold it either (`BIND_EDGES`).
//!
//! Normals follow the surface they are written on: each source normal (a `vn` line) turns by
//! the smallest rotation that takes its vertex's area-weighted normal at rest to the carried
//! mesh's own there, so the shading is the shape's and the source's own normals (hard edges,
//! hand-edited normals) keep their offsets from the faces. `F^-T` at the vertex (`F = I + G`,
//! until 0.13.0) is a mean over the binding's 4.5 spacings and missed how the mesh itself
//! turns: bob -> spot's last frame was written with normals a mean 29 degrees off its faces.
//!
//! An OBJ source is rewritten line by line: `v` and `vn` lines get their new values, every
//! other line (`vt`, faces, groups, materials, smoothing, comments) is kept as it was, so the
//! topology, UVs and groups are the source's; `mtllib` points at the source's material file.
//! A PLY source is carried as the mesh morph read from it (welded, without its properties).
//!
//! A vertex whose particles have spread apart (the material tore or ejected around it) keeps
//! following their average motion; a frame counts the vertices left more than
//! [`DETACHED_SPACINGS`] particle spacings from every particle, and the largest triangle
//! stretch, so a run says when the carried surface no longer sits on the body.

use super::mesh::TriMesh;
use super::neighbourhood::{FIT_SPACINGS, RestNeighbourhood};
use super::point_grid::PointGrid;
use nalgebra::{Matrix2, Matrix3, Vector3};
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// Binding radius, in particle spacings: particles within it carry a vertex.
const BIND_SPACINGS: f64 = 4.5;

/// A vertex's binding radius is at least this many of its mean edge lengths, at most
/// [`BIND_MAX_SPACINGS`] spacings: a mesh cannot show detail finer than its edges, and
/// averaging over fewer edges than this lets neighbouring vertices follow particles that
/// move apart, which folds faces (sphere -> spot with 50,000 particles: 1.7% of the faces at
/// 2 edges, none at 3).
const BIND_EDGES: f64 = 3.0;

/// The largest binding radius the edge rule may give, in particle spacings (a low-poly
/// source's few vertices still follow their own part of the body).
const BIND_MAX_SPACINGS: f64 = 8.0;

/// A particle's fitted deformation is trusted less as the fit's rms residual grows, and not
/// at all from this many particle spacings (its neighbours parted or mixed: the material
/// judge's limit for a continuum, `morph/quality.rs`); its own `F_p` takes the rest.
const FIT_TRUST_SPACINGS: f64 = 0.25;

/// A carried vertex farther than this many particle spacings from every particle is counted
/// as detached.
pub const DETACHED_SPACINGS: f64 = 2.0;

/// One line of the source file.
#[derive(Clone, Debug)]
enum Line {
    Kept(String),
    /// A `v` line: the vertex index, and what followed its coordinates (a `w` or a colour).
    Vertex(usize, String),
    /// A `vn` line: the normal index.
    Normal(usize),
}

/// The source surface bound to the particles (see the module doc).
#[derive(Clone, Debug)]
pub struct CarriedSurface {
    lines: Vec<Line>,
    /// The source's `v` lines as read, for frames where a vertex has not moved.
    vertex_text: Vec<String>,
    /// Rest positions, world units.
    rest: Vec<Vector3<f64>>,
    /// Rest normals (`vn` lines), and the vertex each is written at (it turns as that
    /// vertex's normal on the mesh turns).
    normals: Vec<(Vector3<f64>, Option<usize>)>,
    /// Each vertex's area-weighted normal at rest.
    rest_normals: Vec<Vector3<f64>>,
    /// Faces fan-triangulated, by vertex index (for the stretch measure).
    pub triangles: Vec<[usize; 3]>,
    /// Each triangle's edge neighbours (the topology is fixed: found once, for the fold share).
    neighbours: Vec<Vec<usize>>,
    /// Texture coordinates (`vt` lines).
    pub uvs: usize,
    /// Binding: vertex `i`'s particles and weights are `bind[offsets[i]..offsets[i + 1]]`.
    offsets: Vec<usize>,
    bind: Vec<(u32, f64)>,
    /// Each vertex's offset from its particles' weighted rest centroid (sim units).
    offset: Vec<Vector3<f64>>,
    /// Each particle's rest neighbourhood, for the particles a vertex is bound to (the
    /// deformation `H_p` is fitted over it on every frame).
    fits: Vec<Option<RestNeighbourhood>>,
    /// Particle spacing (sim units).
    spacing: f64,
    /// World -> sim map the binding was made with.
    to_sim: super::Similarity,
}

/// A carried surface on one frame.
pub struct CarriedFrame {
    /// World positions, one per source vertex.
    pub positions: Vec<Vector3<f64>>,
    /// Each vertex's area-weighted normal on this frame (empty when the source has no `vn`
    /// lines: nothing turns).
    pub normals: Vec<Vector3<f64>>,
}

/// What a frame's carried surface measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CarriedStats {
    /// Largest principal stretch of any triangle against its rest shape (1: unstretched).
    pub max_stretch: f64,
    /// Smallest principal stretch (below 1: compressed).
    pub min_stretch: f64,
    /// Vertices more than [`DETACHED_SPACINGS`] particle spacings from every particle.
    pub detached: usize,
    /// Share of the faces that fold ([`crate::geometry::fidelity::fold_share`]); the first
    /// frame's is the source's own.
    #[serde(default)]
    pub fold_share: f64,
    /// How true it is to the reference of its frame: the target on the last frame
    /// ([`crate::geometry::fidelity`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<super::fidelity::Fidelity>,
    /// The last frame's silhouettes and tips against the target
    /// ([`crate::geometry::likeness`]): how far it reaches the target's extremities.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub likeness: Option<super::likeness::Likeness>,
    /// Seconds spent carrying, writing and measuring it (the frame writer's thread).
    #[serde(default)]
    pub seconds: f64,
}

impl CarriedSurface {
    /// Reads the source's own file (OBJ: every line kept; anything else: `fallback`, the mesh
    /// as loaded) and binds its vertices to the particles at rest (`particles`, sim units,
    /// `spacing` apart), through the world -> sim map `to_sim`.
    pub fn bind(
        source: &Path,
        fallback: &TriMesh,
        to_sim: super::Similarity,
        particles: &[Vector3<f64>],
        spacing: f64,
    ) -> std::io::Result<CarriedSurface> {
        let place = super::Similarity::identity();
        CarriedSurface::bind_placed(source, fallback, place, to_sim, particles, spacing)
    }

    /// [`CarriedSurface::bind`] for a mesh whose file is in coordinates of its own, `place`
    /// mapping them to world units (a target, as the run placed it): its vertices are
    /// written in world units.
    pub fn bind_placed(
        source: &Path,
        fallback: &TriMesh,
        place: super::Similarity,
        to_sim: super::Similarity,
        particles: &[Vector3<f64>],
        spacing: f64,
    ) -> std::io::Result<CarriedSurface> {
        let is_obj = source
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("obj"));
        let mut surface = if is_obj {
            parse_obj(
                source,
                &crate::files::read_to_string(source, crate::files::MESH_BYTES)?,
            )
        } else {
            from_mesh(fallback)
        };
        if place != super::Similarity::identity() {
            surface.place(place);
        }
        surface.to_sim = to_sim;
        surface.neighbours = super::fidelity::edge_neighbours(&surface.triangles);
        surface.rest_normals =
            super::mesh::area_weighted_normals(&surface.rest, surface.triangles.iter().copied());
        let radii = binding_radii(&surface.rest, &surface.triangles, to_sim, spacing);
        let (offsets, bind) = binding(&surface.rest, &radii, to_sim, particles);
        surface.offset = centroid_offsets(&surface.rest, to_sim, particles, &offsets, &bind);
        surface.fits = neighbourhoods(particles, &bind, spacing);
        surface.spacing = spacing;
        surface.offsets = offsets;
        surface.bind = bind;
        Ok(surface)
    }

    /// Moves the rest vertices by `place` (a similarity: the normals keep their directions),
    /// and their lines with them.
    fn place(&mut self, place: super::Similarity) {
        for v in &mut self.rest {
            *v = place.apply(v);
        }
        for line in &self.lines {
            if let Line::Vertex(i, tail) = line {
                let v = self.rest[*i];
                self.vertex_text[*i] =
                    format!("v {} {} {}{tail}", v.x as f32, v.y as f32, v.z as f32);
            }
        }
    }

    /// Each triangle's edge neighbours (for the fold share).
    pub fn face_neighbours(&self) -> &[Vec<usize>] {
        &self.neighbours
    }

    pub fn vertex_count(&self) -> usize {
        self.rest.len()
    }

    /// Rest positions, world units (the source's vertices).
    pub fn rest(&self) -> &[Vector3<f64>] {
        &self.rest
    }

    /// The surface on a frame of particle positions `x` and deformation gradients `f` (sim
    /// units, in the particles' order at binding; `rest_particles` their rest positions).
    pub fn carry(
        &self,
        rest_particles: &[Vector3<f64>],
        x: &[Vector3<f64>],
        f: &[Matrix3<f64>],
    ) -> CarriedFrame {
        let gradients = self.gradients(rest_particles, x, f);
        let back = 1.0 / self.to_sim.scale;
        let positions: Vec<Vector3<f64>> = (0..self.rest.len())
            .map(|i| {
                let mut motion = Vector3::zeros();
                let mut g = Matrix3::zeros();
                for &(p, w) in &self.bind[self.offsets[i]..self.offsets[i + 1]] {
                    let p = p as usize;
                    motion += w * (x[p] - rest_particles[p]);
                    g += w * gradients[p];
                }
                self.rest[i] + back * (motion + g * self.offset[i])
            })
            .collect();
        // Only a source with normals of its own (`vn` lines) writes any.
        let normals = if self.normals.is_empty() {
            Vec::new()
        } else {
            super::mesh::area_weighted_normals(&positions, self.triangles.iter().copied())
        };
        CarriedFrame { positions, normals }
    }

    /// Each bound particle's displacement gradient `H_p` on this frame (the module doc): the
    /// fitted one, faded into `F_p - I` as the fit's residual grows; zero for a particle no
    /// vertex is bound to.
    fn gradients(
        &self,
        rest: &[Vector3<f64>],
        x: &[Vector3<f64>],
        f: &[Matrix3<f64>],
    ) -> Vec<Matrix3<f64>> {
        let limit = FIT_TRUST_SPACINGS * self.spacing;
        self.fits
            .par_iter()
            .enumerate()
            .map(|(p, fit)| {
                let Some(fit) = fit else {
                    return Matrix3::zeros();
                };
                let own = f[p] - Matrix3::identity();
                let (h, residual) = fit.fit_displacement(rest, x, p);
                let fitted = h.iter().all(|v| v.is_finite())
                    && (h + Matrix3::identity()).determinant() > 0.0;
                if !fitted {
                    return own;
                }
                let trust = (1.0 - residual / limit).max(0.0).powi(2);
                // At rest `h` is exactly zero and the trust exactly 1: frame 1 stays the source.
                if trust == 1.0 {
                    h
                } else {
                    trust * h + (1.0 - trust) * own
                }
            })
            .collect()
    }

    /// Largest and smallest principal stretch over the triangles, and the vertices detached
    /// from the particles `x` (sim units, `spacing` apart).
    pub fn stats(&self, frame: &CarriedFrame, x: &[Vector3<f64>], spacing: f64) -> CarriedStats {
        let (mut max_stretch, mut min_stretch) = (1.0f64, 1.0f64);
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.rest[i]);
            let [p, q, r] = t.map(|i| frame.positions[i]);
            if let Some((lo, hi)) = principal_stretches([b - a, c - a], [q - p, r - p]) {
                max_stretch = max_stretch.max(hi);
                min_stretch = min_stretch.min(lo);
            }
        }
        let sim: Vec<Vector3<f64>> = frame
            .positions
            .iter()
            .map(|v| self.to_sim.apply(v))
            .collect();
        CarriedStats {
            max_stretch,
            min_stretch,
            detached: detached(&sim, x, DETACHED_SPACINGS * spacing),
            fold_share: super::fidelity::fold_share(
                &frame.positions,
                &self.triangles,
                &self.neighbours,
            ),
            fidelity: None,
            likeness: None,
            seconds: 0.0,
        }
    }

    /// Writes the frame as the source's OBJ with new vertex positions and normals; a vertex
    /// that has not moved keeps its line as read.
    pub fn write_obj(&self, path: &Path, frame: &CarriedFrame) -> std::io::Result<()> {
        super::mesh::finite_in_f32(&frame.positions, "carried vertex")?;
        super::mesh::write_atomically(path, |w| {
            for line in &self.lines {
                match line {
                    Line::Kept(s) => writeln!(w, "{s}")?,
                    Line::Vertex(i, rest) => {
                        let v = frame.positions[*i];
                        if v == self.rest[*i] {
                            writeln!(w, "{}", self.vertex_text[*i])?;
                        } else {
                            writeln!(w, "v {} {} {}{rest}", v.x as f32, v.y as f32, v.z as f32)?;
                        }
                    }
                    Line::Normal(k) => {
                        let (n, at) = self.normals[*k];
                        let n = match at {
                            Some(i) => turned(n, self.rest_normals[i], frame.normals[i]),
                            None => n,
                        };
                        writeln!(w, "vn {} {} {}", n.x as f32, n.y as f32, n.z as f32)?;
                    }
                }
            }
            Ok(())
        })
    }
}

/// `n` turned by the smallest rotation taking the unit normal `from` to `to`: `n` itself where
/// they are equal (a vertex at rest) or either is zero (a vertex of no area), and `to` where
/// the surface has turned over (no smallest rotation).
fn turned(n: Vector3<f64>, from: Vector3<f64>, to: Vector3<f64>) -> Vector3<f64> {
    if from == to || from == Vector3::zeros() || to == Vector3::zeros() {
        return n;
    }
    let (axis, cos) = (from.cross(&to), from.dot(&to));
    if cos <= -1.0 + 1e-9 {
        return to;
    }
    // Rodrigues' formula for the rotation about `axis` by the angle between the two.
    let rotated = n + axis.cross(&n) + axis.cross(&axis.cross(&n)) / (1.0 + cos);
    rotated.try_normalize(1e-300).unwrap_or(n)
}

/// The largest and smallest singular values of the map taking a triangle's rest edges to its
/// current ones (`None` for a degenerate rest triangle).
fn principal_stretches(rest: [Vector3<f64>; 2], now: [Vector3<f64>; 2]) -> Option<(f64, f64)> {
    let u = rest[0].try_normalize(1e-300)?;
    let normal = rest[0].cross(&rest[1]);
    let v = normal.cross(&rest[0]).try_normalize(1e-300)?;
    let e = Matrix2::new(
        rest[0].dot(&u),
        rest[1].dot(&u),
        rest[0].dot(&v),
        rest[1].dot(&v),
    );
    let inv = e.try_inverse()?;
    // G = [now0 now1] E^-1 (3x2); its singular values are the roots of G^T G's eigenvalues.
    let g0 = now[0] * inv[(0, 0)] + now[1] * inv[(1, 0)];
    let g1 = now[0] * inv[(0, 1)] + now[1] * inv[(1, 1)];
    let (a, b, d) = (g0.dot(&g0), g0.dot(&g1), g1.dot(&g1));
    let mean = 0.5 * (a + d);
    let spread = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    Some(((mean - spread).max(0.0).sqrt(), (mean + spread).sqrt()))
}

/// Vertices (sim units) farther than `radius` from every particle of `x`.
fn detached(vertices: &[Vector3<f64>], x: &[Vector3<f64>], radius: f64) -> usize {
    let grid = PointGrid::new(x, radius);
    vertices
        .iter()
        .filter(|v| !grid.any_within(v, radius))
        .count()
}

/// Each vertex's binding radius (sim units): [`BIND_SPACINGS`] spacings, or
/// [`BIND_EDGES`] times the mean length of its edges where that is more, up to
/// [`BIND_MAX_SPACINGS`] spacings.
fn binding_radii(
    rest: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    to_sim: super::Similarity,
    spacing: f64,
) -> Vec<f64> {
    let mut length = vec![0.0; rest.len()];
    let mut count = vec![0usize; rest.len()];
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let l = (rest[a] - rest[b]).norm();
            for v in [a, b] {
                length[v] += l;
                count[v] += 1;
            }
        }
    }
    length
        .iter()
        .zip(&count)
        .map(|(&l, &n)| {
            let edge = if n == 0 {
                0.0
            } else {
                to_sim.scale * l / n as f64
            };
            (BIND_EDGES * edge).clamp(BIND_SPACINGS * spacing, BIND_MAX_SPACINGS * spacing)
        })
        .collect()
}

/// Each vertex's particles within its radius (`radii`, sim units), weighted by
/// `(1 - d^2 / R^2)^3` and normalized; a vertex with none takes its nearest particle.
fn binding(
    rest: &[Vector3<f64>],
    radii: &[f64],
    to_sim: super::Similarity,
    particles: &[Vector3<f64>],
) -> (Vec<usize>, Vec<(u32, f64)>) {
    let largest = radii.iter().copied().fold(0.0, f64::max);
    let grid = PointGrid::new(particles, largest);
    let mut offsets = vec![0];
    let mut bind = Vec::new();
    for (v, &radius) in rest.iter().zip(radii) {
        let at = to_sim.apply(v);
        let start = bind.len();
        grid.for_each_within(&at, radius, |p| {
            let q = (particles[p] - at).norm_squared() / (radius * radius);
            bind.push((p as u32, (1.0 - q).powi(3)));
        });
        if bind.len() == start {
            let nearest = (0..particles.len())
                .min_by(|&a, &b| {
                    (particles[a] - at)
                        .norm_squared()
                        .total_cmp(&(particles[b] - at).norm_squared())
                })
                .expect("a morph has particles");
            bind.push((nearest as u32, 1.0));
        }
        let total: f64 = bind[start..].iter().map(|(_, w)| w).sum();
        for (_, w) in &mut bind[start..] {
            *w /= total;
        }
        offsets.push(bind.len());
    }
    (offsets, bind)
}

/// The rest neighbourhood of every particle some vertex is bound to (`None` for the others,
/// and where the neighbours do not span the space).
fn neighbourhoods(
    particles: &[Vector3<f64>],
    bind: &[(u32, f64)],
    spacing: f64,
) -> Vec<Option<RestNeighbourhood>> {
    let mut bound = vec![false; particles.len()];
    for &(p, _) in bind {
        bound[p as usize] = true;
    }
    let radius = FIT_SPACINGS * spacing;
    let grid = PointGrid::new(particles, radius);
    (0..particles.len())
        .into_par_iter()
        .map(|p| {
            if bound[p] {
                RestNeighbourhood::new(particles, &grid, p, radius)
            } else {
                None
            }
        })
        .collect()
}

/// Each vertex's offset (sim units) from the weighted rest centroid of its particles.
fn centroid_offsets(
    rest: &[Vector3<f64>],
    to_sim: super::Similarity,
    particles: &[Vector3<f64>],
    offsets: &[usize],
    bind: &[(u32, f64)],
) -> Vec<Vector3<f64>> {
    rest.iter()
        .enumerate()
        .map(|(i, v)| {
            let centre: Vector3<f64> = bind[offsets[i]..offsets[i + 1]]
                .iter()
                .map(|&(p, w)| w * particles[p as usize])
                .sum();
            to_sim.apply(v) - centre
        })
        .collect()
}

/// An OBJ file's lines, its vertices, normals and faces.
fn parse_obj(source: &Path, text: &str) -> CarriedSurface {
    let dir = source.parent().unwrap_or(Path::new("."));
    let mut surface = empty();
    let mut normal_vertex: Vec<Option<usize>> = Vec::new();
    for line in text.lines() {
        let trimmed = line.trim_start();
        let mut words = trimmed.split_whitespace();
        match words.next() {
            Some("v") => {
                let xyz: Vec<f64> = words
                    .by_ref()
                    .take(3)
                    .filter_map(|w| w.parse().ok())
                    .collect();
                if xyz.len() == 3 {
                    let mut v = Vector3::new(xyz[0], xyz[1], xyz[2]);
                    let rest: Vec<&str> = words.collect();
                    // `v x y z w`: a homogeneous position, read as (x, y, z) / w as the mesh
                    // loader reads it, and written without w (Blender ignores w). Three more
                    // values are a vertex colour, kept.
                    let (rest, text) = match rest.as_slice() {
                        [w] if w.parse::<f64>().is_ok_and(|w| w != 0.0 && w != 1.0) => {
                            v /= w.parse::<f64>().expect("checked");
                            (Vec::new(), format!("v {} {} {}", v.x, v.y, v.z))
                        }
                        [w] if w.parse::<f64>().is_ok() => {
                            (Vec::new(), format!("v {} {} {}", v.x, v.y, v.z))
                        }
                        _ => (rest, line.to_string()),
                    };
                    let tail = if rest.is_empty() {
                        String::new()
                    } else {
                        format!(" {}", rest.join(" "))
                    };
                    surface.lines.push(Line::Vertex(surface.rest.len(), tail));
                    surface.rest.push(v);
                    surface.vertex_text.push(text);
                    continue;
                }
            }
            Some("vn") => {
                let n: Vec<f64> = words.filter_map(|w| w.parse().ok()).collect();
                if n.len() == 3 {
                    surface.lines.push(Line::Normal(surface.normals.len()));
                    surface.normals.push((Vector3::new(n[0], n[1], n[2]), None));
                    normal_vertex.push(None);
                    continue;
                }
            }
            Some("vt") => surface.uvs += 1,
            Some("f") => {
                let corners: Vec<(Option<usize>, Option<usize>)> = words
                    .map(|c| {
                        let mut parts = c.split('/');
                        let resolve = |s: Option<&str>, count: usize| {
                            let i: i64 = s.filter(|s| !s.is_empty())?.parse().ok()?;
                            let i = if i < 0 { count as i64 + i } else { i - 1 };
                            (0..count as i64).contains(&i).then_some(i as usize)
                        };
                        let v = resolve(parts.next(), surface.rest.len());
                        let _uv = parts.next();
                        let n = resolve(parts.next(), surface.normals.len());
                        (v, n)
                    })
                    .collect();
                for &(v, n) in &corners {
                    if let (Some(v), Some(n)) = (v, n)
                        && normal_vertex[n].is_none()
                    {
                        normal_vertex[n] = Some(v);
                    }
                }
                let vs: Vec<usize> = corners.iter().filter_map(|c| c.0).collect();
                if vs.len() == corners.len() {
                    for k in 1..vs.len().saturating_sub(1) {
                        surface.triangles.push([vs[0], vs[k], vs[k + 1]]);
                    }
                }
            }
            Some("mtllib") => {
                // The material file lives beside the source, not beside the frames.
                let names: Vec<String> = words
                    .map(|name| {
                        let p = dir.join(name);
                        std::path::absolute(&p).unwrap_or(p).display().to_string()
                    })
                    .collect();
                surface
                    .lines
                    .push(Line::Kept(format!("mtllib {}", names.join(" "))));
                continue;
            }
            _ => {}
        }
        surface.lines.push(Line::Kept(line.to_string()));
    }
    for (n, v) in surface.normals.iter_mut().zip(normal_vertex) {
        n.1 = v;
    }
    surface
}

/// A mesh as loaded, written as plain `v` and `f` lines.
fn from_mesh(mesh: &TriMesh) -> CarriedSurface {
    let mut surface = empty();
    surface.lines.push(Line::Kept(format!(
        "# carried by morph {}",
        env!("CARGO_PKG_VERSION")
    )));
    for (i, v) in mesh.vertices.iter().enumerate() {
        surface.lines.push(Line::Vertex(i, String::new()));
        surface.rest.push(*v);
        surface
            .vertex_text
            .push(format!("v {} {} {}", v.x as f32, v.y as f32, v.z as f32));
    }
    for t in &mesh.triangles {
        surface.lines.push(Line::Kept(format!(
            "f {} {} {}",
            t[0] + 1,
            t[1] + 1,
            t[2] + 1
        )));
        surface.triangles.push(t.map(|i| i as usize));
    }
    surface
}

fn empty() -> CarriedSurface {
    CarriedSurface {
        lines: Vec::new(),
        vertex_text: Vec::new(),
        rest: Vec::new(),
        normals: Vec::new(),
        triangles: Vec::new(),
        neighbours: Vec::new(),
        uvs: 0,
        offsets: Vec::new(),
        bind: Vec::new(),
        offset: Vec::new(),
        rest_normals: Vec::new(),
        fits: Vec::new(),
        spacing: 1.0,
        to_sim: super::Similarity::identity(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_uniform_stretch_is_measured() {
        let rest = [Vector3::x(), Vector3::y()];
        let now = [2.0 * Vector3::x(), 0.5 * Vector3::y()];
        let (lo, hi) = principal_stretches(rest, now).unwrap();
        assert!((hi - 2.0).abs() < 1e-12 && (lo - 0.5).abs() < 1e-12);
    }

    /// A source normal turns with its vertex's surface and keeps its angle to it; at rest,
    /// or where the surface has no area, it is kept as it is.
    #[test]
    fn a_source_normal_turns_with_its_surface() {
        let (from, n) = (Vector3::z(), Vector3::new(0.3, 0.0, 1.0).normalize());
        let to = Vector3::new(1.0, 0.0, 1.0).normalize();
        let t = turned(n, from, to);
        assert!((t.norm() - 1.0).abs() < 1e-12);
        assert!((t.dot(&to) - n.dot(&from)).abs() < 1e-12, "{t}");
        assert!(t.y.abs() < 1e-12 && t.x > to.x, "{t}");
        assert_eq!(turned(n, from, from), n);
        assert_eq!(turned(n, Vector3::zeros(), to), n);
        assert_eq!(turned(n, from, -from), -from);
    }

    /// A vertex binds over 4.5 spacings, or [`BIND_EDGES`] of its mean edge lengths where its
    /// mesh is coarser than that, never more than 8 spacings; a vertex of no face takes 4.5.
    #[test]
    fn the_binding_radius_follows_coarse_edges() {
        // A right triangle with legs `l` and a lone vertex; spacing 1, world = sim.
        let radii = |l: f64| {
            let rest = [
                Vector3::zeros(),
                Vector3::x() * l,
                Vector3::y() * l,
                Vector3::z(),
            ];
            binding_radii(
                &rest,
                &[[0, 1, 2]],
                crate::geometry::Similarity::identity(),
                1.0,
            )
        };
        let fine = radii(1.0);
        assert!(fine.iter().all(|&r| r == BIND_SPACINGS), "{fine:?}");
        // Vertex 0's edges are 2.2 and 2.2, vertex 1's 2.2 and 3.11.
        let coarse = radii(2.2);
        assert!((coarse[0] - BIND_EDGES * 2.2).abs() < 1e-12, "{coarse:?}");
        let mean = (2.2 + 2.2 * 2f64.sqrt()) / 2.0;
        assert!((coarse[1] - BIND_EDGES * mean).abs() < 1e-12, "{coarse:?}");
        assert_eq!(coarse[3], BIND_SPACINGS);
        let huge = radii(100.0);
        assert!(
            huge[..3].iter().all(|&r| r == BIND_MAX_SPACINGS),
            "{huge:?}"
        );
    }

    /// An affine motion of the particles carries every vertex exactly by the same map, whatever
    /// the particles' own `F`, and a frame at rest gives the rest positions bit for bit.
    #[test]
    fn affine_motion_is_carried_exactly() {
        let mut particles = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..6 {
                    particles.push(Vector3::new(i as f64, j as f64, k as f64) * 0.5);
                }
            }
        }
        let text = "mtllib m.mtl\nv 1.0 1.2 1.1\nv 1.5 1.0 1.0\nv 1.2 1.6 1.3\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\n";
        let mut s = parse_obj(Path::new("/a/b.obj"), text);
        let to_sim = crate::geometry::Similarity::identity();
        let radii = binding_radii(&s.rest, &s.triangles, to_sim, 0.5);
        (s.offsets, s.bind) = binding(&s.rest, &radii, to_sim, &particles);
        s.offset = centroid_offsets(&s.rest, to_sim, &particles, &s.offsets, &s.bind);
        s.rest_normals =
            crate::geometry::mesh::area_weighted_normals(&s.rest, s.triangles.iter().copied());
        s.fits = neighbourhoods(&particles, &s.bind, 0.5);
        s.spacing = 0.5;
        let f0 = vec![Matrix3::identity(); particles.len()];
        let at_rest = s.carry(&particles, &particles, &f0);
        assert_eq!(at_rest.positions, s.rest);
        let a = Matrix3::new(1.1, 0.2, 0.0, -0.1, 0.9, 0.05, 0.0, 0.1, 1.2);
        let t = Vector3::new(0.3, -0.2, 0.1);
        let moved: Vec<_> = particles.iter().map(|p| a * p + t).collect();
        // The particles' own `F` is the motion's (elastic), or the identity: the plastic
        // control has folded the flow into the rest shape. The surface follows the material
        // either way, and its normals turn by the motion's `F^-T`.
        for f in [a, Matrix3::identity()] {
            let frame = s.carry(&particles, &moved, &vec![f; particles.len()]);
            for (v, r) in frame.positions.iter().zip(&s.rest) {
                assert!(
                    (v - (a * r + t)).norm() < 1e-12,
                    "{v} against {}",
                    a * r + t
                );
            }
            // The mesh's own normals follow `a^-T`, and a source normal along them stays so.
            let inverse_t = a.try_inverse().unwrap().transpose();
            for (i, n) in frame.normals.iter().enumerate() {
                let want = (inverse_t * s.rest_normals[i]).normalize();
                assert!((n - want).norm() < 1e-12, "{n} against {want}");
                assert!((turned(s.rest_normals[i], s.rest_normals[i], *n) - want).norm() < 1e-12);
            }
        }
        assert_eq!((s.uvs, s.triangles.len()), (1, 1));
        assert!(matches!(&s.lines[0], Line::Kept(l) if l == "mtllib /a/m.mtl"));
    }
}
