//! One run into its staging folder: the chain driven with the frame writer, then the
//! whole-sequence formats, the mass grid, the previews and the manifest.

use super::manifest::{
    FrameEntry, FrameStats, FramesSummary, JudgedFrame, KeyframeReport, Manifest, RunIdentity,
    TargetPlacement, Timings,
};
use super::sinks::{self, frame_name, out_err};
use super::writer::{Caller, Sinks, WrittenFrames, halfway, run_writing_frames};
use super::{MANIFEST, Summary};
use crate::engine::mpm::State;
use crate::io::outdir;
use crate::io::{images, massgrid::MassGrid};
use crate::morph::memory::MemoryPlan;
use crate::morph::metrics::{FillMetrics, fill_metrics};
use crate::morph::motion::MotionMeasures;
use crate::morph::{MorphError, MorphResult, Prepared, RunProgress, checkpoint};
use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

/// Runs the morph into the staging folder `dir` (from `resume` when given) and writes every
/// file, the manifest last; returns what the caller prints. `setup_s` is the time spent before
/// (`clock` started with the run).
#[allow(clippy::too_many_arguments)]
pub(super) fn write_run(
    prep: &Prepared,
    identity: &RunIdentity,
    run_id: &str,
    (dir, lock): (&Path, outdir::LockId),
    resume: Option<RunProgress>,
    memory: MemoryPlan,
    setup_s: f64,
    clock: Instant,
    caller: Caller,
) -> Result<Summary, MorphError> {
    let settings = &prep.settings;
    let ck = dir.join(checkpoint::FOLDER);
    std::fs::create_dir_all(&ck).map_err(|e| out_err("folder", &ck, e))?;
    let resumed_from = resume
        .as_ref()
        .map(|p| checkpoint::describe(p, settings.method.passes, prep.settings.method.segments));
    let sinks = sinks::for_folder(prep, dir, identity.source_and_last_target(prep))?;
    let (result, written, sinks) =
        run_writing_frames(prep, (dir, lock), run_id, resume, sinks, caller)?;
    refuse_unmoved(prep, &result)?;
    let frames_summary = FramesSummary::of(&written.stats);
    let (motion, keyframes) = motion_and_keyframes(prep, identity, &written);
    let quality_over_time = quality_over_time(prep, &written);
    let run_warnings = crate::morph::run_warnings(&result.segments);
    let optimization = crate::morph::OptimizationReport::of(&result.segments, &result.iterations);
    let optimize_s = clock.elapsed().as_secs_f64() - setup_s;

    // Every frame is on disk: the whole-sequence formats write now.
    let (finish_s, finish_measures) = finish(sinks)?;
    let fill = write_mass_grid(prep, dir, &result.final_state)?;
    let quality = Some(prep.quality(&result.final_state));
    let previews_clock = Instant::now();
    write_previews(prep, dir, &result, &written)?;
    let previews_s =
        previews_clock.elapsed().as_secs_f64() + finish_s.get("gif").copied().unwrap_or(0.0);
    let total_s = clock.elapsed().as_secs_f64();
    let listed = outdir::list_files(dir, &[MANIFEST, checkpoint::FOLDER])
        .map_err(|e| out_err("(listing) folder", dir, e))?;
    let g = &prep.model().grid;
    let t = prep.geometry.placement.target_to_world;
    let manifest = Manifest {
        tool: "morph".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        run_id: run_id.into(),
        files: listed,
        inputs: identity.inputs.clone(),
        settings: settings.clone(),
        grid_cells: g.cells,
        dx_sim: g.dx,
        dt: prep.model().dt,
        fps: Some(1.0 / (prep.sim_frame_every() as f64 * prep.model().dt)),
        sim_to_world: prep.geometry.placement.sim_to_world(),
        target: TargetPlacement {
            scale: t.scale,
            translation: t.translation,
        },
        particles: prep.initial.len(),
        sizing: prep.sizing.clone(),
        target_particles: prep.geometry.target.positions.len(),
        initial_loss: result.initial_loss,
        final_loss: result.final_loss,
        fill,
        quality,
        frames_summary,
        motion,
        iterations: result.iterations,
        levels: result.levels,
        segments: result.segments,
        timings: Timings {
            setup_s,
            optimize_s,
            total_s,
            usd_s: finish_s.get("usd").copied().unwrap_or(0.0),
            previews_s,
            threads: rayon::current_num_threads(),
            simd: prep.model().simd.resolved().name().into(),
            device: prep.engine.device_name().unwrap_or("cpu").into(),
            peak_resident_mb: crate::morph::usage::peak_mb(),
        },
        frames: frame_entries(prep, written.stats, &finish_measures),
        final_mass: "final_mass.mgrid".into(),
        warnings: [&prep.geometry.warnings[..], &run_warnings].concat(),
        memory: Some(memory),
        optimization: Some(optimization),
        keyframes,
        quality_over_time,
    };
    write_manifest(dir, &lock, &manifest)?;
    // The folder is complete: the checkpoint has served its purpose.
    checkpoint::remove(dir)?;
    Ok(Summary {
        seconds: total_s,
        resumed_from,
        warnings: run_warnings,
        ..Summary::of(&manifest, dir)
    })
}

