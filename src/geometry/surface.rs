//! Particles back to a closed surface, for every exported frame.
//!
//! Each particle spreads its current volume over a lattice of spacing `h` with the quadratic
//! B-spline (so a lattice of particles `h` apart gives a fill fraction of exactly 1 inside
//! and 1/2 on its boundary faces). The surface is the 1/2 level set, extracted by marching
//! tetrahedra: every lattice cell is split into six tetrahedra around its main diagonal (the
//! same split in every cell, so neighbouring cells agree on their shared faces). Unlike the
//! classic marching-cubes table this has no ambiguous cases, so the output is always closed:
//! each edge is shared by exactly two triangles. (We write this ourselves for that
//! guarantee; the marching-cubes crates we looked at either leave ambiguous-face cracks or
//! produce non-manifold surface nets.)

use super::mesh::{Aabb, TriMesh};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// Fill fraction at the surface.
const ISO: f64 = 0.5;
/// Empty lattice layers around the particles: the B-spline reaches 1.5 h, plus margin, so the
/// outermost layer is zero and the surface cannot touch the lattice boundary.
const PAD: usize = 3;

/// Largest fill lattice we build (nodes); a frame whose particles spread wider is refused.
const MAX_NODES: usize = 1 << 28;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SurfaceError {
    #[error("surface extraction: particle {0} has a non-finite position or volume")]
    NonFinite(usize),
    #[error("surface extraction: spacing must be positive and finite, got {0}")]
    BadSpacing(f64),
    #[error(
        "surface extraction: the particles spread over {0} lattice nodes (limit {MAX_NODES}); use a larger spacing"
    )]
    TooLarge(usize),
    #[error("surface extraction: {0}")]
    External(String),
}

/// A closed surface around `positions`, each of which stands for volume `volumes[p]`
/// (current volume: rest volume times J). `spacing` is the lattice spacing, normally the
/// particles' rest spacing `dx / per_cell`.
pub fn extract_surface(
    positions: &[Vector3<f64>],
    volumes: &[f64],
    spacing: f64,
) -> Result<TriMesh, SurfaceError> {
    Ok(fill_field(positions, volumes, spacing)?.march())
}

/// The fill field [`extract_surface`] takes its surface from (the particles' volumes spread
/// with the quadratic B-spline; 1 inside, 1/2 on the surface).
pub fn fill_field(
    positions: &[Vector3<f64>],
    volumes: &[f64],
    spacing: f64,
) -> Result<FillField, SurfaceError> {
    assert_eq!(positions.len(), volumes.len(), "one volume per particle");
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(SurfaceError::BadSpacing(spacing));
    }
    if let Some(p) = (0..positions.len())
        .find(|&p| !(positions[p].iter().all(|c| c.is_finite()) && volumes[p].is_finite()))
    {
        return Err(SurfaceError::NonFinite(p));
    }
    if positions.is_empty() {
        return Ok(FillField::empty(spacing));
    }
    let extent = Aabb::of_points(positions).extent() / spacing;
    let nodes = extent
        .iter()
        .map(|e| e.ceil() + (2 * PAD + 1) as f64)
        .product::<f64>();
    if nodes > MAX_NODES as f64 {
        return Err(SurfaceError::TooLarge(nodes as usize));
    }
    Ok(FillField::splat(positions, volumes, spacing))
}

/// How wide each particle's kernel is in [`extract_deformed_surface`], in particle spacings
/// along each rest axis (an integer, so rest lattices fill exactly; see there).
pub const DEFORMED_KERNEL_WIDTH: usize = 2;

