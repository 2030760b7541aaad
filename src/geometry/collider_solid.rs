//! A closed mesh as a collider's solid: the engine's [`Solid`] (inside by the winding number,
//! the nearest surface point over the triangles) and the [`SolidLoader`] a scene's mesh
//! colliders are read with. The engine reads no files; this is where they are read.

use super::mesh::{TriMesh, load_mesh};
use super::winding::WindingNumber;
use crate::engine::effects::Solid;
use crate::engine::scene::SolidLoader;
use nalgebra::Vector3;
use std::path::Path;

/// The inside of a closed mesh.
pub struct MeshSolid {
    winding: WindingNumber,
    /// The triangles' corners, in the mesh's order (the nearest point's ties go to the first).
    tris: Vec<[Vector3<f64>; 3]>,
}

impl MeshSolid {
    pub fn new(mesh: &TriMesh) -> MeshSolid {
        MeshSolid {
            winding: WindingNumber::new(mesh),
            tris: mesh.triangles.iter().map(|t| mesh.corners(t)).collect(),
        }
    }
}

impl Solid for MeshSolid {
    fn contains(&self, q: &Vector3<f64>) -> bool {
        self.winding.at(q) > 0.5
    }

    fn nearest_surface_point(&self, q: &Vector3<f64>) -> Vector3<f64> {
        self.tris
            .iter()
            .map(|t| closest_point_on_triangle(q, t))
            .min_by(|a, b| (a - q).norm_squared().total_cmp(&(b - q).norm_squared()))
            .unwrap_or(*q)
    }
}

/// Reads a mesh collider's file (OBJ or PLY, checked as any mesh is) and refuses a mesh that
/// is not closed.
pub struct MeshSolids;

impl SolidLoader for MeshSolids {
    fn load(
        &self,
        path: &Path,
        scale: f64,
        translation: Vector3<f64>,
    ) -> Result<Box<dyn Solid>, String> {
        let mesh = load_mesh(path).map_err(|e| format!("collider: {e}"))?;
        if !mesh.mesh.topology().is_closed() {
            return Err(format!(
                "collider mesh {} is not closed: its inside is not defined",
                path.display()
            ));
        }
        let placed = mesh.mesh.transformed(scale, &translation);
        Ok(Box::new(MeshSolid::new(&placed)))
    }
}

/// The point of triangle `t` nearest to `p` (by the triangle's Voronoi regions).
pub fn closest_point_on_triangle(p: &Vector3<f64>, t: &[Vector3<f64>; 3]) -> Vector3<f64> {
    let [a, b, c] = t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_covers_every_region() {
        let t = [Vector3::zeros(), Vector3::x(), Vector3::y()];
        let cases = [
            (Vector3::new(0.2, 0.2, 1.0), Vector3::new(0.2, 0.2, 0.0)),
            (Vector3::new(-1.0, -1.0, 0.0), Vector3::zeros()),
            (Vector3::new(2.0, -0.5, 0.0), Vector3::x()),
            (Vector3::new(0.5, -1.0, 0.3), Vector3::new(0.5, 0.0, 0.0)),
            (Vector3::new(1.0, 1.0, 0.0), Vector3::new(0.5, 0.5, 0.0)),
        ];
        for (p, want) in cases {
            assert!(
                (closest_point_on_triangle(&p, &t) - want).norm() < 1e-12,
                "{p:?}"
            );
        }
    }

    /// A collider mesh that is missing, or not closed, is refused with the file's name.
    #[test]
    fn missing_or_open_collider_meshes_are_refused() {
        let dir = std::env::temp_dir().join(format!("morph-collider-solid-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let missing = dir.join("missing.obj");
        let err = MeshSolids
            .load(&missing, 1.0, Vector3::zeros())
            .err()
            .unwrap();
        assert!(
            err.starts_with("collider: ") && err.contains("missing.obj"),
            "{err}"
        );
        let open = dir.join("open.obj");
        // A cube without its top: ten triangles, one hole.
        let cube = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
                    f 1 3 2\nf 1 4 3\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\n\
                    f 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n";
        std::fs::write(&open, cube).unwrap();
        let err = MeshSolids.load(&open, 1.0, Vector3::zeros()).err().unwrap();
        assert!(
            err.contains("open.obj") && err.contains("not closed"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
