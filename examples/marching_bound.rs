//! How true can any surface marched on a lattice be? The exact signed distance of a mesh,
//! sampled on a lattice and marched like the rebuilt surface (`FillField::march`), measured
//! against the mesh itself (`mesh_fidelity`). No particle field can beat this at the same
//! lattice spacing: it is the bound the rebuilt surface of a body at rest is held to
//! (docs/geometry.md, "Sharp edges at rest").
//!
//! ```text
//! cargo run --release --example marching_bound -- MESH SPACING [STEP_SHARE...]
//! ```
//!
//! `SPACING` is the particle spacing in the mesh's units (a run's manifest: `dx_sim /
//! particles_per_cell * sim_to_world.scale`); each `STEP_SHARE` (default 1, 0.5, 0.25) is a
//! lattice step as a share of it. Prints the fidelity measures per step, in spacings.

use morph::geometry::fidelity::{Reference, mesh_fidelity};
use morph::geometry::surface::FillField;
use morph::geometry::winding::WindingNumber;
use nalgebra::Vector3;
use rayon::prelude::*;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [path, spacing, shares @ ..] = &args[..] else {
        return Err("usage: marching_bound MESH SPACING [STEP_SHARE...]".into());
    };
    let mesh = morph::geometry::load_mesh(std::path::Path::new(path))?.mesh;
    let spacing: f64 = spacing.parse()?;
    let shares: Vec<f64> = if shares.is_empty() {
        vec![1.0, 0.5, 0.25]
    } else {
        shares.iter().map(|s| s.parse()).collect::<Result<_, _>>()?
    };
    let reference = Reference::new(&mesh).ok_or("the mesh has no area")?;
    let winding = WindingNumber::new(&mesh);
    for share in shares {
        let step = spacing * share;
        let bounds = mesh.bounds();
        let origin = bounds.min - Vector3::repeat(3.0 * step);
        let dims = [0, 1, 2].map(|a| (bounds.extent()[a] / step).ceil() as usize + 7);
        // A ramp two steps wide across the surface: the marched edge points are then linear
        // in the signed distance, exact for a flat face in any direction.
        let values: Vec<f64> = (0..dims.iter().product::<usize>())
            .into_par_iter()
            .map(|id| {
                let (i, j, k) = (
                    id / (dims[1] * dims[2]),
                    (id / dims[2]) % dims[1],
                    id % dims[2],
                );
                let x = origin + step * Vector3::new(i as f64, j as f64, k as f64);
                let inside = winding.at(&x) > 0.5;
                let distance = reference.distance(&x);
                let signed = if inside { -distance } else { distance };
                (0.5 - signed / (2.0 * step)).clamp(0.0, 1.0)
            })
            .collect();
        let field = FillField {
            origin,
            h: step,
            dims,
            values,
        };
        let marched = field.march();
        let f = mesh_fidelity(&marched, &reference, spacing);
        println!(
            "step {share} spacings: {} triangles, mean normal {:.2} deg, {:.1}% of the area beyond 20 deg, mean distance {:.3}, max {:.2} spacings",
            marched.triangles.len(),
            f.mean_normal_deg,
            100.0 * f.off_share,
            f.mean_distance,
            f.max_distance
        );
    }
    Ok(())
}
