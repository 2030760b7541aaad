//! Geometry benchmark: loading, voxelizing and surface extraction timings on real meshes.
//!
//! For every mesh in a folder and every resolution: the mesh is placed alone in a domain of
//! `resolution` cells across (as `morph` places a source) and filled with 2x2x2 particles per
//! cell. Prints one JSON line per mesh and resolution with the times, the particle count and
//! the particle volume in the mesh's own units (compare with `../shared/meshes/README.md`).
//! Then times surface extraction from balls of about 17k and 100k particles.

use crate::engine::mpm::GridSpec;
use crate::engine::scene::ball_particles;
use crate::geometry::{
    Placement, PlacementOptions, Solid, extract_surface, load_mesh, particles_in,
};
use nalgebra::Vector3;
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// Fastest of `repeats` runs of `f`, in seconds, with the last result.
fn best_of<T>(repeats: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        out = Some(f());
        best = best.min(t0.elapsed().as_secs_f64());
    }
    (best, out.expect("at least one run"))
}

pub fn run(meshes: &Path, resolutions: &[usize], repeats: usize) -> anyhow::Result<()> {
    let mut files: Vec<_> = std::fs::read_dir(meshes)
        .map_err(|e| anyhow::anyhow!("cannot list '{}': {e}", meshes.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("obj") || e.eq_ignore_ascii_case("ply"))
        })
        .collect();
    files.sort();
    for path in &files {
        let (load_s, loaded) = best_of(repeats, || load_mesh(path));
        let mesh = loaded?.mesh;
        let (measure_s, solid) = best_of(repeats, || Solid::measure(&mesh, path));
        let solid = solid?;
        for &resolution in resolutions {
            let options = PlacementOptions {
                resolution,
                ..Default::default()
            };
            let placement = Placement::new(&solid, &solid, &options)?;
            let sim_mesh = placement.world_to_sim.apply_mesh(&mesh);
            let (voxelize_s, particles) = best_of(repeats, || {
                particles_in(&sim_mesh, &placement.grid, 2, None)
            });
            let world_volume = particles.positions.len() as f64 * particles.volume
                / placement.world_to_sim.scale.powi(3);
            println!(
                "{}",
                json!({
                    "bench": "voxelize",
                    "mesh": path.file_name().map(|n| n.to_string_lossy()),
                    "triangles": mesh.triangles.len(),
                    "resolution": resolution,
                    "grid_cells": placement.grid.cells,
                    "particles": particles.positions.len(),
                    "particle_volume": world_volume,
                    "winding_evaluations": particles.stats.winding_evaluations,
                    "samples": particles.stats.samples,
                    "load_s": load_s,
                    "measure_s": measure_s,
                    "voxelize_s": voxelize_s,
                })
            );
        }
    }
    for radius in [8.0, 14.5] {
        let grid = GridSpec::centred_cube(40, 1.0);
        let (x, vol) = ball_particles(&grid, Vector3::zeros(), radius, 2);
        let (secs, mesh) = best_of(repeats, || extract_surface(&x, &vol, 0.5));
        let mesh = mesh?;
        let particle_volume: f64 = vol.iter().sum();
        println!(
            "{}",
            json!({
                "bench": "surface",
                "particles": x.len(),
                "triangles": mesh.triangles.len(),
                "closed": mesh.topology().is_closed(),
                "volume_ratio": mesh.signed_volume() / particle_volume,
                "ms_per_frame": secs * 1e3,
            })
        );
    }
    Ok(())
}
