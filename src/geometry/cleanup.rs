//! Clean rebuilt surfaces: what marching tetrahedra leaves behind, removed, and the triangles
//! made fit to render.
//!
//! 1. **Shells.** The surface is split into its connected shells. A shell enclosing negative
//!    volume is the inside wall of a void in the body: dropped (it would render as a dark
//!    bubble, and "recalculate outside" flips it). A shell enclosing less than
//!    [`ISLAND_SHARE`] of the largest shell's volume is a floating island (a few ejected
//!    particles): dropped and counted. What is left is one outer shell per body.
//! 2. **Taubin smoothing** (`lambda = 0.5`, `mu = -0.53`, [`SMOOTHING_STEPS`] pairs): a
//!    low-pass filter that takes off the lattice's staircase without the shrinking plain
//!    Laplacian smoothing causes; the volume it changes is measured.
//! 3. **Edge flips.** An edge whose flip raises the smallest angle of its two triangles is
//!    flipped, where the two triangles are nearly coplanar (so the shape does not change) and
//!    the flip makes no duplicate edge: marching tetrahedra's slivers become well-shaped
//!    triangles.
//! 4. **Collapses.** An edge shorter than [`COLLAPSE_SHARE`] of the lattice spacing, or the
//!    short edge of a needle triangle, joins its two vertices where that keeps the surface a
//!    closed manifold and turns no triangle over: the near-zero-area faces of level-set points
//!    that land on a lattice node go, and so does a cap (an angle under [`CAP_DEG`], the
//!    other near 180 degrees) that no flip could take. Collapses and flips alternate for a
//!    few rounds.
//!
//! [`quality`] measures a surface: shells, genus, angles, zero-area faces.

use super::mesh::TriMesh;
use nalgebra::Vector3;
use rustc_hash::{FxHashMap, FxHashSet};

/// Shells enclosing less than this share of the largest shell's volume are islands.
pub const ISLAND_SHARE: f64 = 0.005;
/// Taubin smoothing steps (each a `lambda` and a `mu` pass).
pub const SMOOTHING_STEPS: usize = 10;
/// Edges shorter than this share of the lattice spacing are collapsed.
pub const COLLAPSE_SHARE: f64 = 0.05;
/// Largest angle between the normals of two triangles whose shared edge may be flipped.
const FLIP_MAX_BEND_DEG: f64 = 20.0;
/// Flips are tried on the edges of triangles with an angle under this.
const FLIP_WORTH_DEG: f64 = 20.0;
/// A triangle with an angle under this and one edge much shorter than the others is a needle:
/// its short edge is collapsed.
pub const NEEDLE_DEG: f64 = 10.0;
/// A triangle with an angle under this that the flips left (a cap) has its shortest edge
/// collapsed.
pub const CAP_DEG: f64 = 1.0;
/// Rounds of collapses and flips.
const ROUNDS: usize = 5;
/// A triangle with an angle under this is a sliver: its edge may be flipped across a bend of
/// up to [`SLIVER_MAX_BEND_DEG`].
const SLIVER_DEG: f64 = 5.0;
const SLIVER_MAX_BEND_DEG: f64 = 60.0;

/// What cleaning removed and changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CleanReport {
    /// Inner void shells dropped.
    pub voids: usize,
    /// Floating islands dropped.
    pub islands: usize,
    /// Edges flipped and collapsed.
    pub flips: usize,
    pub collapses: usize,
    /// Relative change of the enclosed volume by smoothing.
    pub smoothing_volume_change: f64,
}

/// A surface's shape as a renderer sees it.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SurfaceQuality {
    pub shells: usize,
    /// Shells enclosing negative volume (inside walls of voids).
    pub void_shells: usize,
    /// Sum of the shells' genus (holes through the body), when every shell is a closed
    /// manifold.
    pub genus: Option<i64>,
    /// The smallest angle of any triangle, degrees.
    pub min_angle_deg: f64,
    /// Share of triangles with an angle under 5 degrees.
    pub under_5_deg: f64,
    /// Triangles of (near) zero area: under 1e-12 of the mean.
    pub zero_area: usize,
    pub triangles: usize,
}

/// The cleaned surface (see the module doc); `spacing` is the lattice spacing it was
/// extracted at.
pub fn clean(mesh: &TriMesh, spacing: f64) -> (TriMesh, CleanReport) {
    let mut report = CleanReport::default();
    let mut mesh = keep_outer_shells(mesh, &mut report);
    let before = mesh.signed_volume();
    taubin(&mut mesh, SMOOTHING_STEPS);
    let after = mesh.signed_volume();
    report.smoothing_volume_change = if before != 0.0 {
        after / before - 1.0
    } else {
        0.0
    };
    (report.collapses, report.flips) = tidy(&mut mesh, spacing);
    (mesh, report)
}

