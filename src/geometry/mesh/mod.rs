//! Triangle meshes: loading (OBJ through tobj, PLY through ply-rs-bw), validation, topology
//! statistics, orientation repair and atomic OBJ writing.

use nalgebra::Vector3;
use rustc_hash::FxHashMap;
use std::io::Write;
use std::path::Path;

mod load;

pub use load::*;

/// Triangles bending more than this from each other meet at a crease in
/// [`TriMesh::corner_normals`] (Blender's "smooth by angle" default is 30).
pub const CREASE_DEG: f64 = 40.0;

/// An indexed triangle mesh in f64.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub vertices: Vec<Vector3<f64>>,
    pub triangles: Vec<[u32; 3]>,
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vector3<f64>,
    pub max: Vector3<f64>,
}

impl Aabb {
    pub fn empty() -> Self {
        Aabb {
            min: Vector3::repeat(f64::INFINITY),
            max: Vector3::repeat(f64::NEG_INFINITY),
        }
    }

    pub fn of_points<'a>(points: impl IntoIterator<Item = &'a Vector3<f64>>) -> Self {
        let mut b = Aabb::empty();
        for p in points {
            b.grow(p);
        }
        b
    }

    pub fn grow(&mut self, p: &Vector3<f64>) {
        self.min = self.min.inf(p);
        self.max = self.max.sup(p);
    }

    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.inf(&o.min),
            max: self.max.sup(&o.max),
        }
    }

    pub fn extent(&self) -> Vector3<f64> {
        self.max - self.min
    }

    pub fn centre(&self) -> Vector3<f64> {
        0.5 * (self.min + self.max)
    }

    pub fn longest_side(&self) -> f64 {
        self.extent().max()
    }
}

/// Edge statistics of a mesh (edges are unordered vertex pairs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Topology {
    pub edges: usize,
    /// Edges used by exactly one triangle (holes).
    pub boundary_edges: usize,
    /// Edges used by three or more triangles.
    pub non_manifold_edges: usize,
    /// Edges that two triangles traverse in the same direction (inconsistent orientation).
    pub misoriented_edges: usize,
}

/// One connected part of a mesh.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PartTopology {
    pub triangles: usize,
    pub vertices: usize,
    pub boundary_edges: usize,
    pub non_manifold_edges: usize,
    /// V - E + F of the part.
    pub euler_characteristic: i64,
    /// Holes through the part (a sphere 0, a torus 1), for a closed, consistently oriented
    /// manifold part; absent otherwise (then the Euler characteristic is what is known).
    pub genus: Option<i64>,
}

impl Topology {
    /// Closed: every edge is shared by exactly two triangles.
    pub fn is_closed(&self) -> bool {
        self.boundary_edges == 0 && self.non_manifold_edges == 0
    }
}

/// A point of [`TriMesh::area_samples`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AreaSample {
    pub point: Vector3<f64>,
    /// The area it stands for.
    pub area: f64,
    /// Its triangle's unit normal.
    pub normal: Vector3<f64>,
}

impl TriMesh {
    /// A mesh of `vertices` and triangles given by `usize` indices (a carried surface's).
    pub fn indexed(vertices: Vec<Vector3<f64>>, triangles: &[[usize; 3]]) -> TriMesh {
        let triangles = triangles.iter().map(|t| t.map(|v| v as u32)).collect();
        TriMesh {
            vertices,
            triangles,
        }
    }

    pub fn bounds(&self) -> Aabb {
        Aabb::of_points(&self.vertices)
    }

    pub fn corners(&self, t: &[u32; 3]) -> [Vector3<f64>; 3] {
        t.map(|i| self.vertices[i as usize])
    }

    /// Signed enclosed volume by the divergence theorem, about the bounding-box centre (which
    /// keeps round-off small for meshes far from the origin). Exact for closed meshes.
    pub fn signed_volume(&self) -> f64 {
        let c = self.bounds().centre();
        let mut sum = crate::loss::CompensatedSum::default();
        for t in &self.triangles {
            let [a, b, d] = self.corners(t).map(|p| p - c);
            sum.add(a.dot(&b.cross(&d)) / 6.0);
        }
        sum.value()
    }

