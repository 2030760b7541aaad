//! Runs a morph into an output folder (layout in `docs/output.md`):
//!
//! ```text
//! OUT/frames/frame_0001.ply ...   binary PLY points: x y z vx vy vz J id (world units)
//! OUT/meshes/frame_0001.obj ...   closed surface per frame (world units)
//! OUT/final_mass.mgrid            final nodal mass grid (see io::massgrid)
//! OUT/final_mass.vdb              the same as an OpenVDB float grid (see io::vdb)
//! OUT/manifest.json               inputs + hashes, settings, placement, losses, timings, frames
//! OUT/scene.toml                  the resolved scene: `morph --scene OUT/scene.toml` reruns it
//! OUT/loss.png, OUT/preview.png
//! ```
//!
//! `-o` is checked before any work and everything is written into the locked staging folder
//! `OUT.partial/` (see [`crate::io::outdir`]), which is put in place of `OUT` atomically when
//! complete. Each completed segment leaves a checkpoint there ([`super::checkpoint`]); an
//! interrupted run keeps it and `--resume` continues bit for bit.

mod liken;
mod manifest;
mod run;
pub use run::target_weight;
pub mod sinks;
mod writer;

pub use liken::{WrittenSurface, written_likeness};
pub use manifest::{
    FrameStats, FramesSummary, JudgedFrame, KeyframeReport, RebuiltSummary, RunIdentity,
    SurfaceSummary, Timings,
};
pub use sinks::{RebuiltStats, frame_name};

use super::memory::MemoryLimit;
use super::metrics::FillMetrics;
use super::motion::MotionMeasures;
use super::quality::Quality;
use super::{CheckedSettings, MorphError, MorphEvent, Prepared, checkpoint};
use crate::io::outdir::{self, Previous, Staging};
use manifest::Manifest;
use serde::Serialize;
use sinks::out_err;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicUsize;
use std::time::Instant;

/// The file that marks a folder as a morph output (and lets `--overwrite` replace it).
pub const MANIFEST: &str = "manifest.json";
/// The file that marks a staging folder as a run's, with what the run is.
pub const RUN_FILE: &str = "run.json";

/// What the caller prints at the end.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub output: PathBuf,
    pub particles: usize,
    /// What the thin parts' rule chose for the particles, and why.
    pub sizing: Option<super::sizing::Sizing>,
    pub frames: usize,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub fill: FillMetrics,
    /// The quality judge's verdict (absent when `--resume` found an older complete folder
    /// without one).
    pub quality: Option<Quality>,
    /// The worst of the written frames' measurements: J range, inverted frames, order,
    /// surface volume.
    pub frames_summary: Option<FramesSummary>,
    /// The motion measures of the whole sequence (see [`super::motion`]).
    pub motion: Option<MotionMeasures>,
    pub seconds: f64,
    /// Where the run continued from (`--resume`), e.g. "pass 2 of 2, 5 of 12 segments done".
    pub resumed_from: Option<String>,
    /// `--resume` found the output already complete for these inputs and settings.
    pub already_complete: bool,
    /// What the run found worth a warning (gradient health, see [`super::run_warnings`]).
    pub warnings: Vec<String>,
    /// How the optimization went (absent when `--resume` found an older complete folder
    /// without it).
    pub optimization: Option<super::OptimizationReport>,
    /// The device the steps ran on (`cpu`, or the GPU adapter's name).
    pub device: String,
}

impl Summary {
    /// What the manifest `m` of the folder `output` says of its run (no time spent, nothing
    /// resumed, no warnings: the caller sets what it knows).
    fn of(m: &Manifest, output: &Path) -> Summary {
        Summary {
            output: output.to_path_buf(),
            particles: m.particles,
            sizing: m.sizing.clone(),
            frames: m.frames.len(),
            initial_loss: m.initial_loss,
            final_loss: m.final_loss,
            fill: m.fill,
            quality: m.quality,
            frames_summary: m.frames_summary,
            motion: m.motion,
            seconds: 0.0,
            resumed_from: None,
            already_complete: false,
            warnings: Vec::new(),
            optimization: m.optimization,
            device: m.timings.device.clone(),
        }
    }
}