/// Cleaning's collapses and flips alone (no smoothing): the slivers a vertex move left.
pub fn tidy(mesh: &mut TriMesh, spacing: f64) -> (usize, usize) {
    let (mut collapses, mut flips) = (0, 0);
    for _ in 0..ROUNDS {
        collapses += collapse_short_edges(mesh, COLLAPSE_SHARE * spacing);
        *mesh = compact(mesh);
        flips += flip_edges(mesh);
    }
    (collapses, flips)
}

/// Moves every vertex along its normal by one distance, the one that makes the surface
/// enclose `volume` (to first order: the volume missing over the area; twice, for the
/// second-order term). A smoothing kernel or smoothing steps shrink a convex body by a thin
/// layer; this puts the layer back evenly, without changing the shape's detail.
pub fn keep_volume(mesh: &mut TriMesh, volume: f64) {
    for _ in 0..2 {
        let (current, area) = (mesh.signed_volume(), mesh.surface_area());
        if !(area > 0.0 && current > 0.0 && volume > 0.0) {
            return;
        }
        let d = (volume - current) / area;
        let normals = mesh.vertex_normals();
        for (v, n) in mesh.vertices.iter_mut().zip(normals) {
            *v += d * n;
        }
    }
}

/// Triangles grouped into connected shells (by shared vertices), in order of first triangle.
fn shells(mesh: &TriMesh) -> Vec<Vec<usize>> {
    let n = mesh.vertices.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for t in &mesh.triangles {
        let a = find(&mut parent, t[0] as usize);
        for &v in &t[1..] {
            let b = find(&mut parent, v as usize);
            if a != b {
                parent[b] = a;
            }
        }
    }
    let mut index: FxHashMap<usize, usize> = FxHashMap::default();
    let mut out: Vec<Vec<usize>> = Vec::new();
    for (k, t) in mesh.triangles.iter().enumerate() {
        let root = find(&mut parent, t[0] as usize);
        let s = *index.entry(root).or_insert_with(|| {
            out.push(Vec::new());
            out.len() - 1
        });
        out[s].push(k);
    }
    out
}

fn shell_volume(mesh: &TriMesh, tris: &[usize]) -> f64 {
    tris.iter()
        .map(|&k| {
            let [a, b, c] = mesh.corners(&mesh.triangles[k]);
            a.dot(&b.cross(&c)) / 6.0
        })
        .sum()
}

fn keep_outer_shells(mesh: &TriMesh, report: &mut CleanReport) -> TriMesh {
    let shells = shells(mesh);
    let volumes: Vec<f64> = shells.iter().map(|s| shell_volume(mesh, s)).collect();
    let largest = volumes.iter().copied().fold(0.0, f64::max);
    let mut kept = TriMesh {
        vertices: mesh.vertices.clone(),
        triangles: Vec::new(),
    };
    for (s, v) in shells.iter().zip(&volumes) {
        if *v <= 0.0 {
            report.voids += 1;
        } else if *v < ISLAND_SHARE * largest {
            report.islands += 1;
        } else {
            kept.triangles.extend(s.iter().map(|&k| mesh.triangles[k]));
        }
    }
    compact(&kept)
}

/// Only the vertices some triangle uses, renumbered in order of first use.
fn compact(mesh: &TriMesh) -> TriMesh {
    let mut index: FxHashMap<u32, u32> = FxHashMap::default();
    let mut out = TriMesh::default();
    for t in &mesh.triangles {
        let tri = t.map(|v| {
            *index.entry(v).or_insert_with(|| {
                out.vertices.push(mesh.vertices[v as usize]);
                (out.vertices.len() - 1) as u32
            })
        });
        out.triangles.push(tri);
    }
    out
}

/// Each vertex's neighbours (sorted, without repeats).
fn neighbours(mesh: &TriMesh) -> Vec<Vec<u32>> {
    let mut n: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertices.len()];
    for t in &mesh.triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            n[a as usize].push(b);
            n[b as usize].push(a);
        }
    }
    for l in &mut n {
        l.sort_unstable();
        l.dedup();
    }
    n
}