/// A body the optimization never moved is no morph: refused before the sequence's files,
/// unless it began in its target's shape (a target the source's own shape at another size:
/// nothing was there to move).
fn refuse_unmoved(prep: &Prepared, result: &crate::morph::MorphResult) -> Result<(), MorphError> {
    let began_there = prep.quality(&prep.initial).iou >= crate::morph::ARRIVED_IOU;
    let failure = crate::morph::optimization_failure(
        &prep.settings,
        &result.segments,
        &result.iterations,
        began_there,
    );
    match failure {
        Some(why) => Err(MorphError::Optimization(why)),
        None => Ok(()),
    }
}

/// The manifest, written last (once the folder is still this run's).
fn write_manifest(
    dir: &Path,
    lock: &outdir::LockId,
    manifest: &Manifest,
) -> Result<(), MorphError> {
    let manifest_path = dir.join(MANIFEST);
    lock.check(dir).map_err(MorphError::Output)?;
    let json =
        serde_json::to_vec_pretty(manifest).map_err(|e| MorphError::Output(e.to_string()))?;
    crate::io::write_atomically(&manifest_path, |w| std::io::Write::write_all(w, &json))
        .map_err(|e| out_err("manifest", &manifest_path, e))
}

/// What the sinks measured in `finish`: per frame, a figure by name.
type FinishMeasures = Vec<(&'static str, Vec<f64>)>;

/// The target's carried surface's fold share, as its sink names it.
const TARGET_CARRIED_FOLDS: &str = "target_carried_fold_share";

/// Frame `i`'s figure `name` of `measures`, if a sink measured it.
fn measured(measures: &FinishMeasures, name: &str, i: usize) -> Option<f64> {
    let (_, per_frame) = measures.iter().find(|(n, _)| *n == name)?;
    per_frame.get(i).copied()
}

/// Tells each sink the sequence is complete; returns the seconds each took, by name, and what
/// they measured on each frame.
fn finish(mut sinks: Sinks) -> Result<(HashMap<&'static str, f64>, FinishMeasures), MorphError> {
    let (mut seconds, mut measures) = (HashMap::new(), Vec::new());
    for sink in &mut sinks {
        let clock = Instant::now();
        sink.finish()?;
        seconds.insert(sink.name(), clock.elapsed().as_secs_f64());
        if let Some((name, per_frame)) = sink.measured_in_finish() {
            measures.push((name, per_frame.to_vec()));
        }
    }
    Ok((seconds, measures))
}

/// The motion measures of the whole sequence (against the final target) and each target's
/// keyframe report, from every frame's speed and progress (a resumed run restored the earlier
/// frames' from its checkpoint). The measures are absent when frames are missing.
fn motion_and_keyframes(
    prep: &Prepared,
    identity: &RunIdentity,
    written: &WrittenFrames,
) -> (Option<MotionMeasures>, Vec<KeyframeReport>) {
    let at = &prep.settings.shot.at;
    let n_frames = prep.frame_count();
    let speeds: Vec<f64> = written.stats.iter().map(|s| s.rms_speed).collect();
    let progress_to = |t: usize| -> Vec<f64> {
        written
            .stats
            .iter()
            .filter_map(|s| s.progress_iou.get(t).copied())
            .collect()
    };
    let targets = at.len();
    let measured = |t: usize, from: usize, to: usize| {
        (speeds.len() == n_frames)
            .then(|| prep.motion_of(&speeds, &progress_to(t), from, to, at[t]))
    };
    // Measured from the frame the shape change begins on (before it the body only does what
    // its physics does).
    let begin = prep.settings.shot.begin;
    let motion = measured(targets - 1, begin, n_frames);
    let keyframes = (0..targets)
        .map(|t| {
            let judged_at = |f: usize| {
                written
                    .judged
                    .iter()
                    .find(|(i, j, _)| (*i, *j) == (f, t))
                    .map(|(_, _, q)| *q)
            };
            // This target's section: from the previous keyframe (the begin frame for the first)
            // to its own, or to the last frame for the final target.
            let from = if t == 0 { begin } else { at[t - 1] };
            let to = if t + 1 == targets { n_frames } else { at[t] };
            KeyframeReport {
                target: identity.inputs[1 + t].path.clone(),
                frame: at[t],
                time: frame_time(prep, at[t]),
                quality: judged_at(at[t]),
                halfway_frame: halfway(prep, t),
                halfway_quality: judged_at(halfway(prep, t)),
                motion: measured(t, from, to),
            }
        })
        .collect();
    (motion, keyframes)
}

/// The simulated time of frame `f` (numbered from 1).
fn frame_time(prep: &Prepared, f: usize) -> f64 {
    ((f - 1) * prep.sim_frame_every()) as f64 * prep.model().dt
}

/// The judge against the final target on the frames it saw, in order.
fn quality_over_time(prep: &Prepared, written: &WrittenFrames) -> Vec<JudgedFrame> {
    let last = prep.settings.shot.at.len() - 1;
    written
        .judged
        .iter()
        .filter(|(_, t, _)| *t == last)
        .map(|(f, _, q)| JudgedFrame {
            frame: *f,
            time: frame_time(prep, *f),
            fill: q.fill,
            iou: q.iou,
        })
        .collect()
}

/// The final nodal mass grid as an OpenVDB file.
pub(super) const FINAL_MASS_VDB: &str = "final_mass.vdb";

/// Writes the final nodal mass grid (world coordinates) as `final_mass.mgrid` and
/// `final_mass.vdb`; returns the
/// fill measures of the final state.
fn write_mass_grid(prep: &Prepared, dir: &Path, last: &State) -> Result<FillMetrics, MorphError> {
    let to_world = prep.geometry.placement.sim_to_world();
    let mass = prep.model().mass_grid(&last.x)?;
    let g = &prep.model().grid;
    let origin = to_world.apply(&g.origin_vec());
    let grid = MassGrid::new(g.nodes(), origin.into(), g.dx * to_world.scale, mass);
    let mass_path = dir.join("final_mass.mgrid");
    grid.write(&mass_path)
        .map_err(|e| out_err("mass grid", &mass_path, e))?;
    // The same grid as OpenVDB reads it, for DCCs and volume tools.
    let vdb_path = dir.join(FINAL_MASS_VDB);
    let h = &grid.header;
    crate::io::vdb::write_float_grid(&vdb_path, "mass", h.dims, h.origin, h.dx, &grid.values)
        .map_err(|e| out_err("mass grid", &vdb_path, e))?;
    Ok(fill_metrics(
        g,
        particle_spacing(prep),
        &prep.geometry.target.positions,
        &prep.initial.x,
        &last.x,
    ))
}

/// The particles' initial spacing, in simulation units.
fn particle_spacing(prep: &Prepared) -> f64 {
    prep.model().grid.dx / prep.settings.body.particles_per_cell as f64
}

/// The loss curve and the preview strip.
fn write_previews(
    prep: &Prepared,
    dir: &Path,
    result: &MorphResult,
    written: &WrittenFrames,
) -> Result<(), MorphError> {
    let losses: Vec<(f64, f64)> = result
        .iterations
        .iter()
        .map(|r| (r.seconds, r.loss))
        .collect();
    let loss_png = dir.join("loss.png");
    images::write_loss_plot(&loss_png, &losses).map_err(|e| out_err("plot", &loss_png, e))?;
    let preview_png = dir.join("preview.png");
    let radius = 0.5 * particle_spacing(prep) * prep.geometry.placement.sim_to_world().scale;
    images::write_preview(&preview_png, &written.preview, radius)
        .map_err(|e| out_err("preview", &preview_png, e))
}

/// The last target's weight on frame `frame` (1 = the rest shape): 0 until the shape change
/// begins, 1 from the last target's arrival, a smoothstep between.
pub fn target_weight(prep: &Prepared, frame: usize) -> f64 {
    let shot = &prep.settings.shot;
    let (begin, arrive) = (
        shot.begin as f64,
        *shot.at.last().unwrap_or(&shot.begin) as f64,
    );
    if arrive <= begin {
        return if frame as f64 >= arrive { 1.0 } else { 0.0 };
    }
    let t = ((frame as f64 - begin) / (arrive - begin)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The manifest's list of frames: each one's files and measurements.
fn frame_entries(
    prep: &Prepared,
    stats: Vec<FrameStats>,
    measures: &FinishMeasures,
) -> Vec<FrameEntry> {
    let n_frames = prep.frame_count();
    let surfaces = prep.settings.outputs.surfaces;
    let mut stats = stats.into_iter();
    let start = prep.settings.shot.start_frame;
    (0..n_frames)
        .map(|i| {
            let name = frame_name(start + i, start + n_frames - 1);
            let step = i * prep.sim_frame_every();
            FrameEntry {
                index: i + 1,
                step,
                time: step as f64 * prep.model().dt,
                points: format!("frames/{name}.ply"),
                mesh: surfaces.rebuilt().then(|| format!("meshes/{name}.obj")),
                carried: surfaces.carried().then(|| format!("carried/{name}.obj")),
                target_carried: surfaces
                    .target_carried()
                    .then(|| format!("target_carried/{name}.obj")),
                target_weight: surfaces
                    .target_carried()
                    .then(|| target_weight(prep, i + 1)),
                target_carried_fold_share: measured(measures, TARGET_CARRIED_FOLDS, i),
                stats: stats.next(),
            }
        })
        .collect()
}
