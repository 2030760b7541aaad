//! Built-in shapes the project generates itself (the files in `assets/`): closed, outward,
//! welded triangle meshes. `morph assets` writes them.

use super::mesh::TriMesh;
use nalgebra::Vector3;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::Path;

/// A closed surface of a star-shaped body: `radius * shape(theta, phi)` along each direction
/// (theta from +z, phi about z), with `rings` latitude bands and `segments` longitudes.
pub fn uv_sphere(
    radius: f64,
    rings: usize,
    segments: usize,
    shape: impl Fn(f64, f64) -> f64,
) -> TriMesh {
    assert!(rings >= 2 && segments >= 3);
    let at = |theta: f64, phi: f64| {
        let r = radius * shape(theta, phi);
        r * Vector3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    };
    let mut vertices = vec![at(0.0, 0.0)];
    for i in 1..rings {
        let theta = PI * i as f64 / rings as f64;
        for j in 0..segments {
            vertices.push(at(theta, 2.0 * PI * j as f64 / segments as f64));
        }
    }
    vertices.push(at(PI, 0.0));
    let south = (vertices.len() - 1) as u32;
    let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut triangles = Vec::new();
    for j in 0..segments {
        triangles.push([0, ring(1, j), ring(1, j + 1)]);
        for i in 1..rings - 1 {
            let (a0, a1, b0, b1) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            triangles.push([a0, b0, b1]);
            triangles.push([a0, b1, a1]);
        }
        triangles.push([south, ring(rings - 1, j + 1), ring(rings - 1, j)]);
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// Texture coordinates for [`uv_sphere`] of the same `rings` and `segments`: the
/// equirectangular map (u along the longitude, v from the south pole up), with the seam's
/// column doubled and one coordinate per pole triangle. Returns the coordinates and, for each
/// of the sphere's triangles in order, its corners' coordinate indices.
pub fn uv_sphere_uvs(rings: usize, segments: usize) -> (Vec<[f64; 2]>, Vec<[u32; 3]>) {
    let mut uvs = Vec::new();
    // Ring i (1..rings), column j (0..=segments).
    let grid = |i: usize, j: usize| (i - 1) * (segments + 1) + j;
    for i in 1..rings {
        for j in 0..=segments {
            uvs.push([j as f64 / segments as f64, 1.0 - i as f64 / rings as f64]);
        }
    }
    let north = uvs.len();
    for j in 0..segments {
        uvs.push([(j as f64 + 0.5) / segments as f64, 1.0]);
    }
    let south = uvs.len();
    for j in 0..segments {
        uvs.push([(j as f64 + 0.5) / segments as f64, 0.0]);
    }
    let mut corners = Vec::new();
    for j in 0..segments {
        corners.push([north + j, grid(1, j), grid(1, j + 1)]);
        for i in 1..rings - 1 {
            let (a0, a1, b0, b1) = (
                grid(i, j),
                grid(i, j + 1),
                grid(i + 1, j),
                grid(i + 1, j + 1),
            );
            corners.push([a0, b0, b1]);
            corners.push([a0, b1, a1]);
        }
        corners.push([south + j, grid(rings - 1, j + 1), grid(rings - 1, j)]);
    }
    let corners = corners.into_iter().map(|c| c.map(|k| k as u32)).collect();
    (uvs, corners)
}

/// A ring torus about the z axis (genus 1).
pub fn torus(major: f64, minor: f64, around: usize, tube: usize) -> TriMesh {
    let mut vertices = Vec::with_capacity(around * tube);
    for i in 0..around {
        let u = 2.0 * PI * i as f64 / around as f64;
        for j in 0..tube {
            let v = 2.0 * PI * j as f64 / tube as f64;
            let r = major + minor * v.cos();
            vertices.push(Vector3::new(r * u.cos(), r * u.sin(), minor * v.sin()));
        }
    }
    let id = |i: usize, j: usize| ((i % around) * tube + j % tube) as u32;
    let mut triangles = Vec::with_capacity(2 * around * tube);
    for i in 0..around {
        for j in 0..tube {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// An axis-aligned cube of edge `size` centred on the origin, each face split into
/// `subdiv x subdiv` quads (two triangles each), vertices shared between faces.
pub fn cube(size: f64, subdiv: usize) -> TriMesh {
    let n = subdiv.max(1);
    let mut index: HashMap<[usize; 3], u32> = HashMap::new();
    let mut vertices = Vec::new();
    let mut vertex = |c: [usize; 3]| {
        *index.entry(c).or_insert_with(|| {
            vertices.push(
                Vector3::new(c[0] as f64, c[1] as f64, c[2] as f64) * (size / n as f64)
                    - Vector3::repeat(0.5 * size),
            );
            (vertices.len() - 1) as u32
        })
    };
    let mut triangles = Vec::new();
    for axis in 0..3 {
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [0, n] {
            for i in 0..n {
                for j in 0..n {
                    let corner = |di: usize, dj: usize| {
                        let mut p = [0; 3];
                        p[axis] = side;
                        p[b] = i + di;
                        p[c] = j + dj;
                        p
                    };
                    // Counter-clockwise in (b, c) faces +axis.
                    let mut q = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                    if side == 0 {
                        q.reverse();
                    }
                    let q = q.map(&mut vertex);
                    triangles.push([q[0], q[1], q[2]]);
                    triangles.push([q[0], q[2], q[3]]);
                }
            }
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// A peanut: two round lobes along x joined by a waist.
pub fn two_lobes(rings: usize, segments: usize) -> TriMesh {
    let mut mesh = uv_sphere(1.0, rings, segments, |theta, _| {
        1.0 + 0.45 * (2.0 * theta).cos()
    });
    // Lobes along z -> along x (a cyclic axis permutation: a rotation, orientation kept).
    for v in &mut mesh.vertices {
        *v = Vector3::new(v.z, v.x, v.y);
    }
    mesh
}

/// The built-in sphere's rings and segments.
const SPHERE: (usize, usize) = (32, 64);

/// The built-in assets by file name.
pub fn builtin() -> Vec<(&'static str, TriMesh)> {
    vec![
        ("sphere.obj", uv_sphere(1.0, SPHERE.0, SPHERE.1, |_, _| 1.0)),
        ("torus.obj", torus(1.0, 0.4, 64, 32)),
        ("cube.obj", cube(2.0, 8)),
        ("two-lobes.obj", two_lobes(48, 64)),
    ]
}

/// Writes the built-in meshes into `dir` (created if missing) and returns the paths. Existing files of the same names are replaced only
/// with `overwrite`; otherwise nothing is written and the error names the first one.
pub fn write_builtin(dir: &Path, overwrite: bool) -> std::io::Result<Vec<std::path::PathBuf>> {
    if !overwrite && let Some((name, _)) = builtin().into_iter().find(|(n, _)| dir.join(n).exists())
    {
        return Err(std::io::Error::new(
            std::io::ErrorKind::AlreadyExists,
            format!(
                "'{}' exists; pass --overwrite to replace it",
                dir.join(name).display()
            ),
        ));
    }
    std::fs::create_dir_all(dir)?;
    builtin()
        .into_iter()
        .map(|(name, mesh)| {
            let path = dir.join(name);
            if name == "sphere.obj" {
                // The sphere carries texture coordinates, as a modelled source would.
                let (uvs, corners) = uv_sphere_uvs(SPHERE.0, SPHERE.1);
                mesh.write_obj_with_uvs(&path, &uvs, &corners)?;
            } else {
                mesh.write_obj(&path)?;
            }
            Ok(path)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_assets_are_closed_and_outward() {
        for (name, mesh) in builtin() {
            let topo = mesh.topology();
            assert!(topo.is_closed(), "{name}: {topo:?}");
            assert_eq!(topo.misoriented_edges, 0, "{name}");
            assert!(mesh.signed_volume() > 0.0, "{name}");
            let mut copy = mesh.clone();
            assert_eq!(copy.repair_orientation(), 0, "{name}");
        }
    }

    #[test]
    fn analytic_volumes() {
        let s = uv_sphere(1.0, 64, 128, |_, _| 1.0).signed_volume();
        assert!((s / (4.0 / 3.0 * PI) - 1.0).abs() < 2e-3, "{s}");
        let t = torus(1.0, 0.4, 128, 64).signed_volume();
        assert!((t / (2.0 * PI * PI * 0.16) - 1.0).abs() < 5e-3, "{t}");
        assert!((cube(2.0, 3).signed_volume() - 8.0).abs() < 1e-12);
    }

    #[test]
    fn genus_from_euler_characteristic() {
        let genus = |m: &TriMesh| {
            let chi =
                m.vertices.len() as i64 - m.topology().edges as i64 + m.triangles.len() as i64;
            (2 - chi) / 2
        };
        let assets = builtin();
        let g: Vec<i64> = assets.iter().map(|(_, m)| genus(m)).collect();
        assert_eq!(g, vec![0, 1, 0, 0]);
    }
}
