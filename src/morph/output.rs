//! Runs a morph into an output folder (layout in `docs/morph.md`):
//!
//! ```text
//! OUT/frames/frame_0001.ply ...   binary PLY points: x y z vx vy vz J (world units)
//! OUT/meshes/frame_0001.obj ...   closed surface per frame (world units)
//! OUT/final_mass.mgrid            final nodal mass grid (see io::massgrid)
//! OUT/manifest.json               inputs + hashes, settings, placement, losses, timings, frames
//! OUT/loss.png, OUT/preview.png
//! ```
//!
//! Everything is written into `OUT.partial/` and renamed to `OUT` at the end, so a folder
//! named `OUT` is always complete; a failed run removes its partial folder.

use super::metrics::{FillMetrics, fill_metrics};
use super::{IterationRecord, MorphError, MorphEvent, MorphSettings, Prepared, SegmentRecord, run};
use crate::geometry::{Similarity, extract_surface};
use crate::io::{frames::write_points_ply, images, massgrid::MassGrid, sha256_file};
use nalgebra::Vector3;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Serialize)]
struct InputFile {
    path: String,
    sha256: String,
}

#[derive(Serialize)]
struct TargetPlacement {
    scale: f64,
    translation: [f64; 3],
}

#[derive(Serialize)]
struct FrameEntry {
    index: usize,
    step: usize,
    time: f64,
    points: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    mesh: Option<String>,
}

#[derive(Serialize)]
struct Manifest<'a> {
    tool: &'static str,
    version: &'static str,
    inputs: [InputFile; 2],
    settings: &'a MorphSettings,
    grid_cells: [usize; 3],
    dx_sim: f64,
    dt: f64,
    /// Sim -> world (source mesh coordinates): world = scale * sim + translation.
    sim_to_world: Similarity,
    /// Target mesh -> world: world = scale * mesh + translation.
    target: TargetPlacement,
    particles: usize,
    target_particles: usize,
    initial_loss: f64,
    final_loss: f64,
    fill: FillMetrics,
    iterations: &'a [IterationRecord],
    segments: &'a [SegmentRecord],
    timings: Timings,
    frames: Vec<FrameEntry>,
    final_mass: &'static str,
    warnings: &'a [String],
}

#[derive(Clone, Copy, Serialize)]
pub struct Timings {
    pub setup_s: f64,
    pub optimize_s: f64,
    pub total_s: f64,
}

/// What the caller prints at the end.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub output: PathBuf,
    pub particles: usize,
    pub frames: usize,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub fill: FillMetrics,
    pub seconds: f64,
}

fn out_err(what: &str, path: &Path, e: impl std::fmt::Display) -> MorphError {
    MorphError::Output(format!("cannot write {what} '{}': {e}", path.display()))
}

/// The staging folder next to `out`.
pub fn partial_dir(out: &Path) -> PathBuf {
    let mut s = out.as_os_str().to_owned();
    s.push(".partial");
    PathBuf::from(s)
}

