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
//! split by how much each face's area grew or shrank since. `--colour` writes the mesh as a PLY
//! whose faces are coloured by their angle (white at 0, yellow at 10 degrees, red from 20), for
//! `scripts/render_deviation.py`.
//!
//! `SPACING` is the unit of the distances (a run's particle spacing in world units: `dx_sim
//! / particles_per_cell * sim_to_world.scale`).

use morph::geometry::fidelity::{Reference, mesh_fidelity};

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
        _ => {
            return Err(
                "usage: surface_against MESH REFERENCE SPACING [REST] [--colour OUT.ply]".into(),
            );
        }
    };
    let rest = match rest {
        Some(p) => Some(morph::geometry::load_mesh(std::path::Path::new(p))?.mesh),
        None => None,
    };
    let mesh = morph::geometry::load_mesh(std::path::Path::new(mesh))?.mesh;
    let reference = morph::geometry::load_mesh(std::path::Path::new(reference))?.mesh;
    let reference = Reference::new(&reference).ok_or("the reference has no area")?;
    let f = mesh_fidelity(&mesh, &reference, spacing.parse()?);
    println!(
        "{} triangles: mean normal {:.2} deg, {:.1}% of the area beyond 20 deg, mean distance {:.3}, max {:.2} spacings",
        mesh.triangles.len(),
        f.mean_normal_deg,
        100.0 * f.off_share,
        f.mean_distance,
        f.max_distance
    );
    // Where the mean angle comes from: each face's share of it, by its distance to the
    // reference (a face far off is a part the body did not take; a near one is facets and
    // ripples).
    let spacing: f64 = spacing.parse()?;
    let bands = [0.5, 1.0, 2.0, f64::INFINITY];
    let mut area = [0.0; 4];
    let mut angle = [0.0; 4];
    let stretches = [0.5, 1.0, 2.0, 4.0, f64::INFINITY];
    let mut stretch_area = [0.0; 5];
    let mut stretch_angle = [0.0; 5];
    let mut total = 0.0;
    let mut coloured = String::new();
    for (face, t) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let cross = (b - a).cross(&(c - a));
        let face_area = 0.5 * cross.norm();
        if face_area == 0.0 {
            continue;
        }
        let centre = (a + b + c) / 3.0;
        let (q, n) = reference.closest(&centre);
        let degrees = (cross / (2.0 * face_area))
            .dot(&n)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        if colour.is_some() {
            let [red, green, blue] = ramp(degrees);
            for v in [a, b, c] {
                coloured += &format!("{} {} {} {red} {green} {blue}\n", v.x, v.y, v.z);
            }
        }
        let band = bands
            .iter()
            .position(|&d| (centre - q).norm() / spacing < d)
            .unwrap();
        area[band] += face_area;
        angle[band] += face_area * degrees;
        total += face_area;
        if let Some(rest) = &rest {
            let [a, b, c] = rest.triangles[face].map(|i| rest.vertices[i as usize]);
            let rest_area = 0.5 * (b - a).cross(&(c - a)).norm();
            let grew = face_area / rest_area.max(f64::MIN_POSITIVE);
            let s = stretches.iter().position(|&r| grew < r).unwrap();
            stretch_area[s] += face_area;
            stretch_angle[s] += face_area * degrees;
        }
    }
    for (band, upper) in bands.iter().enumerate() {
        println!(
            "  faces within {upper} spacings: {:.1}% of the area, {:.2} of the mean's degrees",
            100.0 * area[band] / total,
            angle[band] / total
        );
    }
    if let Some(path) = colour {
        let n = mesh.triangles.len();
        let mut ply = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {n}\nproperty list uchar int vertex_indices\nend_header\n",
            3 * n
        );
        ply += &coloured;
        for f in 0..n {
            ply += &format!("3 {} {} {}\n", 3 * f, 3 * f + 1, 3 * f + 2);
        }
        std::fs::write(path, ply)?;
    }
    if rest.is_some() {
        for (s, upper) in stretches.iter().enumerate() {
            println!(
                "  faces grown under {upper} times their rest area: {:.1}% of the area, {:.2} of the mean's degrees",
                100.0 * stretch_area[s] / total,
                stretch_angle[s] / total
            );
        }
    }
    Ok(())
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