    pub fn surface_area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }

    /// Points spread evenly over the surface, each with the area it stands for and its
    /// triangle's unit normal (zero for a triangle of no area): each triangle is cut into
    /// `n^2` equal sub-triangles (`n` from its longest edge over `gap`, at most 64) and
    /// sampled at their centroids.
    pub fn area_samples(&self, gap: f64) -> Vec<AreaSample> {
        let mut samples = Vec::new();
        for t in &self.triangles {
            let [a, b, c] = self.corners(t);
            let (u, v) = (b - a, c - a);
            let longest = u.norm().max(v.norm()).max((c - b).norm());
            let n = ((longest / gap).ceil() as usize).clamp(1, 64);
            let area = 0.5 * u.cross(&v).norm() / (n * n) as f64;
            let normal = u
                .cross(&v)
                .try_normalize(0.0)
                .unwrap_or_else(Vector3::zeros);
            let at = |i: f64, j: f64| a + u * (i / n as f64) + v * (j / n as f64);
            let mut push = |point| {
                samples.push(AreaSample {
                    point,
                    area,
                    normal,
                })
            };
            for i in 0..n {
                for j in 0..n - i {
                    push(at(i as f64 + 1.0 / 3.0, j as f64 + 1.0 / 3.0));
                    if i + j + 1 < n {
                        push(at(i as f64 + 2.0 / 3.0, j as f64 + 2.0 / 3.0));
                    }
                }
            }
        }
        samples
    }

    /// Counts boundary, non-manifold and misoriented edges.
    pub fn topology(&self) -> Topology {
        // Per unordered edge: (uses in the lo->hi direction, uses in the hi->lo direction).
        let mut uses: FxHashMap<(u32, u32), (u32, u32)> =
            FxHashMap::with_capacity_and_hasher(self.triangles.len() * 2, Default::default());
        for t in &self.triangles {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                let u = uses.entry((a.min(b), a.max(b))).or_default();
                if a < b {
                    u.0 += 1;
                } else {
                    u.1 += 1;
                }
            }
        }
        let mut topo = Topology {
            edges: uses.len(),
            boundary_edges: 0,
            non_manifold_edges: 0,
            misoriented_edges: 0,
        };
        for &(f, b) in uses.values() {
            match f + b {
                1 => topo.boundary_edges += 1,
                2 => {}
                _ => topo.non_manifold_edges += 1,
            }
            if f > 1 || b > 1 {
                topo.misoriented_edges += 1;
            }
        }
        topo
    }

    /// Merges vertices closer than `tolerance` (the first in file order is kept) and drops the
    /// triangles that collapse. Returns the merged and dropped counts. Unwelded exports (each
    /// face with its own corners, or vertices split at UV seams) become one connected
    /// surface, so the topology checks and the orientation repair see the real shape.
    pub fn weld(&mut self, tolerance: f64) -> (usize, usize) {
        if self.vertices.is_empty() || tolerance.is_nan() || tolerance <= 0.0 {
            return (0, 0);
        }
        let origin = self.bounds().min;
        let key = |v: &Vector3<f64>| ((v - origin) / tolerance).map(|c| c.floor() as i64);
        let mut cells: FxHashMap<[i64; 3], Vec<u32>> =
            FxHashMap::with_capacity_and_hasher(self.vertices.len(), Default::default());
        let mut remap = Vec::with_capacity(self.vertices.len());
        let mut kept: Vec<Vector3<f64>> = Vec::with_capacity(self.vertices.len());
        for v in &self.vertices {
            let k = key(v);
            let mut found = None;
            'search: for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let near = cells.get(&[k.x + dx, k.y + dy, k.z + dz]).and_then(|list| {
                            list.iter()
                                .find(|&&i| ((kept[i as usize] - v) / tolerance).norm() <= 1.0)
                        });
                        if let Some(&i) = near {
                            found = Some(i);
                            break 'search;
                        }
                    }
                }
            }
            let index = found.unwrap_or_else(|| {
                let i = kept.len() as u32;
                kept.push(*v);
                cells.entry([k.x, k.y, k.z]).or_default().push(i);
                i
            });
            remap.push(index);
        }
        let merged = self.vertices.len() - kept.len();
        let before = self.triangles.len();
        self.triangles = self
            .triangles
            .iter()
            .map(|t| t.map(|i| remap[i as usize]))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        self.vertices = kept;
        (merged, before - self.triangles.len())
    }

    /// The connected parts (triangles sharing vertices), each with its own topology.
    pub fn parts(&self) -> Vec<PartTopology> {
        let nv = self.vertices.len();
        let mut parent: Vec<u32> = (0..nv as u32).collect();
        fn find(parent: &mut [u32], mut i: u32) -> u32 {
            while parent[i as usize] != i {
                parent[i as usize] = parent[parent[i as usize] as usize];
                i = parent[i as usize];
            }
            i
        }
        for t in &self.triangles {
            let a = find(&mut parent, t[0]);
            for &v in &t[1..] {
                let b = find(&mut parent, v);
                if a != b {
                    parent[b as usize] = a;
                }
            }
        }
        // Parts numbered in order of their first triangle.
        let mut part_of_root: FxHashMap<u32, usize> = FxHashMap::default();
        let mut parts: Vec<TriMesh> = Vec::new();
        let mut local: Vec<FxHashMap<u32, u32>> = Vec::new();
        for t in &self.triangles {
            let root = find(&mut parent, t[0]);
            let p = *part_of_root.entry(root).or_insert_with(|| {
                parts.push(TriMesh::default());
                local.push(FxHashMap::default());
                parts.len() - 1
            });
            let (mesh, map) = (&mut parts[p], &mut local[p]);
            let tri = t.map(|v| {
                *map.entry(v).or_insert_with(|| {
                    mesh.vertices.push(self.vertices[v as usize]);
                    (mesh.vertices.len() - 1) as u32
                })
            });
            mesh.triangles.push(tri);
        }
        parts
            .iter()
            .map(|m| {
                let topo = m.topology();
                let euler = m.vertices.len() as i64 - topo.edges as i64 + m.triangles.len() as i64;
                let closed = topo.is_closed() && topo.misoriented_edges == 0;
                PartTopology {
                    triangles: m.triangles.len(),
                    vertices: m.vertices.len(),
                    boundary_edges: topo.boundary_edges,
                    non_manifold_edges: topo.non_manifold_edges,
                    euler_characteristic: euler,
                    genus: (closed && euler % 2 == 0).then_some((2 - euler) / 2),
                }
            })
            .collect()
    }

    /// Makes the orientation consistent across every manifold edge (flood fill per connected
    /// component) and then points each component outward (positive signed volume).
    /// Returns how many triangles were flipped.
    pub fn repair_orientation(&mut self) -> usize {
        let n = self.triangles.len();
        let mut by_edge: FxHashMap<(u32, u32), Vec<u32>> =
            FxHashMap::with_capacity_and_hasher(n * 2, Default::default());
        for (ti, t) in self.triangles.iter().enumerate() {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                by_edge
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push(ti as u32);
            }
        }
        let directed =
            |t: &[u32; 3], a: u32, b: u32| (0..3).any(|e| t[e] == a && t[(e + 1) % 3] == b);
        let mut component = vec![u32::MAX; n];
        let mut flip = vec![false; n];
        let mut components: Vec<Vec<u32>> = Vec::new();
        for seed in 0..n {
            if component[seed] != u32::MAX {
                continue;
            }
            let id = components.len() as u32;
            let mut members = vec![seed as u32];
            component[seed] = id;
            let mut head = 0;
            while head < members.len() {
                let ti = members[head] as usize;
                head += 1;
                let t = self.triangles[ti];
                for e in 0..3 {
                    // The edge as this triangle traverses it after its own flip.
                    let (mut a, mut b) = (t[e], t[(e + 1) % 3]);
                    if flip[ti] {
                        std::mem::swap(&mut a, &mut b);
                    }
                    let shared = &by_edge[&(a.min(b), a.max(b))];
                    if shared.len() != 2 {
                        continue; // boundary or non-manifold: no orientation constraint
                    }
                    let other = if shared[0] as usize == ti {
                        shared[1]
                    } else {
                        shared[0]
                    } as usize;
                    if component[other] != u32::MAX {
                        continue;
                    }
                    component[other] = id;
                    // A consistent neighbour traverses the shared edge as b -> a.
                    flip[other] = directed(&self.triangles[other], a, b);
                    members.push(other as u32);
                }
            }
            components.push(members);
        }
        // Only the sign of each part's volume matters: measure at unit size, so meshes in
        // extreme units (1e300) do not overflow.
        let bounds = self.bounds();
        let (centre, unit) = (bounds.centre(), 1.0 / bounds.longest_side());
        let mut flipped = 0;
        for members in &components {
            let mut vol = 0.0;
            for &ti in members {
                let t = self.triangles[ti as usize];
                let [a, b, c] = self.corners(&t).map(|p| (p - centre) * unit);
                let v = a.dot(&b.cross(&c));
                vol += if flip[ti as usize] { -v } else { v };
            }
            let outward = vol < 0.0;
            for &ti in members {
                let ti = ti as usize;
                if flip[ti] != outward {
                    self.triangles[ti].swap(1, 2);
                    flipped += 1;
                }
            }
        }
        flipped
    }

    /// Applies `x -> scale * x + translation` to every vertex.
    pub fn transformed(&self, scale: f64, translation: &Vector3<f64>) -> TriMesh {
        TriMesh {
            vertices: self
                .vertices
                .iter()
                .map(|v| scale * v + translation)
                .collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// Writes a Wavefront OBJ (vertices and faces only) atomically: to a temporary name in
    /// the same folder, then renamed over `path`.
    pub fn write_obj(&self, path: &Path) -> std::io::Result<()> {
        self.write_obj_with_uvs(path, &[], &[])
    }

    /// Area-weighted vertex normals (unit length; zero for an unused vertex).
    pub fn vertex_normals(&self) -> Vec<Vector3<f64>> {
        area_weighted_normals(
            &self.vertices,
            self.triangles.iter().map(|t| t.map(|v| v as usize)),
        )
    }

    /// Normals per triangle corner that keep creases: a corner's normal is the area-weighted
    /// mean of the triangles around its vertex that bend less than [`CREASE_DEG`] from its own
    /// triangle (a renderer's "smooth by angle"), so a sharp edge renders sharp and a smooth
    /// surface gets [`TriMesh::vertex_normals`]. Returns the distinct normals and each
    /// triangle's three indices into them.
    pub fn corner_normals(&self) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let cos_crease = CREASE_DEG.to_radians().cos();
        let faces: Vec<Vector3<f64>> = self
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                (b - a).cross(&(c - a))
            })
            .collect();
        let units: Vec<Vector3<f64>> = faces
            .iter()
            .map(|f| f.try_normalize(1e-300).unwrap_or_else(Vector3::zeros))
            .collect();
        let mut around: Vec<Vec<u32>> = vec![Vec::new(); self.vertices.len()];
        for (k, t) in self.triangles.iter().enumerate() {
            for &v in t {
                around[v as usize].push(k as u32);
            }
        }
        let mut normals = Vec::with_capacity(self.vertices.len());
        // Per vertex, the normals made so far (bits -> index): equal groups share one.
        let mut made: Vec<Vec<([u64; 3], u32)>> = vec![Vec::new(); self.vertices.len()];
        let mut corners = Vec::with_capacity(self.triangles.len());
        for (k, t) in self.triangles.iter().enumerate() {
            let corner = t.map(|v| {
                let n = around[v as usize]
                    .iter()
                    .filter(|&&j| units[j as usize].dot(&units[k]) >= cos_crease)
                    .map(|&j| faces[j as usize])
                    .sum::<Vector3<f64>>()
                    .try_normalize(1e-300)
                    .unwrap_or_else(Vector3::zeros);
                let bits = [n.x.to_bits(), n.y.to_bits(), n.z.to_bits()];
                let list = &mut made[v as usize];
                match list.iter().find(|(b, _)| *b == bits) {
                    Some(&(_, i)) => i,
                    None => {
                        normals.push(n);
                        let i = (normals.len() - 1) as u32;
                        list.push((bits, i));
                        i
                    }
                }
            });
            corners.push(corner);
        }
        (normals, corners)
    }

    /// [`TriMesh::write_obj`] with normals that keep creases ([`TriMesh::corner_normals`]:
    /// `vn`, faces `f a//n`).
    pub fn write_obj_with_normals(&self, path: &Path) -> std::io::Result<()> {
        finite_in_f32(&self.vertices, "vertex")?;
        let (normals, corners) = self.corner_normals();
        write_atomically(path, |w| {
            writeln!(w, "# written by morph {}", env!("CARGO_PKG_VERSION"))?;
            for v in &self.vertices {
                writeln!(w, "v {} {} {}", v.x as f32, v.y as f32, v.z as f32)?;
            }
            for n in &normals {
                writeln!(w, "vn {} {} {}", n.x as f32, n.y as f32, n.z as f32)?;
            }
            for (t, c) in self.triangles.iter().zip(&corners) {
                let [a, b, d] = t.map(|i| i + 1);
                let [na, nb, nd] = c.map(|i| i + 1);
                writeln!(w, "f {a}//{na} {b}//{nb} {d}//{nd}")?;
            }
            Ok(())
        })
    }

    /// [`TriMesh::write_obj`] with texture coordinates: `uv_corners[t]` holds triangle `t`'s
    /// corners' indices into `uvs` (both empty: no `vt`).
    pub fn write_obj_with_uvs(
        &self,
        path: &Path,
        uvs: &[[f64; 2]],
        uv_corners: &[[u32; 3]],
    ) -> std::io::Result<()> {
        let textured = !uv_corners.is_empty();
        if textured && uv_corners.len() != self.triangles.len() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "one set of texture corners per triangle",
            ));
        }
        finite_in_f32(&self.vertices, "vertex")?;
        write_atomically(path, |w| {
            writeln!(w, "# written by morph {}", env!("CARGO_PKG_VERSION"))?;
            for v in &self.vertices {
                writeln!(w, "v {} {} {}", v.x as f32, v.y as f32, v.z as f32)?;
            }
            for uv in uvs {
                writeln!(w, "vt {} {}", uv[0] as f32, uv[1] as f32)?;
            }
            for (k, t) in self.triangles.iter().enumerate() {
                if textured {
                    let c = uv_corners[k];
                    writeln!(
                        w,
                        "f {}/{} {}/{} {}/{}",
                        t[0] + 1,
                        c[0] + 1,
                        t[1] + 1,
                        c[1] + 1,
                        t[2] + 1,
                        c[2] + 1
                    )?;
                } else {
                    writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
                }
            }
            Ok(())
        })
    }
}