/// A closed surface around particles that carry their deformation: particle `p` at
/// `positions[p]` stands for the material of a rest cell of `rest_volume` deformed by
/// `deformation[p]` (`F`). Its share of the fill field is the cubic B-spline of width `w`
/// rest spacings ([`DEFORMED_KERNEL_WIDTH`]) evaluated in the particle's rest frame,
///
/// ```text
///   fill(x) = sum_p rest_volume / (w h)^3  N(F_p^-1 (x - x_p) / (w h))
/// ```
///
/// so the kernel is an ellipsoid that stretches, shears and turns with the material. For a
/// lattice of particles `h` apart under any one affine deformation the fill is exactly 1
/// inside and exactly 1/2 where the deformed cells end (the cubic B-spline at an integer
/// width is a partition of unity, symmetric about the half-spacing): the surface sits where
/// the material ends, parts along a stretch stay closed, and the kernel's width smooths the
/// rest lattice's steps that show as bumps with a narrow kernel.
pub fn extract_deformed_surface(
    positions: &[Vector3<f64>],
    deformation: &[Matrix3<f64>],
    rest_volume: f64,
    spacing: f64,
) -> Result<TriMesh, SurfaceError> {
    Ok(deformed_fill_field(positions, deformation, rest_volume, None, spacing)?.march())
}

/// The fill field [`extract_deformed_surface`] takes its surface from. `edge_weights`, one per
/// particle (from [`edge_weights`]), scale each particle's kernel; `None` weighs every one 1.
pub fn deformed_fill_field(
    positions: &[Vector3<f64>],
    deformation: &[Matrix3<f64>],
    rest_volume: f64,
    edge_weights: Option<&[f64]>,
    spacing: f64,
) -> Result<FillField, SurfaceError> {
    assert_eq!(positions.len(), deformation.len(), "one F per particle");
    if let Some(w) = edge_weights {
        assert_eq!(positions.len(), w.len(), "one edge weight per particle");
    }
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(SurfaceError::BadSpacing(spacing));
    }
    if let Some(p) = (0..positions.len()).find(|&p| {
        !(positions[p].iter().all(|c| c.is_finite())
            && deformation[p].iter().all(|c| c.is_finite()))
    }) {
        return Err(SurfaceError::NonFinite(p));
    }
    if positions.is_empty() {
        return Ok(FillField::empty(spacing));
    }
    let clipped: Vec<Matrix3<f64>> = deformation.par_iter().map(clip_stretch).collect();
    let reach = 2.0 * DEFORMED_KERNEL_WIDTH as f64 * spacing * max_row_sum(&clipped);
    let extent = (Aabb::of_points(positions).extent() + Vector3::repeat(2.0 * reach)) / spacing;
    let nodes = extent.iter().map(|e| e.ceil() + 3.0).product::<f64>();
    if nodes > MAX_NODES as f64 {
        return Err(SurfaceError::TooLarge(nodes as usize));
    }
    Ok(FillField::splat_deformed(
        positions,
        &clipped,
        rest_volume,
        edge_weights,
        spacing,
        reach,
    ))
}

/// How much each particle's kernel weighs in the deformed fill field, from where the source's
/// surface passes between the particles at rest (`positions`, inside `surface`, `spacing`
/// apart). A particle stands for its lattice cell, but the surface cuts the outermost cells
/// anywhere: a particle `d` spacings inside it (`d < 1`) weighs `d + 1/2`, the share of its
/// own cell inside plus that of the empty cell beyond it, and every deeper one weighs 1.
/// With equal weights the field's 1/2 level lies half a spacing past the outermost particles
/// wherever the surface passes, so a curved source shows the lattice's steps as ripples;
/// with these it lies within 0.12 spacings of the surface (a flat face along a lattice
/// axis; 0.5 before), and over a layer of particles the weights add up to the same as
/// equal ones. The particle carries its weight as it deforms.
pub fn edge_weights(surface: &TriMesh, positions: &[Vector3<f64>], spacing: f64) -> Vec<f64> {
    let Some(reference) = super::fidelity::Reference::new(surface) else {
        return vec![1.0; positions.len()];
    };
    positions
        .par_iter()
        .map(|x| {
            let d = reference.distance(x) / spacing;
            if d < 1.0 { d + 0.5 } else { 1.0 }
        })
        .collect()
}

/// The largest row sum of `|F|` over the particles: how far, in rest half-widths, a
/// particle's kernel box reaches along a lattice axis.
fn max_row_sum(deformation: &[Matrix3<f64>]) -> f64 {
    deformation
        .iter()
        .flat_map(|f| (0..3).map(move |a| f.row(a).abs().sum()))
        .fold(1.0f64, f64::max)
}