/// Taubin's lambda|mu smoothing with the uniform Laplacian.
fn taubin(mesh: &mut TriMesh, steps: usize) {
    let nb = neighbours(mesh);
    for _ in 0..steps {
        for factor in [0.5, -0.53] {
            let moved: Vec<Vector3<f64>> = (0..mesh.vertices.len())
                .map(|i| {
                    let p = mesh.vertices[i];
                    if nb[i].is_empty() {
                        return p;
                    }
                    let mean = nb[i]
                        .iter()
                        .map(|&j| mesh.vertices[j as usize])
                        .sum::<Vector3<f64>>()
                        / nb[i].len() as f64;
                    p + factor * (mean - p)
                })
                .collect();
            mesh.vertices = moved;
        }
    }
}

/// The cosines of a triangle's angles (1, an angle of 0, at a corner with an edge of zero
/// length).
fn cosines(a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> [f64; 3] {
    let cosine = |p: &Vector3<f64>, q: &Vector3<f64>, r: &Vector3<f64>| {
        let (u, v) = (q - p, r - p);
        let (nu, nv) = (u.norm(), v.norm());
        if nu == 0.0 || nv == 0.0 {
            1.0
        } else {
            (u.dot(&v) / (nu * nv)).clamp(-1.0, 1.0)
        }
    };
    [cosine(a, b, c), cosine(b, c, a), cosine(c, a, b)]
}

/// A triangle's smallest angle, radians: the arc cosine of its largest cosine (one `acos`
/// where three were taken: they were 3% of a morph's samples).
fn min_angle(mesh: &TriMesh, t: [u32; 3]) -> f64 {
    let [a, b, c] = mesh.corners(&t);
    let [x, y, z] = cosines(&a, &b, &c);
    x.max(y).max(z).acos()
}

fn normal(mesh: &TriMesh, t: [u32; 3]) -> Vector3<f64> {
    let [a, b, c] = mesh.corners(&t);
    (b - a).cross(&(c - a))
}

/// Directed edge -> the triangle holding it.
fn edge_map(mesh: &TriMesh) -> FxHashMap<(u32, u32), usize> {
    let mut m = FxHashMap::with_capacity_and_hasher(3 * mesh.triangles.len(), Default::default());
    for (k, t) in mesh.triangles.iter().enumerate() {
        for e in 0..3 {
            m.insert((t[e], t[(e + 1) % 3]), k);
        }
    }
    m
}

/// Flips edges that raise the smallest angle of their two nearly coplanar triangles; returns
/// the flips made. Passes until none helps (at most 10).
fn flip_edges(mesh: &mut TriMesh) -> usize {
    let cos_bend = FLIP_MAX_BEND_DEG.to_radians().cos();
    let cos_sliver_bend = SLIVER_MAX_BEND_DEG.to_radians().cos();
    let worth = FLIP_WORTH_DEG.to_radians();
    // Only an edge of a poor triangle is worth flipping: start from those.
    let mut candidates: Vec<usize> = (0..mesh.triangles.len())
        .filter(|&k| min_angle(mesh, mesh.triangles[k]) < worth)
        .collect();
    if candidates.is_empty() {
        return 0;
    }
    let mut edges = edge_map(mesh);
    let mut undirected: FxHashSet<(u32, u32)> =
        edges.keys().map(|&(a, b)| (a.min(b), a.max(b))).collect();
    let mut flips = 0;
    for _ in 0..10 {
        let mut changed = 0;
        let mut next = Vec::new();
        for &k in &candidates {
            for e in 0..3 {
                let t = mesh.triangles[k];
                let (a, b) = (t[e], t[(e + 1) % 3]);
                let c = t[(e + 2) % 3];
                let Some(&other) = edges.get(&(b, a)) else {
                    continue;
                };
                let u = mesh.triangles[other];
                let d = u
                    .into_iter()
                    .find(|&v| v != a && v != b)
                    .expect("a triangle");
                if c == d || undirected.contains(&(c.min(d), c.max(d))) {
                    continue;
                }
                let (n1, n2) = (normal(mesh, t), normal(mesh, u));
                let (l1, l2) = (n1.norm(), n2.norm());
                let before = min_angle(mesh, t).min(min_angle(mesh, u));
                // A sliver may bend the surface more to go.
                let cos_allowed = if before < SLIVER_DEG.to_radians() {
                    cos_sliver_bend
                } else {
                    cos_bend
                };
                if l1 == 0.0 || l2 == 0.0 || n1.dot(&n2) < cos_allowed * l1 * l2 {
                    continue;
                }
                let (new1, new2) = ([c, a, d], [d, b, c]);
                let after = min_angle(mesh, new1).min(min_angle(mesh, new2));
                // The new triangles must face the same way (no fold-over).
                let (m1, m2) = (normal(mesh, new1), normal(mesh, new2));
                if after <= before + 1e-9 || m1.dot(&n1) <= 0.0 || m2.dot(&n1) <= 0.0 {
                    continue;
                }
                for tri in [t, u] {
                    for f in 0..3 {
                        edges.remove(&(tri[f], tri[(f + 1) % 3]));
                    }
                }
                undirected.remove(&(a.min(b), a.max(b)));
                undirected.insert((c.min(d), c.max(d)));
                mesh.triangles[k] = new1;
                mesh.triangles[other] = new2;
                for (idx, tri) in [(k, new1), (other, new2)] {
                    for f in 0..3 {
                        edges.insert((tri[f], tri[(f + 1) % 3]), idx);
                    }
                    if min_angle(mesh, tri) < worth {
                        next.push(idx);
                    }
                }
                changed += 1;
            }
        }
        flips += changed;
        if changed == 0 {
            break;
        }
        next.sort_unstable();
        next.dedup();
        candidates = next;
    }
    flips
}

/// Collapses into its midpoint every edge shorter than `min_length`, and the short edge of
/// every needle (a triangle with an angle under [`NEEDLE_DEG`] whose shortest edge is under
/// half its next), where the two vertices share exactly two neighbours (the link condition:
/// the surface stays a closed manifold) and no triangle around them turns over; returns the
/// collapses made.
fn collapse_short_edges(mesh: &mut TriMesh, min_length: f64) -> usize {
    let length = |mesh: &TriMesh, a: u32, b: u32| {
        (mesh.vertices[a as usize] - mesh.vertices[b as usize]).norm()
    };
    let wanted = |mesh: &TriMesh, t: [u32; 3]| {
        let mut edges: [(f64, u32, u32); 3] =
            std::array::from_fn(|e| (length(mesh, t[e], t[(e + 1) % 3]), t[e], t[(e + 1) % 3]));
        edges.sort_by(|x, y| x.0.total_cmp(&y.0));
        let smallest = min_angle(mesh, t);
        let needle = smallest < NEEDLE_DEG.to_radians() && edges[0].0 < 0.5 * edges[1].0;
        // A cap (one angle near 180 degrees) has two short edges of about equal length: no
        // needle, and a flip cannot always take it (its neighbour bends away). It goes too.
        let cap = smallest < CAP_DEG.to_radians();
        // Shortest first; a cap may go by either of its short edges.
        let count = if cap {
            2
        } else {
            usize::from(edges[0].0 < min_length || needle)
        };
        edges.into_iter().take(count).map(|(_, a, b)| (a, b))
    };
    if !mesh
        .triangles
        .iter()
        .any(|t| wanted(mesh, *t).next().is_some())
    {
        return 0;
    }
    let mut collapses = 0;
    let mut removed = vec![false; mesh.triangles.len()];
    let mut nb: Vec<FxHashSet<u32>> = neighbours(mesh)
        .into_iter()
        .map(|l| l.into_iter().collect())
        .collect();
    // Triangles around each vertex.
    let mut around: Vec<Vec<usize>> = vec![Vec::new(); mesh.vertices.len()];
    for (k, t) in mesh.triangles.iter().enumerate() {
        for &v in t {
            around[v as usize].push(k);
        }
    }
    for k in 0..mesh.triangles.len() {
        if removed[k] {
            continue;
        }
        for (a, b) in wanted(mesh, mesh.triangles[k]) {
            let shared = nb[a as usize].intersection(&nb[b as usize]).count();
            if shared != 2 || nb[a as usize].len() <= 3 || nb[b as usize].len() <= 3 {
                continue;
            }
            // Where the joined vertex goes: the midpoint, or else one of the two ends (on a sharp
            // edge the midpoint can turn a triangle over where an end keeps the edge). No
            // triangle that stays may turn over.
            let (va, vb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
            let turns_over = |to: Vector3<f64>| {
                around[a as usize]
                    .iter()
                    .chain(&around[b as usize])
                    .filter(|&&j| !removed[j])
                    .any(|&j| {
                        let tri = mesh.triangles[j];
                        if tri.contains(&a) && tri.contains(&b) {
                            return false;
                        }
                        let before = normal(mesh, tri);
                        let corners = tri.map(|v| {
                            if v == a || v == b {
                                to
                            } else {
                                mesh.vertices[v as usize]
                            }
                        });
                        let after = (corners[1] - corners[0]).cross(&(corners[2] - corners[0]));
                        after.dot(&before) <= 0.0
                    })
            };
            let Some(joined) = [0.5 * (va + vb), va, vb]
                .into_iter()
                .find(|&to| !turns_over(to))
            else {
                continue;
            };
            // Move a to where they join, send b's triangles to a, drop the two on the edge.
            mesh.vertices[a as usize] = joined;
            let b_tris = std::mem::take(&mut around[b as usize]);
            for &j in &b_tris {
                if removed[j] {
                    continue;
                }
                let tri = &mut mesh.triangles[j];
                if tri.contains(&a) {
                    removed[j] = true;
                    continue;
                }
                for v in tri.iter_mut() {
                    if *v == b {
                        *v = a;
                    }
                }
                around[a as usize].push(j);
            }
            let b_nb: Vec<u32> = nb[b as usize].drain().collect();
            for n in b_nb {
                nb[n as usize].remove(&b);
                if n != a {
                    nb[n as usize].insert(a);
                    nb[a as usize].insert(n);
                }
            }
            nb[a as usize].remove(&b);
            collapses += 1;
            break;
        }
    }
    mesh.triangles = mesh
        .triangles
        .iter()
        .zip(&removed)
        .filter(|(_, r)| !**r)
        .map(|(t, _)| *t)
        .collect();
    collapses
}

/// How a surface measures (see [`SurfaceQuality`]).
pub fn quality(mesh: &TriMesh) -> SurfaceQuality {
    let shells = shells(mesh);
    let void_shells = shells
        .iter()
        .filter(|s| shell_volume(mesh, s) <= 0.0)
        .count();
    let parts = mesh.parts();
    let genus = parts.iter().map(|p| p.genus).sum::<Option<i64>>();
    let areas: Vec<f64> = mesh
        .triangles
        .iter()
        .map(|t| 0.5 * normal(mesh, *t).norm())
        .collect();
    let mean = areas.iter().sum::<f64>() / areas.len().max(1) as f64;
    let mut min_angle_deg = 180.0f64;
    let mut under = 0;
    for t in &mesh.triangles {
        let m = min_angle(mesh, *t).to_degrees();
        min_angle_deg = min_angle_deg.min(m);
        under += usize::from(m < 5.0);
    }
    SurfaceQuality {
        shells: shells.len(),
        void_shells,
        genus,
        min_angle_deg,
        under_5_deg: under as f64 / mesh.triangles.len().max(1) as f64,
        zero_area: areas.iter().filter(|a| **a < 1e-12 * mean).count(),
        triangles: mesh.triangles.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::extract_surface;

    /// A ball with a void inside and a few stray particles: cleaning leaves one closed shell
    /// of genus 0 that keeps the ball's volume within a few percent, with better angles.
    #[test]
    fn voids_and_islands_go_and_angles_improve() {
        let h = 1.0;
        let mut x = Vec::new();
        for i in -8i32..=8 {
            for j in -8i32..=8 {
                for k in -8i32..=8 {
                    let p = Vector3::new(i as f64, j as f64, k as f64) * h;
                    let r = p.norm();
                    if r < 8.0 && r > 3.0 {
                        x.push(p);
                    }
                }
            }
        }
        for c in 0..8 {
            let d = Vector3::new((c & 1) as f64, ((c >> 1) & 1) as f64, ((c >> 2) & 1) as f64);
            x.push(Vector3::new(20.0, 0.0, 0.0) + d * h);
        }
        let volumes = vec![h * h * h; x.len()];
        let raw = extract_surface(&x, &volumes, h).unwrap();
        let before = quality(&raw);
        assert_eq!((before.shells, before.void_shells), (3, 1), "{before:?}");
        let (clean, report) = clean(&raw, h);
        let after = quality(&clean);
        assert_eq!((report.voids, report.islands), (1, 1), "{report:?}");
        assert_eq!(
            (after.shells, after.void_shells, after.genus),
            (1, 0, Some(0)),
            "{after:?}"
        );
        assert!(clean.topology().is_closed());
        assert!(
            after.min_angle_deg > before.min_angle_deg,
            "{before:?} -> {after:?}"
        );
        assert_eq!(after.zero_area, 0);
        assert!(report.smoothing_volume_change.abs() < 0.03, "{report:?}");
    }
}