/// Refuses points a 32-bit float file cannot hold (exit 0 means every written value is
/// finite); `what` names them in the message.
pub fn finite_in_f32(points: &[Vector3<f64>], what: &str) -> std::io::Result<()> {
    match points
        .iter()
        .position(|v| !v.iter().all(|&c| (c as f32).is_finite()))
    {
        Some(i) => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{what} {} is not finite in 32-bit floats", i + 1),
        )),
        None => Ok(()),
    }
}

/// Runs `write` into `path` + ".tmp" and renames the result over `path`, so readers never
/// see a half-written file. The temporary file is removed on failure. It is open for reading
/// too, so a writer may go back over what it wrote (through `get_mut` after a flush).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp);
    let result = (|| {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&tmp)?;
        let mut w = std::io::BufWriter::new(file);
        write(&mut w)?;
        w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Unit vertex normals of the triangles over `vertices`: the sum of the faces' area vectors
/// around each vertex, normalized (zero for a vertex of no face or of zero area).
pub fn area_weighted_normals(
    vertices: &[Vector3<f64>],
    triangles: impl Iterator<Item = [usize; 3]>,
) -> Vec<Vector3<f64>> {
    let mut n = vec![Vector3::zeros(); vertices.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| vertices[v]);
        let face = (b - a).cross(&(c - a));
        for v in t {
            n[v] += face;
        }
    }
    n.iter()
        .map(|v| v.try_normalize(1e-300).unwrap_or_else(Vector3::zeros))
        .collect()
}

#[cfg(test)]
mod tests {
    use crate::geometry::assets;

    /// Crease-keeping normals: a cube's corner has one normal per face around it, each the
    /// face's own; a smooth sphere gets one normal per vertex, the vertex normal's bits.
    #[test]
    fn corner_normals_keep_creases_and_nothing_else() {
        let cube = assets::cube(2.0, 2);
        let (normals, corners) = cube.corner_normals();
        for (t, c) in cube.triangles.iter().zip(&corners) {
            let [a, b, d] = cube.corners(t);
            let face = (b - a).cross(&(d - a)).normalize();
            for &i in c {
                assert!((normals[i as usize] - face).norm() < 1e-12);
            }
        }
        let sphere = assets::uv_sphere(1.0, 12, 24, |_, _| 1.0);
        let (normals, corners) = sphere.corner_normals();
        let smooth = sphere.vertex_normals();
        assert_eq!(normals.len(), sphere.vertices.len());
        for (t, c) in sphere.triangles.iter().zip(&corners) {
            for (v, i) in t.iter().zip(c) {
                assert_eq!(normals[*i as usize], smooth[*v as usize]);
            }
        }
    }
}