/// Largest principal stretch a kernel takes (and smallest, its inverse): beyond it a
/// particle's ellipsoid is clipped (a strand pulled that thin is below what the lattice
/// resolves, and a torn-off particle cannot blow the lattice up).
const MAX_KERNEL_STRETCH: f64 = 4.0;

/// The cubic B-spline (support [-2, 2], integral 1).
fn cubic(t: f64) -> f64 {
    // Branch-free form of the piecewise cubic (the splat's inner loop vectorizes):
    // ((2 - |t|)_+^3 - 4 (1 - |t|)_+^3) / 6.
    let a = t.abs();
    let b = (2.0 - a).max(0.0);
    let c = (1.0 - a).max(0.0);
    (b * b * b - 4.0 * c * c * c) * (1.0 / 6.0)
}

/// The nodes `k` in `lo..=hi` where every coordinate of `start + k step` is inside the
/// cubic's support (-2, 2), as one run (the support is convex), or `None`.
fn support_run(
    start: &Vector3<f64>,
    step: &Vector3<f64>,
    lo: usize,
    hi: usize,
) -> Option<(usize, usize)> {
    let (mut a, mut b) = (lo as f64, hi as f64);
    for c in 0..3 {
        if step[c] == 0.0 {
            if start[c].abs() >= 2.0 {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((-2.0 - start[c]) / step[c], (2.0 - start[c]) / step[c]);
        a = a.max(t0.min(t1));
        b = b.min(t0.max(t1));
    }
    // Endpoints are rounded inward; a node exactly on the edge weighs zero anyway.
    let (k0, k1) = (a.ceil(), b.floor());
    (k0 <= k1).then_some((k0 as usize, k1 as usize))
}

/// Fill fraction on a lattice: node (i, j, k) at `origin + h * (i, j, k)`, x slowest and z
/// fastest in `values`. The rebuilt surface is its 1/2 level set; `--volume` writes it as a
/// density grid.
pub struct FillField {
    pub origin: Vector3<f64>,
    pub h: f64,
    pub dims: [usize; 3],
    pub values: Vec<f64>,
}

impl FillField {
    /// No particles: an empty lattice (its surface is empty).
    fn empty(h: f64) -> FillField {
        FillField {
            origin: Vector3::zeros(),
            h,
            dims: [0; 3],
            values: Vec::new(),
        }
    }

    fn splat(positions: &[Vector3<f64>], volumes: &[f64], h: f64) -> FillField {
        let bounds = Aabb::of_points(positions);
        let origin = bounds.min - Vector3::repeat(PAD as f64 * h);
        let dims = [0, 1, 2].map(|a| (bounds.extent()[a] / h).ceil() as usize + 2 * PAD + 1);
        let mut values = vec![0.0; dims[0] * dims[1] * dims[2]];
        let inv_h3 = 1.0 / (h * h * h);
        // Sequential on purpose: a fixed summation order keeps frames bitwise reproducible,
        // and 27 adds per particle are a small part of the extraction time.
        for (x, &vol) in positions.iter().zip(volumes) {
            let g = (x - origin) / h;
            let mut base = [0usize; 3];
            let mut w = [[0.0; 3]; 3];
            for a in 0..3 {
                let b = (g[a] - 0.5).floor();
                let f = g[a] - b; // in [0.5, 1.5)
                base[a] = b as usize;
                w[a] = [
                    0.5 * (1.5 - f).powi(2),
                    0.75 - (f - 1.0).powi(2),
                    0.5 * (f - 0.5).powi(2),
                ];
            }
            let fill = vol * inv_h3;
            for (di, wi) in w[0].iter().enumerate() {
                for (dj, wj) in w[1].iter().enumerate() {
                    let row = ((base[0] + di) * dims[1] + base[1] + dj) * dims[2] + base[2];
                    for (dk, wk) in w[2].iter().enumerate() {
                        values[row + dk] += fill * wi * wj * wk;
                    }
                }
            }
        }
        FillField {
            origin,
            h,
            dims,
            values,
        }
    }

    /// The field of [`extract_deformed_surface`]. The lattice is cut into x-slabs; each slab
    /// sums the particles that reach it in particle order, so the field is the same for any
    /// thread count.
    fn splat_deformed(
        positions: &[Vector3<f64>],
        deformation: &[Matrix3<f64>],
        rest_volume: f64,
        edge_weights: Option<&[f64]>,
        h: f64,
        reach: f64,
    ) -> FillField {
        let bounds = Aabb::of_points(positions);
        let pad = (reach / h).ceil() + 1.0;
        let origin = bounds.min - Vector3::repeat(pad * h);
        let dims =
            [0, 1, 2].map(|a| (bounds.extent()[a] / h).ceil() as usize + 2 * pad as usize + 1);
        let s = DEFORMED_KERNEL_WIDTH as f64 * h;
        let weight = rest_volume / (s * s * s);
        // Per particle: the map from a lattice offset to rest-frame kernel coordinates, and the
        // box of nodes its kernel reaches.
        let kernels: Vec<(Matrix3<f64>, [usize; 3], [usize; 3])> = positions
            .iter()
            .zip(deformation)
            .map(|(x, f)| {
                let inv = f.try_inverse().unwrap_or_else(Matrix3::identity) / s;
                // Half-widths of the support box: 2 s times the row sums of |F| (the box
                // around F times the kernel's cube).
                let g = (x - origin) / h;
                let mut lo = [0usize; 3];
                let mut hi = [0usize; 3];
                for a in 0..3 {
                    let half = 2.0 * s * f.row(a).abs().sum() / h;
                    lo[a] = (g[a] - half).ceil().max(0.0) as usize;
                    hi[a] = ((g[a] + half).floor() as usize).min(dims[a] - 1);
                }
                (inv, lo, hi)
            })
            .collect();
        let [nx, ny, nz] = dims;
        let mut values = vec![0.0; nx * ny * nz];
        // Each chunk of `slab` x-layers lists the particles whose box reaches it, in order.
        let slab = 4usize;
        let chunks: Vec<(usize, Vec<usize>)> = (0..nx.div_ceil(slab))
            .map(|c| {
                let (a, b) = (c * slab, ((c + 1) * slab).min(nx));
                let list = (0..positions.len())
                    .filter(|&p| kernels[p].1[0] < b && kernels[p].2[0] >= a)
                    .collect();
                (c, list)
            })
            .collect();
        values
            .par_chunks_mut(slab * ny * nz)
            .zip(chunks.par_iter())
            .for_each(|(out, (c, list))| {
                let i0 = c * slab;
                let i1 = (i0 + slab).min(nx);
                for &p in list {
                    let (inv, lo, hi) = &kernels[p];
                    let weight = edge_weights.map_or(weight, |w| weight * w[p]);
                    // The kernel coordinate is affine in the node index: u = base + i di +
                    // j dj + k dk. Along a row of k only the nodes with every |u_a| < 2 (the
                    // cubic's support) are visited.
                    let base = inv * (origin - positions[p]);
                    let [di, dj, dk] = [0, 1, 2].map(|a| h * inv.column(a).into_owned());
                    for i in lo[0].max(i0)..=hi[0].min(i1 - 1) {
                        for j in lo[1]..=hi[1] {
                            let row = ((i - i0) * ny + j) * nz;
                            let start = base + i as f64 * di + j as f64 * dj;
                            let Some((k0, k1)) = support_run(&start, &dk, lo[2], hi[2]) else {
                                continue;
                            };
                            for k in k0..=k1 {
                                let u = start + k as f64 * dk;
                                out[row + k] += weight * cubic(u.x) * cubic(u.y) * cubic(u.z);
                            }
                        }
                    }
                }
            });
        FillField {
            origin,
            h,
            dims,
            values,
        }
    }

    fn node(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.dims[1] + j) * self.dims[2] + k
    }

    /// The fill at `x`, trilinear between the lattice's nodes (0 outside it).
    pub fn sample(&self, x: &Vector3<f64>) -> f64 {
        let g = (x - self.origin) / self.h;
        let mut base = [0usize; 3];
        let mut t = [0.0; 3];
        for a in 0..3 {
            let f = g[a].floor();
            if !(f >= 0.0 && (f as usize) + 1 < self.dims[a]) {
                return 0.0;
            }
            base[a] = f as usize;
            t[a] = g[a] - f;
        }
        let mut sum = 0.0;
        for corner in 0..8 {
            let o = [corner >> 2 & 1, corner >> 1 & 1, corner & 1];
            let w: f64 = (0..3)
                .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
                .product();
            sum += w * self.values[self.node(base[0] + o[0], base[1] + o[1], base[2] + o[2])];
        }
        sum
    }

    /// The fill's surface level (the rebuilt surface is this level set).
    pub const LEVEL: f64 = ISO;

    fn position(&self, id: usize) -> Vector3<f64> {
        let k = id % self.dims[2];
        let j = (id / self.dims[2]) % self.dims[1];
        let i = id / (self.dims[1] * self.dims[2]);
        self.origin + self.h * Vector3::new(i as f64, j as f64, k as f64)
    }

    /// The closed surface at fill 1/2, by marching tetrahedra. Triangles are found per x-slab in parallel as triples of edge
    /// keys; vertices are then numbered in order of first use, so the output is the same
    /// for any thread count.
    pub fn march(&self) -> TriMesh {
        let [nx, ny, nz] = self.dims;
        if nx < 2 || ny < 2 || nz < 2 {
            return TriMesh::default();
        }
        // Lattice offset of cube corner c (bit 0: +x, bit 1: +y, bit 2: +z).
        let corner_offset: [usize; 8] =
            std::array::from_fn(|c| (c & 1) * ny * nz + ((c >> 1) & 1) * nz + ((c >> 2) & 1));
        let tets = kuhn_tetrahedra();
        let slabs: Vec<Vec<[u64; 3]>> = (0..nx - 1)
            .into_par_iter()
            .map(|i| {
                let mut tris = Vec::new();
                for j in 0..ny - 1 {
                    for k in 0..nz - 1 {
                        let base = self.node(i, j, k);
                        let f: [f64; 8] =
                            std::array::from_fn(|c| self.values[base + corner_offset[c]]);
                        let inside = f.iter().filter(|&&v| v > ISO).count();
                        if inside == 0 || inside == 8 {
                            continue;
                        }
                        for tet in &tets {
                            march_tet(tet, &f, base, &corner_offset, &mut tris);
                        }
                    }
                }
                tris
            })
            .collect();
        let mut index: FxHashMap<u64, u32> = FxHashMap::default();
        let mut mesh = TriMesh::default();
        for tris in slabs {
            for key_tri in tris {
                let tri = key_tri.map(|key| {
                    *index.entry(key).or_insert_with(|| {
                        mesh.vertices.push(self.edge_point(key));
                        (mesh.vertices.len() - 1) as u32
                    })
                });
                mesh.triangles.push(tri);
            }
        }
        mesh
    }

    /// The level-set point on the lattice edge `key`, interpolated from its lower node, so
    /// every tetrahedron that shares the edge gets the same point.
    fn edge_point(&self, key: u64) -> Vector3<f64> {
        let lo = (key >> 3) as usize;
        let mask = (key & 7) as usize;
        let [_, ny, nz] = self.dims;
        let hi = lo + (mask & 1) * ny * nz + ((mask >> 1) & 1) * nz + ((mask >> 2) & 1);
        let (flo, fhi) = (self.values[lo], self.values[hi]);
        let t = ((ISO - flo) / (fhi - flo)).clamp(0.0, 1.0);
        let (xlo, xhi) = (self.position(lo), self.position(hi));
        xlo + t * (xhi - xlo)
    }
}

/// `f` with its singular values clipped to [1 / MAX_KERNEL_STRETCH, MAX_KERNEL_STRETCH]
/// (unchanged when they already are: then only the singular values are computed).
fn clip_stretch(f: &Matrix3<f64>) -> Matrix3<f64> {
    let norm = f.norm();
    if norm <= MAX_KERNEL_STRETCH && f.determinant() > 0.0 {
        let svd = f.svd(false, false);
        if svd.singular_values.min() >= 1.0 / MAX_KERNEL_STRETCH {
            return *f;
        }
    }
    let svd = f.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    let clipped = svd
        .singular_values
        .map(|s| s.clamp(1.0 / MAX_KERNEL_STRETCH, MAX_KERNEL_STRETCH));
    let r = u * Matrix3::from_diagonal(&clipped) * v_t;
    if r.determinant() > 0.0 {
        r
    } else {
        Matrix3::identity()
    }
}

/// The six tetrahedra of a cube around its 0-7 diagonal, as cube-corner indices, each with
/// positive orientation. Corners of one tetrahedron form a chain 0 < e_a < e_a + e_b < 7,
/// so each of its edges joins a corner to one whose bits contain it.
fn kuhn_tetrahedra() -> [[usize; 4]; 6] {
    let perms = [
        [0, 1, 2],
        [1, 2, 0],
        [2, 0, 1],
        [0, 2, 1],
        [2, 1, 0],
        [1, 0, 2],
    ];
    perms.map(|[a, b, _]| {
        let (v1, v2) = (1 << a, (1 << a) | (1 << b));
        // Orientation of (e_a, e_a + e_b, 1) is the parity of the permutation.
        if [[0, 1, 2], [1, 2, 0], [2, 0, 1]].contains(&[a, b, 3 - a - b]) {
            [0, v1, v2, 7]
        } else {
            [0, v2, v1, 7]
        }
    })
}

/// Parity of a permutation of four distinct items (true when odd).
fn odd(p: [usize; 4]) -> bool {
    let mut inversions = 0;
    for i in 0..4 {
        for j in i + 1..4 {
            if p[i] > p[j] {
                inversions += 1;
            }
        }
    }
    inversions % 2 == 1
}

/// Adds the triangles of one positively oriented tetrahedron (cube corners `tet`), with
/// normals pointing from the inside (fill > 1/2) out.
fn march_tet(
    tet: &[usize; 4],
    f: &[f64; 8],
    base: usize,
    corner_offset: &[usize; 8],
    out: &mut Vec<[u64; 3]>,
) {
    let inside: [bool; 4] = std::array::from_fn(|v| f[tet[v]] > ISO);
    let count = inside.iter().filter(|b| **b).count();
    if count == 0 || count == 4 {
        return;
    }
    // Key of the lattice edge between tetrahedron vertices a and b.
    let edge = |a: usize, b: usize| -> u64 {
        let (ca, cb) = (tet[a], tet[b]);
        let (lo, hi) = if ca & cb == ca { (ca, cb) } else { (cb, ca) };
        (((base + corner_offset[lo]) as u64) << 3) | (hi ^ lo) as u64
    };
    let (ins, outs): (Vec<usize>, Vec<usize>) = (0..4).partition(|&v| inside[v]);
    match count {
        1 | 3 => {
            // The lone vertex a, the others ordered so (a, b, c, d) is even: the triangle
            // (ab, ac, ad) then faces away from a.
            let a = if count == 1 { ins[0] } else { outs[0] };
            let mut rest: Vec<usize> = (0..4).filter(|&v| v != a).collect();
            if odd([a, rest[0], rest[1], rest[2]]) {
                rest.swap(1, 2);
            }
            let (ab, ac, ad) = (edge(a, rest[0]), edge(a, rest[1]), edge(a, rest[2]));
            if count == 1 {
                out.push([ab, ac, ad]);
            } else {
                out.push([ab, ad, ac]);
            }
        }
        _ => {
            let (a, b) = (ins[0], ins[1]);
            let (mut c, mut d) = (outs[0], outs[1]);
            if odd([a, b, c, d]) {
                std::mem::swap(&mut c, &mut d);
            }
            let (ac, ad, bd, bc) = (edge(a, c), edge(a, d), edge(b, d), edge(b, c));
            out.push([ac, ad, bd]);
            out.push([ac, bd, bc]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kuhn_tetrahedra_are_positive_and_fill_the_cube() {
        let corner =
            |c: usize| Vector3::new((c & 1) as f64, ((c >> 1) & 1) as f64, (c >> 2) as f64);
        let mut total = 0.0;
        for t in kuhn_tetrahedra() {
            let [a, b, c, d] = t.map(corner);
            let det = (b - a).dot(&(c - a).cross(&(d - a)));
            assert!(det > 0.0);
            total += det / 6.0;
        }
        assert!((total - 1.0).abs() < 1e-15);
    }

    /// Where the deformed field first reaches 1/2 along the x axis through the centre
    /// (linear between nodes, as marching does).
    fn half_crossing(field: &FillField, centre: &Vector3<f64>) -> f64 {
        let [_, ny, nz] = field.dims;
        let (j, k) = [1, 2]
            .map(|a| ((centre[a] - field.origin[a]) / field.h).round() as usize)
            .into();
        let at = |i: usize| field.values[(i * ny + j) * nz + k];
        let i = (1..field.dims[0]).find(|&i| at(i) >= 0.5).unwrap();
        let t = (0.5 - at(i - 1)) / (at(i) - at(i - 1));
        field.origin.x + field.h * (i as f64 - 1.0 + t)
    }

    /// A face that passes anywhere between the particle layers: with edge weights the field's
    /// 1/2 level lies within 0.12 spacings of it; with equal weights it lies half a spacing
    /// past the outermost layer, up to 0.5 spacings off.
    #[test]
    fn edge_weights_put_the_surface_where_the_mesh_is() {
        let h = 0.1;
        let cube = super::super::assets::cube(2.0, 8);
        for d in [0.05, 0.3, 0.5, 0.75, 0.95] {
            let mut positions = Vec::new();
            for i in 0..((2.0 - d * h) / h) as usize {
                for j in 0..20 {
                    for k in 0..20 {
                        let at = |n: usize| -0.95 + n as f64 * h;
                        positions.push(Vector3::new(-1.0 + (d + i as f64) * h, at(j), at(k)));
                    }
                }
            }
            let rest = vec![Matrix3::identity(); positions.len()];
            let weights = edge_weights(&cube, &positions, h);
            let off = |w: Option<&[f64]>| {
                let field = deformed_fill_field(&positions, &rest, h * h * h, w, h).unwrap();
                (half_crossing(&field, &Vector3::new(0.0, 0.05, 0.05)) + 1.0) / h
            };
            let (weighted, equal) = (off(Some(&weights)), off(None));
            assert!(weighted.abs() <= 0.12, "d = {d}: weighted {weighted}");
            assert!((equal - (d - 0.5)).abs() <= 0.01, "d = {d}: equal {equal}");
        }
    }

    #[test]
    fn single_particle_gives_a_closed_blob() {
        let mesh = extract_surface(&[Vector3::new(0.1, 0.2, 0.3)], &[1.0], 1.0).unwrap();
        // A lone particle of volume h^3 peaks at a fill of 0.75^3 = 0.42 < 1/2: no surface.
        // With spacing 0.5 its volume counts as 8 lattice volumes and a blob appears.
        assert!(mesh.triangles.is_empty());
        let mesh = extract_surface(&[Vector3::new(0.1, 0.2, 0.3)], &[1.0], 0.5).unwrap();
        assert!(!mesh.triangles.is_empty());
        assert!(mesh.topology().is_closed());
        assert!(mesh.signed_volume() > 0.0);
    }

    #[test]
    fn bad_input_is_an_error() {
        let x = [Vector3::zeros(), Vector3::new(f64::NAN, 0.0, 0.0)];
        assert_eq!(
            extract_surface(&x, &[1.0, 1.0], 0.5),
            Err(SurfaceError::NonFinite(1))
        );
        let far = [Vector3::zeros(), Vector3::repeat(1e9)];
        assert!(matches!(
            extract_surface(&far, &[1.0, 1.0], 0.5),
            Err(SurfaceError::TooLarge(_))
        ));
        assert!(extract_surface(&x[..1], &[1.0], 0.0).is_err());
    }
}
