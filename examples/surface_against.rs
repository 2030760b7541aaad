//! How true is one surface to another? The fidelity measures a run reports
//! (docs/geometry.md, "Surface measures"), for any two meshes in the same units: for
//! instance a run's carried frame against its rebuilt frame, which tells what the carrying
//! loses apart from what the body's shape loses.
//!
//! ```text
//! cargo run --release --example surface_against -- MESH REFERENCE SPACING [REST] [--colour OUT.ply]
//! ```
//!
//! With `REST`, the same mesh at rest (a carried surface's frame 1), the mean angle is also
//! split by how much each face's area grew or shrank since. `--colour` writes the mesh as a
//! new PLY file (an existing one is not replaced) whose faces are coloured by their angle
//! (white at 0, yellow at 10 degrees, red from 20), for `scripts/render_deviation.py`.
//!
//! `SPACING` is the unit of the distances (a run's particle spacing in world units: `dx_sim
//! / particles_per_cell * sim_to_world.scale`).

use morph::geometry::fidelity::{Reference, face_deviations, fidelity};
use morph::geometry::mesh::write_atomically;
use std::io::Write;
use std::path::Path;

const USAGE: &str = "usage: surface_against MESH REFERENCE SPACING [REST] [--colour OUT.ply]";

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let colour = match args.iter().position(|a| a == "--colour") {
        Some(i) if i + 1 < args.len() => Some(args.drain(i..i + 2).nth(1).unwrap()),
        Some(_) => return Err("--colour needs a file".into()),
        None => None,
    };
    let (mesh, reference, spacing, rest) = match &args[..] {
        [m, r, s] => (m, r, s, None),
        [m, r, s, rest] => (m, r, s, Some(rest)),
        _ => return Err(USAGE.into()),
    };
    let spacing: f64 = match spacing.parse() {
        Ok(s) if s > 0.0 && f64::is_finite(s) => s,
        _ => return Err(format!("SPACING '{spacing}' is not a positive number").into()),
    };
    if let Some(path) = colour.as_deref().filter(|p| Path::new(p).exists()) {
        return Err(format!("{path}: exists; name a new file for --colour").into());
    }
    let mesh = morph::geometry::load_mesh(Path::new(mesh))?.mesh;
    let rest = match rest {
        Some(p) => {
            let rest = morph::geometry::load_mesh(Path::new(p))?.mesh;
            if rest.triangles != mesh.triangles {
                return Err(format!("{p}: not MESH at rest (its triangles differ)").into());
            }
            Some(rest)
        }
        None => None,
    };
    let reference = morph::geometry::load_mesh(Path::new(reference))?.mesh;
    let reference = Reference::new(&reference).ok_or("the reference has no area")?;
    let triangles: Vec<[usize; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| i as usize))
        .collect();
    let f = fidelity(&mesh.vertices, &triangles, &reference, spacing);
    println!(
        "{} triangles: mean normal {:.2} deg, {:.1}% of the area beyond 20 deg, mean distance {:.3}, max {:.2} spacings",
        triangles.len(),
        f.mean_normal_deg,
        100.0 * f.off_share,
        f.mean_distance,
        f.max_distance
    );

    // Where the mean angle comes from: each face's share of it, by its distance to the
    // reference (a face far off is a part the body did not take; a near one is facets and
    // ripples) and, given REST, by how much it grew.
    let faces = face_deviations(&mesh.vertices, &triangles, &reference);
    let total: f64 = faces
        .iter()
        .map(|f| f.0)
        .sum::<f64>()
        .max(f64::MIN_POSITIVE);
    let distances = [0.5, 1.0, 2.0, f64::INFINITY];
    let band = |&(_, _, d): &(f64, f64, f64)| distances.iter().position(|&u| d / spacing < u);
    print_bands("within", "spacings", &distances, &faces, band, total);
    if let Some(rest) = &rest {
        let rest_areas: Vec<f64> = triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| rest.vertices[i]);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .collect();
        let growths = [0.5, 1.0, 2.0, 4.0, f64::INFINITY];
        let grown: Vec<(f64, f64, f64)> = faces
            .iter()
            .zip(&rest_areas)
            .map(|(&(area, degrees, _), &was)| (area, degrees, area / was.max(f64::MIN_POSITIVE)))
            .collect();
        let band = |&(_, _, g): &(f64, f64, f64)| growths.iter().position(|&u| g < u);
        print_bands(
            "grown under",
            "times their rest area",
            &growths,
            &grown,
            band,
            total,
        );
    }

    if let Some(path) = colour {
        write_atomically(Path::new(&path), |w| {
            // Each face its own three vertices, so that its colour is its own.
            write!(
                w,
                "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
                3 * triangles.len(),
                triangles.len()
            )?;
            for (t, &(_, degrees, _)) in triangles.iter().zip(&faces) {
                let [red, green, blue] = ramp(degrees);
                for v in t.map(|i| mesh.vertices[i]) {
                    writeln!(w, "{} {} {} {red} {green} {blue}", v.x, v.y, v.z)?;
                }
            }
            for f in 0..triangles.len() {
                writeln!(w, "3 {} {} {}", 3 * f, 3 * f + 1, 3 * f + 2)?;
            }
            Ok(())
        })?;
    }
    Ok(())
}

/// Prints, for each band `bounds` sets by `band`, its share of the area and of the mean angle.
fn print_bands(
    what: &str,
    unit: &str,
    bounds: &[f64],
    faces: &[(f64, f64, f64)],
    band: impl Fn(&(f64, f64, f64)) -> Option<usize>,
    total: f64,
) {
    let (mut area, mut angle) = (vec![0.0; bounds.len()], vec![0.0; bounds.len()]);
    for face in faces.iter().filter(|f| f.0 > 0.0) {
        if let Some(b) = band(face) {
            area[b] += face.0;
            angle[b] += face.0 * face.1;
        }
    }
    for (b, upper) in bounds.iter().enumerate() {
        println!(
            "  faces {what} {upper} {unit}: {:.1}% of the area, {:.2} of the mean's degrees",
            100.0 * area[b] / total,
            angle[b] / total
        );
    }
}

/// A face's colour for its angle: white at 0 degrees, yellow at 10, red from 20.
fn ramp(degrees: f64) -> [u8; 3] {
    let t = (degrees / 10.0).clamp(0.0, 2.0);
    let channel = |v: f64| (255.0 * v.clamp(0.0, 1.0)).round() as u8;
    if t <= 1.0 {
        [255, 255, channel(1.0 - t)]
    } else {
        [255, channel(2.0 - t), 0]
    }
}