/// Where and how a morph writes its folder.
#[derive(Clone, Copy)]
pub struct OutputRequest<'a> {
    pub out: &'a Path,
    /// Replace an existing morph output folder.
    pub overwrite: bool,
    /// Continue an interrupted run of the same inputs and settings from its checkpoint
    /// (starting afresh when there is none); a complete output of the same run is left as is.
    pub resume: bool,
    /// When it holds a nonzero value, the run stops at the next evaluation, keeps its
    /// checkpoint and returns [`MorphError::Interrupted`] with that value (the CLI stores the
    /// signal number here).
    pub stop: Option<&'a AtomicUsize>,
    /// A cap on the run's memory (see [`super::memory`]).
    pub memory_limit: MemoryLimit,
    /// The scene file the settings came from, if any: an input like the meshes, so never
    /// inside the output folder.
    pub scene: Option<&'a Path>,
    /// Called with every frame as the run makes it (world units), on the calling thread
    /// before the frame is written; a caller that wants to stop sets `stop`.
    pub on_frame: Option<&'a dyn Fn(&crate::morph::Frame)>,
}

/// The names a run writes at the top of its staging folder.
const STAGING_NAMES: &[&str] = &[
    RUN_FILE,
    MANIFEST,
    "frames",
    "meshes",
    "carried",
    "target_carried",
    "volumes",
    checkpoint::FOLDER,
    super::scene_file::RESOLVED,
    "final_mass.mgrid",
    run::FINAL_MASS_VDB,
    "loss.png",
    "preview.png",
    "preview.gif",
    crate::io::usd::USDC_FILE,
    crate::io::usd::USDA_FILE,
];

/// Morphs `source` into `target` and writes the folder `request.out`; see the module docs.
///
/// Nothing is deleted before the inputs are loaded and checked: an earlier output is
/// replaced only once the new one is complete, and an interrupted run's staging folder is
/// cleared (`--overwrite`) only after the new inputs have loaded.
pub fn morph_to_folder(
    settings: &CheckedSettings,
    source: &Path,
    targets: &[PathBuf],
    request: &OutputRequest,
    mut on_event: impl FnMut(&MorphEvent),
) -> Result<Summary, MorphError> {
    let clock = Instant::now();
    settings
        .validate_targets(targets.len())
        .map_err(MorphError::Settings)?;
    let mut inputs: Vec<&Path> = vec![source];
    inputs.extend(targets.iter().map(PathBuf::as_path));
    inputs.extend(settings.world.meshes());
    inputs.extend(request.scene);
    let plan = outdir::plan(
        request.out,
        &inputs,
        request.overwrite || request.resume,
        MANIFEST,
    )
    .map_err(MorphError::Settings)?;
    let identity = RunIdentity::new(settings, source, targets)?;
    let run_id = identity.id();
    if let Some(done) = existing_output(&plan, request, &run_id)? {
        return Ok(done);
    }
    let mut staging = Staging::take(&plan, RUN_FILE, STAGING_NAMES).map_err(|e| match e {
        outdir::TakeError::InUse(why) => MorphError::Output(why),
        outdir::TakeError::Unusable(why) => MorphError::Settings(why),
    })?;
    let run_path = staging.dir.join(RUN_FILE);
    // What to do with an earlier run's staging folder, decided now, done once the inputs load.
    let (resuming, clear_earlier) = earlier_staging(&staging, &identity, request)?;
    // Killed after its manifest was written (while its checkpoint was being removed, or
    // before the folder was moved into place): every file is there, only the move is left.
    if resuming && let Some(m) = finished_staging(&staging.dir, &run_id) {
        checkpoint::remove(&staging.dir)?;
        staging.commit(&plan).map_err(MorphError::Output)?;
        return Ok(Summary {
            seconds: clock.elapsed().as_secs_f64(),
            resumed_from: Some(
                "nothing left to compute: the interrupted run had written every file".into(),
            ),
            ..Summary::of(&m, &plan.out)
        });
    }
    let had_checkpoint = staging.previous == Previous::Run;
    let (prep, memory) = match prepare_within(settings, source, targets, request.memory_limit) {
        Ok(p) => p,
        Err(e) => {
            // The inputs did not load: leave an earlier run's files exactly as they were.
            if !had_checkpoint {
                staging.discard();
            }
            return Err(e);
        }
    };
    if clear_earlier {
        staging.clear().map_err(MorphError::Output)?;
    }
    if !resuming {
        let json = serde_json::to_vec_pretty(&identity).expect("plain data");
        crate::io::write_atomically(&run_path, |w| std::io::Write::write_all(w, &json))
            .map_err(|e| out_err("run identity", &run_path, e))?;
    }
    let staged = Staged {
        prep: &prep,
        identity: &identity,
        run_id: &run_id,
        staging: &staging,
        resuming,
    };
    let result = staged.write(source, targets, memory, clock, request, &mut on_event);
    match result {
        Ok(mut summary) => {
            staging.commit(&plan).map_err(MorphError::Output)?;
            summary.output = plan.out.clone();
            Ok(summary)
        }
        Err(e) => Err(failed(staging, e)),
    }
}