/// Morphs `source` into `target` and writes the folder `out`. Refuses an existing non-empty
/// `out` unless `overwrite`.
pub fn morph_to_folder(
    settings: &MorphSettings,
    source: &Path,
    target: &Path,
    out: &Path,
    overwrite: bool,
    mut on_event: impl FnMut(&MorphEvent),
) -> Result<Summary, MorphError> {
    let clock = Instant::now();
    settings.validate().map_err(MorphError::Settings)?;
    if out.exists()
        && !overwrite
        && std::fs::read_dir(out)
            .map(|mut d| d.next().is_some())
            .unwrap_or(true)
    {
        return Err(MorphError::Settings(format!(
            "output folder '{}' already exists; pass --overwrite to replace it",
            out.display()
        )));
    }
    let prep = Prepared::new(settings, source, target)?;
    let setup_s = clock.elapsed().as_secs_f64();
    let staging = partial_dir(out);
    let result = write_run(
        &prep,
        settings,
        source,
        target,
        &staging,
        setup_s,
        clock,
        &mut on_event,
    );
    match result {
        Ok(mut summary) => {
            if out.exists() {
                std::fs::remove_dir_all(out).map_err(|e| out_err("over folder", out, e))?;
            }
            std::fs::rename(&staging, out).map_err(|e| out_err("folder", out, e))?;
            summary.output = out.to_path_buf();
            Ok(summary)
        }
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            Err(e)
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn write_run(
    prep: &Prepared,
    settings: &MorphSettings,
    source: &Path,
    target: &Path,
    dir: &Path,
    setup_s: f64,
    clock: Instant,
    on_event: &mut dyn FnMut(&MorphEvent),
) -> Result<Summary, MorphError> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(|e| out_err("folder", dir, e))?;
    }
    for sub in ["frames", "meshes"] {
        let d = dir.join(sub);
        if sub == "meshes" && !settings.surfaces {
            continue;
        }
        std::fs::create_dir_all(&d).map_err(|e| out_err("folder", &d, e))?;
    }
    let to_world = prep.geometry.placement.sim_to_world();
    let s = to_world.scale;
    let shift = Vector3::from(to_world.translation);
    let spacing = prep.sim.grid.dx / settings.particles_per_cell as f64;
    let rest_volume = prep.geometry.source.volume;
    let n_frames = prep.frame_count();
    let preview_at: Vec<usize> = (0..6).map(|i| i * (n_frames - 1) / 5).collect();
    let mut preview = Vec::new();
    let mut frames = Vec::new();
    let dt = prep.sim.dt;
    let result = run(prep, &mut *on_event, |index, step, state| {
        let name = format!("frame_{:04}", index + 1);
        let x: Vec<Vector3<f64>> = state.x.iter().map(|p| s * p + shift).collect();
        let v: Vec<Vector3<f64>> = state.v.iter().map(|v| s * v).collect();
        let j: Vec<f64> = state.f.iter().map(|f| f.determinant()).collect();
        let points = dir.join("frames").join(format!("{name}.ply"));
        write_points_ply(&points, &x, &v, &j).map_err(|e| out_err("frame", &points, e))?;
        let mesh = if settings.surfaces {
            let volumes: Vec<f64> = j.iter().map(|j| rest_volume * j.max(0.0)).collect();
            let surface = extract_surface(&state.x, &volumes, spacing)
                .map_err(|e| MorphError::Output(e.to_string()))?;
            let path = dir.join("meshes").join(format!("{name}.obj"));
            to_world
                .apply_mesh(&surface)
                .write_obj(&path)
                .map_err(|e| out_err("surface", &path, e))?;
            Some(format!("meshes/{name}.obj"))
        } else {
            None
        };
        if preview_at.contains(&index) {
            preview.push((index + 1, x));
        }
        frames.push(FrameEntry {
            index: index + 1,
            step,
            time: step as f64 * dt,
            points: format!("frames/{name}.ply"),
            mesh,
        });
        Ok(())
    })?;
    let optimize_s = clock.elapsed().as_secs_f64() - setup_s;

    // Final nodal mass grid, on world coordinates.
    let mass = prep.sim.mass_grid(&result.final_state.x)?;
    let g = &prep.sim.grid;
    let origin = to_world.apply(&g.origin_vec());
    let grid = MassGrid::new(g.nodes(), origin.into(), g.dx * s, mass);
    let mass_path = dir.join("final_mass.mgrid");
    grid.write(&mass_path)
        .map_err(|e| out_err("mass grid", &mass_path, e))?;

    let fill = fill_metrics(
        g,
        spacing,
        &prep.geometry.target.positions,
        &prep.initial.x,
        &result.final_state.x,
    );
    let losses: Vec<(f64, f64)> = result
        .iterations
        .iter()
        .map(|r| (r.seconds, r.loss))
        .collect();
    let loss_png = dir.join("loss.png");
    images::write_loss_plot(&loss_png, &losses).map_err(|e| out_err("plot", &loss_png, e))?;
    let preview_png = dir.join("preview.png");
    images::write_preview(&preview_png, &preview, 0.5 * spacing * s)
        .map_err(|e| out_err("preview", &preview_png, e))?;

    let input = |p: &Path| -> Result<InputFile, MorphError> {
        Ok(InputFile {
            path: p.display().to_string(),
            sha256: sha256_file(p)
                .map_err(|e| MorphError::Output(format!("cannot hash '{}': {e}", p.display())))?,
        })
    };
    let t = prep.geometry.placement.target_to_world;
    let total_s = clock.elapsed().as_secs_f64();
    let n_written = frames.len();
    let manifest = Manifest {
        tool: "morph",
        version: env!("CARGO_PKG_VERSION"),
        inputs: [input(source)?, input(target)?],
        settings,
        grid_cells: g.cells,
        dx_sim: g.dx,
        dt,
        sim_to_world: to_world,
        target: TargetPlacement {
            scale: t.scale,
            translation: t.translation,
        },
        particles: prep.initial.len(),
        target_particles: prep.geometry.target.positions.len(),
        initial_loss: result.initial_loss,
        final_loss: result.final_loss,
        fill,
        iterations: &result.iterations,
        segments: &result.segments,
        timings: Timings {
            setup_s,
            optimize_s,
            total_s,
        },
        frames,
        final_mass: "final_mass.mgrid",
        warnings: &prep.geometry.warnings,
    };
    let manifest_path = dir.join("manifest.json");
    let json =
        serde_json::to_vec_pretty(&manifest).map_err(|e| MorphError::Output(e.to_string()))?;
    crate::io::write_atomically(&manifest_path, |w| std::io::Write::write_all(w, &json))
        .map_err(|e| out_err("manifest", &manifest_path, e))?;
    Ok(Summary {
        output: dir.to_path_buf(),
        particles: prep.initial.len(),
        frames: n_written,
        initial_loss: result.initial_loss,
        final_loss: result.final_loss,
        fill,
        seconds: total_s,
    })
}