/// A set-up run and its staging folder, ready to write.
struct Staged<'a> {
    prep: &'a Prepared,
    identity: &'a RunIdentity,
    run_id: &'a str,
    staging: &'a Staging,
    resuming: bool,
}

impl Staged<'_> {
    /// Writes the resolved scene, then the run (from the checkpoint when resuming) into the
    /// staging folder.
    fn write(
        &self,
        source: &Path,
        targets: &[PathBuf],
        memory: super::memory::MemoryPlan,
        clock: Instant,
        request: &OutputRequest,
        on_event: &mut dyn FnMut(&MorphEvent),
    ) -> Result<Summary, MorphError> {
        let Staged {
            prep,
            identity,
            run_id,
            staging,
            resuming,
        } = *self;
        // The resolved scene: `morph --scene OUT/scene.toml` runs this again, bit for bit.
        let scene = super::scene_file::SceneFile::resolved(&prep.settings, source, targets);
        let scene_path = staging.dir.join(super::scene_file::RESOLVED);
        crate::io::write_atomically(&scene_path, |w| {
            std::io::Write::write_all(w, scene.as_bytes())
        })
        .map_err(|e| out_err("resolved scene", &scene_path, e))?;
        let setup_s = clock.elapsed().as_secs_f64();
        let resume = match resuming {
            true => checkpoint::load(
                &staging.dir,
                run_id,
                prep.initial.len(),
                &prep.segment_layers(),
            )?,
            false => None,
        };
        let lock = staging.lock_id().ok_or_else(|| {
            MorphError::Output(format!(
                "cannot read the lock of '{}'",
                staging.dir.display()
            ))
        })?;
        let caller = writer::Caller {
            stop: request.stop,
            on_frame: request.on_frame,
            on_event,
        };
        let place = (staging.dir.as_path(), lock);
        run::write_run(
            prep, identity, run_id, place, resume, memory, setup_s, clock, caller,
        )
    }
}

/// An output folder this program wrote before: its summary when it is this run's, complete,
/// and `--resume` was asked; refused when it is this run's with files missing, or another
/// run's, unless `--overwrite` replaces it.
fn existing_output(
    plan: &outdir::OutputPlan,
    request: &OutputRequest,
    run_id: &str,
) -> Result<Option<Summary>, MorphError> {
    if plan.existing != outdir::Existing::Ours {
        return Ok(None);
    }
    let done = read_manifest(&plan.out.join(MANIFEST));
    let missing = outdir::check_owned(&plan.out, MANIFEST)
        .map(|o| o.missing)
        .unwrap_or_default();
    match done {
        Some(m) if request.resume && m.run_id == run_id && missing.is_empty() => {
            Ok(Some(Summary {
                already_complete: true,
                ..Summary::of(&m, &plan.out)
            }))
        }
        Some(m) if m.run_id == run_id && !request.overwrite => Err(MorphError::Settings(format!(
            "output folder '{}' is this run's, but '{}' that its manifest lists is missing ({} file(s) in all); pass --overwrite to make the folder again",
            plan.out.display(),
            missing[0],
            missing.len()
        ))),
        _ if !request.overwrite => Err(MorphError::Settings(format!(
            "output folder '{}' holds a different run; pass --overwrite to replace it",
            plan.out.display()
        ))),
        _ => Ok(None),
    }
}

/// What to do with an interrupted run's staging folder: `(resume it, clear it once the new
/// inputs have loaded)`; refused when neither `--resume` (of the same run) nor `--overwrite`
/// says.
fn earlier_staging(
    staging: &Staging,
    identity: &RunIdentity,
    request: &OutputRequest,
) -> Result<(bool, bool), MorphError> {
    if staging.previous != Previous::Run {
        return Ok((false, false));
    }
    let earlier: Option<RunIdentity> =
        crate::files::read(&staging.dir.join(RUN_FILE), crate::files::SMALL_FILE_BYTES)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok());
    let shown = staging.dir.display().to_string();
    // What keeps the earlier run from being continued, if anything.
    let obstacle = match &earlier {
        None => Some(format!("'{shown}' has an unreadable {RUN_FILE}")),
        Some(earlier) => {
            let diff = identity.differences(earlier);
            (!diff.is_empty()).then(|| {
                format!(
                    "cannot resume '{shown}': it is a run of other inputs or settings ({})",
                    diff.join("; ")
                )
            })
        }
    };
    if request.resume && obstacle.is_none() {
        Ok((true, false))
    } else if request.overwrite {
        // --overwrite (alone, or with --resume when the earlier run cannot be continued)
        // starts over, once the new inputs have loaded.
        Ok((false, true))
    } else if let (true, Some(why)) = (request.resume, obstacle) {
        Err(MorphError::Resume(format!(
            "{why}; start over with --overwrite"
        )))
    } else {
        Err(MorphError::Settings(format!(
            "'{shown}' holds an interrupted run; continue it with --resume or start over with --overwrite"
        )))
    }
}

/// Loads the meshes and sets the morph up, within the memory limit: refused before the fill
/// when the estimate is over it, and again on the exact counts.
fn prepare_within(
    settings: &CheckedSettings,
    source: &Path,
    targets: &[PathBuf],
    limit: MemoryLimit,
) -> Result<(Prepared, super::memory::MemoryPlan), MorphError> {
    let src = crate::geometry::load_mesh(source)?;
    let loaded = targets
        .iter()
        .map(|t| crate::geometry::load_mesh(t))
        .collect::<Result<Vec<_>, _>>()?;
    let meshes: Vec<(&crate::geometry::LoadedMesh, &Path)> = loaded
        .iter()
        .zip(targets)
        .map(|(m, p)| (m, p.as_path()))
        .collect();
    // The thin parts' rule once: the estimate and the setup use what it chose.
    let (settings, sizing) = super::sizing::size(settings, (&src, source), &meshes)?;
    let settings = &settings;
    let estimate = Prepared::estimate(settings, (&src, source), &meshes)?;
    let source_vertices = src.mesh.vertices.len();
    let keyframes = targets.len() - 1;
    super::memory::check_before_setup(settings, &estimate, (keyframes, source_vertices), limit)?;
    let mut prep = Prepared::from_sized(settings, sizing, (&src, source), &meshes)?;
    // On the exact counts: the same figure as before setup, the larger of the run's and the
    // writers' needs.
    let counts = prep.memory_counts(source_vertices);
    super::memory::check_least(&prep.settings, &counts, limit)?;
    let memory = prep.plan_memory(limit)?;
    Ok((prep, memory))
}

/// What a run that failed after setup leaves: whatever a later `--resume` can use (a staging
/// folder with nothing in it is removed), and the error that says so.
fn failed(staging: Staging, e: MorphError) -> MorphError {
    // Only while the folder is still the one this run locked: removed and made again by
    // another run, it is that run's.
    if !staging.is_ours() {
        return match e {
            MorphError::Interrupted { signal, .. } => MorphError::Interrupted {
                signal,
                kept: false,
            },
            e => MorphError::Output(format!(
                "{e}; the staging folder '{}' was removed or replaced during the run (by another run?): nothing there was touched",
                staging.dir.display()
            )),
        };
    }
    // A failed optimization is no work to continue: a resume would fail the same way.
    let kept = checkpoint::exists(&staging.dir) && !matches!(e, MorphError::Optimization(_));
    let dir = staging.dir.clone();
    if !kept {
        staging.discard();
    }
    match e {
        MorphError::Interrupted { signal, .. } => MorphError::Interrupted { signal, kept },
        MorphError::Output(why) if kept => MorphError::Output(format!(
            "{why}; the completed segments are kept in '{}': once the cause is fixed (e.g. disk space freed), run the same command with --resume to continue",
            dir.display()
        )),
        e => e,
    }
}

/// The manifest of staging folder `dir` when it is run `run_id`'s and every file it lists is
/// there: the run finished and only moving the folder into place was left.
fn finished_staging(dir: &Path, run_id: &str) -> Option<Manifest> {
    let m = read_manifest(&dir.join(MANIFEST))?;
    (m.run_id == run_id && m.files.iter().all(|f| dir.join(f).is_file())).then_some(m)
}

fn read_manifest(path: &Path) -> Option<Manifest> {
    serde_json::from_slice(&crate::files::read(path, crate::files::MANIFEST_BYTES).ok()?).ok()
}
