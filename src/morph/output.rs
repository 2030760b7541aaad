//! Runs a morph into an output folder (layout in `docs/morph.md`):
//!
//! ```text
//! OUT/frames/frame_0001.ply ...   binary PLY points: x y z vx vy vz J id (world units)
//! OUT/meshes/frame_0001.obj ...   closed surface per frame (world units)
//! OUT/final_mass.mgrid            final nodal mass grid (see io::massgrid)
//! OUT/manifest.json               inputs + hashes, settings, placement, losses, timings, frames
//! OUT/scene.toml                  the resolved scene: `morph --scene OUT/scene.toml` reruns it
//! OUT/loss.png, OUT/preview.png
//! ```
//!
//! `-o` is checked before any work and everything is written into the locked staging folder
//! `OUT.partial/` (see [`crate::io::outdir`]), which is put in place of `OUT` atomically when
//! complete. Each completed segment leaves a checkpoint there ([`super::checkpoint`]); an
//! interrupted run keeps it and `--resume` continues bit for bit.

use super::memory::{MemoryLimit, MemoryPlan};
use super::metrics::{FillMetrics, fill_metrics};
use super::motion::MotionMeasures;
use super::quality::Quality;
use super::sinks::{self, FrameRecord, FrameSink, SinkFrame, out_err};
pub use super::sinks::{RebuiltStats, frame_name};
use super::{
    Frame, IterationRecord, MorphError, MorphEvent, MorphSettings, Observer, Prepared, RunProgress,
    SegmentRecord, WorldFrame, checkpoint, run,
};
use crate::geometry::Similarity;
use crate::geometry::carried::CarriedStats;
use crate::geometry::fidelity::Fidelity;
use crate::io::outdir::{self, Previous, Staging};
use crate::io::{images, massgrid::MassGrid, sha256_file};
use crate::mpm::State;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, SyncSender, channel, sync_channel};
use std::time::Instant;

/// The file that marks a folder as a morph output (and lets `--overwrite` replace it).
pub const MANIFEST: &str = "manifest.json";
/// The file that marks a staging folder as a run's, with what the run is.
pub const RUN_FILE: &str = "run.json";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct InputFile {
    path: String,
    sha256: String,
}

#[derive(Serialize, Deserialize)]
struct TargetPlacement {
    scale: f64,
    translation: [f64; 3],
}

#[derive(Serialize, Deserialize)]
struct FrameEntry {
    index: usize,
    step: usize,
    time: f64,
    points: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    mesh: Option<String>,
    /// The carried surface's file (with `--surface carried` or `both`).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        rename = "carried_mesh"
    )]
    carried: Option<String>,
    #[serde(flatten)]
    stats: Option<FrameStats>,
}

/// What each written frame measured: its particles' volume ratios, their order below the
/// grid, and the volume its rebuilt surface encloses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    pub min_j: f64,
    pub mean_j: f64,
    pub max_j: f64,
    /// Particles with `J <= 0`.
    pub inverted: usize,
    /// Share of particles with a neighbour closer than half the initial spacing.
    pub close_share: f64,
    /// Root-mean-square particle speed, world units per second: how fast the body moves
    /// (0 in records written before it was measured).
    #[serde(default)]
    pub rms_speed: f64,
    /// Kinetic energy `1/2 sum m |v|^2`, with the body's density and world units.
    #[serde(default)]
    pub kinetic_energy: f64,
    /// Root-mean-square particle jerk `|v_k - 2 v_(k-1) + v_(k-2)| / dt^2` over this frame and
    /// the two before it (`dt` the frame interval), world units per second cubed: how abruptly
    /// the motion changes. Absent on the first two frames (and on the first two after a
    /// `--resume`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_jerk: Option<f64>,
    /// What the carried surface measures on this frame (with `--surface carried` or `both`):
    /// the largest and smallest principal stretch of its triangles, and its vertices left
    /// away from the body.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub carried: Option<CarriedStats>,
    /// The rebuilt surface as extracted and as written (cleaned; see
    /// [`crate::geometry::cleanup`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rebuilt: Option<RebuiltStats>,
    /// The body's IoU with each target's inside on the coarse progress lattice, in target
    /// order ([`super::quality::Progress`]): how far it has come toward each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub progress_iou: Vec<f64>,
    /// Volume inside the rebuilt surface (world units), when surfaces are written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface_volume: Option<f64>,
    /// `surface_volume / body volume - 1`: the body's volume is the source mesh's (the
    /// target is scaled to it), so a surface that keeps the body's volume has 0.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface_volume_error: Option<f64>,
}

/// The surfaces' figures a viewer judges a run by (see docs/geometry.md "Surface measures"):
/// the rebuilt surface against the source on the first frame and against the target on the
/// last, the carried one against the target on the last, and how much the carried one folds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurfaceSummary {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rebuilt_first: Option<Fidelity>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rebuilt_last: Option<Fidelity>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub carried_last: Option<Fidelity>,
    /// The source's own fold share (the carried surface on the first frame) and the largest
    /// over the frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source_fold_share: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_carried_fold_share: Option<f64>,
    /// Seconds the carried and the rebuilt surfaces took over all frames (this process's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub carried_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rebuilt_s: Option<f64>,
}

/// The worst of every frame's [`FrameStats`], for the manifest and the summary.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FramesSummary {
    pub min_j: f64,
    pub max_j: f64,
    /// Frames with at least one inverted particle.
    pub frames_inverted: usize,
    pub max_close_share: f64,
    /// The largest of the frames' `rms_speed`.
    #[serde(default)]
    pub max_rms_speed: f64,
    /// The largest of the frames' `kinetic_energy`.
    #[serde(default)]
    pub max_kinetic_energy: f64,
    /// The largest of the frames' `rms_jerk`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_rms_jerk: Option<f64>,
    /// The rebuilt surfaces over the frames: the most shells, the smallest angle, the most
    /// voids and islands dropped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rebuilt: Option<RebuiltSummary>,
    /// The carried surface's largest and smallest triangle stretch and most detached
    /// vertices over the frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub carried: Option<CarriedStats>,
    /// Largest `|surface_volume_error|` over the frames (when surfaces are written).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_surface_volume_error: Option<f64>,
    /// What the surfaces measure against the source and the target (when written).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surfaces: Option<SurfaceSummary>,
}

/// The rebuilt surfaces of a run, summed up (see [`FramesSummary::rebuilt`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RebuiltSummary {
    pub max_shells_before: usize,
    pub max_shells: usize,
    pub min_angle_deg_before: f64,
    pub min_angle_deg: f64,
    /// Over all frames.
    pub voids_dropped: usize,
    pub islands_dropped: usize,
    pub max_smoothing_volume_change: f64,
}

impl FramesSummary {
    fn of(stats: &[FrameStats]) -> Option<FramesSummary> {
        let first = stats.first()?;
        let mut s = FramesSummary {
            min_j: first.min_j,
            max_j: first.max_j,
            frames_inverted: 0,
            max_close_share: 0.0,
            max_rms_speed: 0.0,
            max_kinetic_energy: 0.0,
            max_rms_jerk: None,
            carried: None,
            rebuilt: None,
            max_surface_volume_error: None,
            surfaces: None,
        };
        for f in stats {
            s.min_j = s.min_j.min(f.min_j);
            s.max_j = s.max_j.max(f.max_j);
            s.frames_inverted += usize::from(f.inverted > 0);
            s.max_close_share = s.max_close_share.max(f.close_share);
            s.max_rms_speed = s.max_rms_speed.max(f.rms_speed);
            s.max_kinetic_energy = s.max_kinetic_energy.max(f.kinetic_energy);
            if let Some(r) = f.rebuilt {
                let w = s.rebuilt.get_or_insert(RebuiltSummary {
                    max_shells_before: 0,
                    max_shells: 0,
                    min_angle_deg_before: 180.0,
                    min_angle_deg: 180.0,
                    voids_dropped: 0,
                    islands_dropped: 0,
                    max_smoothing_volume_change: 0.0,
                });
                w.max_shells_before = w.max_shells_before.max(r.before.shells);
                w.max_shells = w.max_shells.max(r.after.shells);
                w.min_angle_deg_before = w.min_angle_deg_before.min(r.before.min_angle_deg);
                w.min_angle_deg = w.min_angle_deg.min(r.after.min_angle_deg);
                w.voids_dropped += r.cleanup.voids;
                w.islands_dropped += r.cleanup.islands;
                w.max_smoothing_volume_change = w
                    .max_smoothing_volume_change
                    .max(r.cleanup.smoothing_volume_change.abs());
            }
            if let Some(c) = f.carried {
                let w = s.carried.get_or_insert(c);
                w.max_stretch = w.max_stretch.max(c.max_stretch);
                w.min_stretch = w.min_stretch.min(c.min_stretch);
                w.detached = w.detached.max(c.detached);
                w.fold_share = w.fold_share.max(c.fold_share);
            }
            if let Some(j) = f.rms_jerk {
                s.max_rms_jerk = Some(s.max_rms_jerk.unwrap_or(0.0).max(j));
            }
            if let Some(e) = f.surface_volume_error {
                let worst = s.max_surface_volume_error.unwrap_or(0.0).max(e.abs());
                s.max_surface_volume_error = Some(worst);
            }
        }
        let last = stats.last().expect("not empty");
        let surfaces = SurfaceSummary {
            rebuilt_first: first.rebuilt.and_then(|r| r.fidelity),
            rebuilt_last: last.rebuilt.and_then(|r| r.fidelity),
            carried_last: last.carried.and_then(|c| c.fidelity),
            source_fold_share: first.carried.map(|c| c.fold_share),
            max_carried_fold_share: s.carried.map(|c| c.fold_share),
            carried_s: first.carried.map(|_| {
                stats
                    .iter()
                    .filter_map(|f| f.carried)
                    .map(|c| c.seconds)
                    .sum()
            }),
            rebuilt_s: first.rebuilt.map(|_| {
                stats
                    .iter()
                    .filter_map(|f| f.rebuilt)
                    .map(|r| r.seconds)
                    .sum()
            }),
        };
        if surfaces.rebuilt_first.is_some() || surfaces.source_fold_share.is_some() {
            s.surfaces = Some(surfaces);
        }
        if let Some(c) = &mut s.carried {
            c.fidelity = None;
        }
        Some(s)
    }
}

/// Who a run is: what decides its result bit for bit. Two runs with equal identities write
/// the same frames and mass grid; `--resume` continues only a run with the same identity.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunIdentity {
    tool: String,
    version: String,
    /// The source, each target in keyframe order, then each collider mesh.
    inputs: Vec<InputFile>,
    /// The settings, with each collider's mesh path replaced by its content's hash.
    settings: MorphSettings,
}

impl RunIdentity {
    fn new(
        settings: &MorphSettings,
        source: &Path,
        targets: &[PathBuf],
    ) -> Result<Self, MorphError> {
        let input = |p: &Path| -> Result<InputFile, MorphError> {
            Ok(InputFile {
                path: p.display().to_string(),
                sha256: sha256_file(p, crate::files::MESH_BYTES).map_err(|e| {
                    MorphError::Mesh(crate::geometry::MeshError::Unreadable {
                        path: p.into(),
                        reason: e.to_string(),
                    })
                })?,
            })
        };
        let mut inputs = vec![input(source)?];
        for t in targets {
            inputs.push(input(t)?);
        }
        let mut settings = settings.clone();
        for c in &mut settings.colliders {
            let file = input(&c.mesh)?;
            c.mesh = PathBuf::from(format!("sha256:{}", file.sha256));
            inputs.push(file);
        }
        Ok(RunIdentity {
            tool: "morph".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            inputs,
            settings,
        })
    }

    /// SHA-256 of what decides the result: the version, the inputs' content (not their
    /// paths) and the settings.
    fn id(&self) -> String {
        let decisive = (
            &self.tool,
            &self.version,
            self.inputs.iter().map(|i| &i.sha256).collect::<Vec<_>>(),
            &self.settings,
        );
        sha256_hex(&serde_json::to_vec(&decisive).expect("plain data"))
    }

    /// What differs from `other`, one phrase per difference (input paths may differ: the
    /// content decides).
    fn differences(&self, other: &RunIdentity) -> Vec<String> {
        let mut out = Vec::new();
        if self.version != other.version {
            out.push(format!(
                "morph version {} vs {}",
                other.version, self.version
            ));
        }
        if self.inputs.len() != other.inputs.len() {
            out.push(format!(
                "{} input meshes vs {}",
                other.inputs.len(),
                self.inputs.len()
            ));
        }
        for (i, (a, b)) in self.inputs.iter().zip(&other.inputs).enumerate() {
            if a.sha256 != b.sha256 {
                let which = match i {
                    0 => "source".to_string(),
                    i if i < self.inputs.len() - self.settings.colliders.len() => {
                        format!("target {i}")
                    }
                    _ => "collider".to_string(),
                };
                out.push(format!(
                    "{which} mesh content ('{}' vs '{}')",
                    b.path, a.path
                ));
            }
        }
        let (a, b) = (
            serde_json::to_value(&other.settings).unwrap_or_default(),
            serde_json::to_value(&self.settings).unwrap_or_default(),
        );
        let mut diff = Vec::new();
        json_diff("", &a, &b, &mut diff);
        out.extend(diff);
        out
    }
}

/// Leaf-by-leaf differences of two JSON values, as `path: old -> new`.
fn json_diff(at: &str, a: &serde_json::Value, b: &serde_json::Value, out: &mut Vec<String>) {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let sub = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                json_diff(
                    &sub,
                    x.get(k).unwrap_or(&Value::Null),
                    y.get(k).unwrap_or(&Value::Null),
                    out,
                );
            }
        }
        _ if a != b => out.push(format!("{at}: {a} -> {b}")),
        _ => {}
    }
}

#[derive(Serialize, Deserialize)]
struct Manifest {
    tool: String,
    version: String,
    /// SHA-256 of the run identity (tool version, input hashes, settings).
    run_id: String,
    /// Every other file of the folder, relative, with `/`: what `--overwrite` may replace
    /// (see [`outdir::check_owned`]).
    files: Vec<String>,
    inputs: Vec<InputFile>,
    settings: MorphSettings,
    grid_cells: [usize; 3],
    dx_sim: f64,
    /// The simulation time step (a morph step over its substeps).
    dt: f64,
    /// Frames per second of the written sequence: frames are `1 / fps` apart in simulated
    /// time (absent in manifests written before it was recorded).
    #[serde(default)]
    fps: Option<f64>,
    /// Sim -> world (source mesh coordinates): world = scale * sim + translation.
    sim_to_world: Similarity,
    /// Target mesh -> world: world = scale * mesh + translation.
    target: TargetPlacement,
    particles: usize,
    target_particles: usize,
    initial_loss: f64,
    final_loss: f64,
    fill: FillMetrics,
    /// The quality judge's verdict on the final state (`morph::quality`).
    #[serde(default)]
    quality: Option<Quality>,
    /// The worst of the frames' measurements (each frame's are in `frames`).
    #[serde(default)]
    frames_summary: Option<FramesSummary>,
    /// What a viewer sees of the motion: pulse, dip, wobble, settle, ease error
    /// ([`super::motion`]), over the whole sequence against the final target.
    #[serde(default)]
    motion: Option<MotionMeasures>,
    iterations: Vec<IterationRecord>,
    /// The coarse-to-fine levels solved before the morph's own grid (none with one level).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    levels: Vec<super::LevelRecord>,
    segments: Vec<SegmentRecord>,
    timings: Timings,
    frames: Vec<FrameEntry>,
    final_mass: String,
    warnings: Vec<String>,
    /// How the run's memory was planned (absent in manifests written before it was).
    #[serde(default)]
    memory: Option<MemoryPlan>,
    /// Each target's keyframe: the quality judge against that target on the frame it is
    /// reached and on the frame halfway there from the previous keyframe.
    #[serde(default)]
    keyframes: Vec<KeyframeReport>,
    /// The judge on frames a quarter of the sequence apart (and the `--arrive` ones): how
    /// the shape approaches the target over time (frames written before a `--resume` are
    /// missing).
    #[serde(default)]
    quality_over_time: Vec<JudgedFrame>,
}

/// How a run met one target's keyframe (`--at`; frames are numbered from 1, the rest shape).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct KeyframeReport {
    /// The target's input file.
    pub target: String,
    pub frame: usize,
    pub time: f64,
    /// The judge against this target on its frame (absent when a resumed run had already
    /// written it).
    pub quality: Option<Quality>,
    pub halfway_frame: usize,
    pub halfway_quality: Option<Quality>,
    /// The motion measures of this target's section: from the previous keyframe's frame (the
    /// rest shape's for the first) to this one's (to the last frame for the final target).
    #[serde(default)]
    pub motion: Option<MotionMeasures>,
}

#[derive(Clone, Copy, Serialize, Deserialize)]
pub struct Timings {
    pub setup_s: f64,
    pub optimize_s: f64,
    pub total_s: f64,
    /// Writing the USD sequence, and the previews (PNG, GIF), after the frames.
    #[serde(default)]
    pub usd_s: f64,
    #[serde(default)]
    pub previews_s: f64,
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
}

/// Where and how a morph writes its folder.
#[derive(Clone, Copy, Debug)]
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
}

/// The names a run writes at the top of its staging folder.
const STAGING_NAMES: &[&str] = &[
    RUN_FILE,
    MANIFEST,
    "frames",
    "meshes",
    "carried",
    checkpoint::FOLDER,
    super::scene_file::RESOLVED,
    "final_mass.mgrid",
    "loss.png",
    "preview.png",
    "preview.gif",
    crate::io::usd::FILE,
];

/// Morphs `source` into `target` and writes the folder `request.out`; see the module docs.
///
/// Nothing is deleted before the inputs are loaded and checked: an earlier output is
/// replaced only once the new one is complete, and an interrupted run's staging folder is
/// cleared (`--overwrite`) only after the new inputs have loaded.
pub fn morph_to_folder(
    settings: &MorphSettings,
    source: &Path,
    targets: &[PathBuf],
    request: &OutputRequest,
    mut on_event: impl FnMut(&MorphEvent),
) -> Result<Summary, MorphError> {
    let clock = Instant::now();
    settings.validate().map_err(MorphError::Settings)?;
    settings
        .validate_targets(targets.len())
        .map_err(MorphError::Settings)?;
    let mut inputs: Vec<&Path> = vec![source];
    inputs.extend(targets.iter().map(PathBuf::as_path));
    inputs.extend(settings.colliders.iter().map(|c| c.mesh.as_path()));
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
    if plan.existing == outdir::Existing::Ours {
        let done = read_manifest(&plan.out.join(MANIFEST));
        let missing = outdir::check_owned(&plan.out, MANIFEST)
            .map(|o| o.missing)
            .unwrap_or_default();
        match done {
            Some(m) if request.resume && m.run_id == run_id && missing.is_empty() => {
                return Ok(Summary {
                    output: plan.out.clone(),
                    particles: m.particles,
                    frames: m.frames.len(),
                    initial_loss: m.initial_loss,
                    final_loss: m.final_loss,
                    fill: m.fill,
                    quality: m.quality,
                    frames_summary: m.frames_summary,
                    motion: m.motion,
                    seconds: 0.0,
                    resumed_from: None,
                    already_complete: true,
                    warnings: Vec::new(),
                });
            }
            Some(m) if m.run_id == run_id && !request.overwrite => {
                return Err(MorphError::Settings(format!(
                    "output folder '{}' is this run's, but '{}' that its manifest lists is missing ({} file(s) in all); pass --overwrite to make the folder again",
                    plan.out.display(),
                    missing[0],
                    missing.len()
                )));
            }
            _ if !request.overwrite => {
                return Err(MorphError::Settings(format!(
                    "output folder '{}' holds a different run; pass --overwrite to replace it",
                    plan.out.display()
                )));
            }
            _ => {}
        }
    }
    let mut staging = Staging::take(&plan, RUN_FILE, STAGING_NAMES).map_err(MorphError::Output)?;
    let run_path = staging.dir.join(RUN_FILE);
    // What to do with an earlier run's staging folder, decided now, done once the inputs load.
    let mut resuming = false;
    let mut clear_earlier = false;
    if staging.previous == Previous::Run {
        let earlier: Option<RunIdentity> =
            crate::files::read(&run_path, crate::files::SMALL_FILE_BYTES)
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
            resuming = true;
        } else if request.overwrite {
            // --overwrite (alone, or with --resume when the earlier run cannot be continued)
            // starts over, once the new inputs have loaded.
            clear_earlier = true;
        } else if let (true, Some(why)) = (request.resume, obstacle) {
            return Err(MorphError::Resume(format!(
                "{why}; start over with --overwrite"
            )));
        } else {
            return Err(MorphError::Settings(format!(
                "'{shown}' holds an interrupted run; continue it with --resume or start over with --overwrite"
            )));
        }
    }
    let had_checkpoint = staging.previous == Previous::Run;
    let prepared = (|| {
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
        // The memory limit holds for setup too: refused before the fill when it cannot.
        let estimate = Prepared::estimate(settings, (&src, source), &meshes)?;
        super::memory::check_before_setup(
            settings,
            &estimate,
            targets.len() - 1,
            request.memory_limit,
        )?;
        let mut prep = Prepared::from_meshes(settings, (&src, source), &meshes)?;
        let memory = prep.plan_memory(request.memory_limit)?;
        Ok((prep, memory))
    })();
    let (prep, memory) = match prepared {
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
    let result = (|| {
        // The resolved scene: `morph --scene OUT/scene.toml` runs this again, bit for bit.
        let scene = super::scene_file::SceneFile::resolved(&prep.settings, source, targets);
        let scene_path = staging.dir.join(super::scene_file::RESOLVED);
        crate::io::write_atomically(&scene_path, |w| {
            std::io::Write::write_all(w, scene.as_bytes())
        })
        .map_err(|e| out_err("resolved scene", &scene_path, e))?;
        let setup_s = clock.elapsed().as_secs_f64();
        let resume = if resuming {
            checkpoint::load(
                &staging.dir,
                &run_id,
                prep.initial.len(),
                &prep.segment_layers(),
            )?
        } else {
            None
        };
        write_run(
            &prep,
            &identity,
            &run_id,
            &staging.dir,
            resume,
            request.stop,
            memory,
            setup_s,
            clock,
            &mut on_event,
        )
    })();
    match result {
        Ok(mut summary) => {
            staging.commit(&plan).map_err(MorphError::Output)?;
            summary.output = plan.out.clone();
            Ok(summary)
        }
        Err(e) => {
            // Keep whatever a later --resume can use; remove a staging folder with nothing in it.
            let kept = checkpoint::exists(&staging.dir);
            let dir = staging.dir.clone();
            if !kept {
                staging.discard();
            }
            Err(match e {
                MorphError::Interrupted { signal, .. } => MorphError::Interrupted { signal, kept },
                MorphError::Output(why) if kept => MorphError::Output(format!(
                    "{why}; the completed segments are kept in '{}': once the cause is fixed (e.g. disk space freed), run the same command with --resume to continue",
                    dir.display()
                )),
                e => e,
            })
        }
    }
}

fn read_manifest(path: &Path) -> Option<Manifest> {
    serde_json::from_slice(&crate::files::read(path, crate::files::MANIFEST_BYTES).ok()?).ok()
}

fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The frame halfway (in time) between the previous keyframe's frame (the rest shape's for
/// the first) and target `t`'s.
fn halfway(prep: &Prepared, t: usize) -> usize {
    let at = &prep.settings.at;
    let before = if t == 0 { 1 } else { at[t - 1] };
    before + (at[t] - before) / 2
}

/// The frames the judge sees as the run goes (numbered from 1), each with the target it is
/// judged against: a quarter of the sequence apart against the final target, and each
/// target's keyframe and the frame halfway to it against that target.
fn judged_frames(prep: &Prepared) -> Vec<(usize, usize)> {
    let n = prep.frame_count();
    let last = prep.settings.at.len() - 1;
    let mut f: Vec<(usize, usize)> = (1..=4).map(|q| (1 + q * (n - 1) / 4, last)).collect();
    for (t, &a) in prep.settings.at.iter().enumerate() {
        f.extend([(a, t), (halfway(prep, t), t)]);
    }
    f.sort_unstable();
    f.dedup();
    f
}

/// The judge's verdict on one frame of the sequence.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct JudgedFrame {
    pub frame: usize,
    pub time: f64,
    pub fill: f64,
    pub iou: f64,
}

/// The particles' side of a frame's [`FrameStats`], but for the close-neighbour share, which
/// the writer thread measures.
fn frame_stats(frame: &Frame) -> FrameStats {
    let j = &frame.world.j;
    let n = j.len().max(1) as f64;
    // Particle masses in world units: density times the world volume each stands for.
    let to_world = frame.prep.geometry.placement.sim_to_world().scale.powi(3);
    let kinetic_energy = 0.5
        * frame
            .prep
            .model()
            .mass
            .iter()
            .zip(&frame.world.v)
            .map(|(m, v)| m * to_world * v.norm_squared())
            .sum::<f64>();
    FrameStats {
        kinetic_energy,
        rms_jerk: None,
        carried: None,
        rebuilt: None,
        min_j: j.iter().copied().fold(f64::INFINITY, f64::min),
        mean_j: j.iter().sum::<f64>() / n,
        max_j: j.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        inverted: j.iter().filter(|j| **j <= 0.0).count(),
        // Measured on the writer thread with the surfaces (see `FrameWork`).
        close_share: 0.0,
        rms_speed: (frame.world.v.iter().map(|v| v.norm_squared()).sum::<f64>() / n).sqrt(),
        progress_iou: Vec::new(),
        surface_volume: None,
        surface_volume_error: None,
    }
}

/// Writes frames through its sinks as the chain produces them, checkpoints completed
/// segments, and passes on events and stop requests.
struct FolderWriter<'a> {
    dir: &'a Path,
    /// The run's identity, which seals its checkpoint files.
    run_id: &'a str,
    /// The writer thread's queue, and its answers (see [`FrameWork`]).
    work: SyncSender<FrameWork>,
    done: Receiver<FrameDone>,
    /// Frames sent to the writer thread and not yet answered.
    pending: usize,
    /// Each written frame's measurements, in frame order.
    stats: Vec<FrameStats>,
    /// The velocities (world units) of the last two frames written, with their indices: the
    /// jerk needs three frames.
    recent: Vec<(usize, Vec<Vector3<f64>>)>,
    /// The body's volume (world units) the surfaces are measured against.
    body_volume: f64,
    particles: usize,
    preview_at: Vec<usize>,
    preview: Vec<(usize, Vec<Vector3<f64>>)>,
    /// The judge's verdict on the frames [`judged_frames`] names: (frame, target, verdict).
    judged: Vec<(usize, usize, Quality)>,
    /// Progress toward each target, measured on every frame (see [`super::motion`]).
    progress: Vec<super::quality::Progress>,
    stop: Option<&'a AtomicUsize>,
    on_event: &'a mut dyn FnMut(&MorphEvent),
}

/// One frame for the writer thread: the files (points, carried and rebuilt surfaces) and the
/// measurements that come with them, the costliest part of a frame. It runs while the
/// optimizer goes on with the next segment; the order of frames on disk and in the manifest
/// is that of their indices whatever the timing.
struct FrameWork {
    index: usize,
    time: f64,
    world: WorldFrame,
    state: State,
}

/// The writer thread's answer for one frame: what the sinks measured and the close-neighbour
/// share, or why the frame could not be written.
struct FrameDone {
    index: usize,
    result: Result<(FrameRecord, f64), MorphError>,
}

/// The writer thread: hands the frames it is sent, in order, to every sink in turn until the
/// queue closes, then gives the sinks back (to finish). After a failure it writes nothing
/// more (the run stops on the error). `spacing` (simulation units) is for the close-neighbour
/// share.
fn write_frames(
    mut sinks: Vec<Box<dyn FrameSink + Send>>,
    count: usize,
    spacing: f64,
    work: Receiver<FrameWork>,
    done: Sender<FrameDone>,
) -> Vec<Box<dyn FrameSink + Send>> {
    let mut failed = false;
    for job in work {
        if failed {
            continue;
        }
        let frame = SinkFrame {
            index: job.index,
            count,
            time: job.time,
            world: &job.world,
            state: &job.state,
        };
        let mut record = FrameRecord::default();
        let result = sinks
            .iter_mut()
            .try_for_each(|sink| sink.frame(&frame, &mut record))
            .map(|()| {
                let close = super::quality::close_neighbour_share(&job.state.x, spacing);
                (record, close)
            });
        failed = result.is_err();
        if done
            .send(FrameDone {
                index: job.index,
                result,
            })
            .is_err()
        {
            break;
        }
    }
    sinks
}

impl FolderWriter<'_> {
    /// Takes in the writer thread's answers: every one still owed when `all`, else those
    /// ready now. The first failed frame's error is returned.
    fn collect(&mut self, all: bool) -> Result<(), MorphError> {
        while self.pending > 0 {
            let done = if all {
                self.done.recv().ok()
            } else {
                self.done.try_recv().ok()
            };
            let Some(FrameDone { index, result }) = done else {
                if all {
                    return Err(MorphError::Output("the frame writer stopped".into()));
                }
                return Ok(());
            };
            self.pending -= 1;
            let (
                FrameRecord {
                    surface_volume,
                    carried,
                    rebuilt,
                },
                close,
            ) = result?;
            let stats = &mut self.stats[index];
            stats.carried = carried;
            stats.rebuilt = rebuilt;
            stats.surface_volume = surface_volume;
            stats.surface_volume_error = surface_volume.map(|v| v / self.body_volume - 1.0);
            stats.close_share = close;
        }
        Ok(())
    }

    fn preview_path(&self, index: usize) -> PathBuf {
        self.dir
            .join(checkpoint::FOLDER)
            .join(format!("preview_{index:06}.bin"))
    }

    fn stats_path(&self) -> PathBuf {
        self.dir.join(checkpoint::FOLDER).join("frame_stats.json")
    }

    /// Measurements of the frames written before an interruption, from the checkpoint folder.
    fn restore_stats(&mut self, frames_done: usize) -> Result<(), MorphError> {
        let path = self.stats_path();
        let bad = |e: String| {
            MorphError::Resume(format!(
                "checkpoint file '{}' is damaged or not this run's ({e}); start over with --overwrite",
                path.display()
            ))
        };
        let mut stats: Vec<FrameStats> = checkpoint::read_json(&path, self.run_id).map_err(bad)?;
        if stats.len() < frames_done {
            return Err(bad(format!(
                "{} frame measurements for {frames_done} frames",
                stats.len()
            )));
        }
        stats.truncate(frames_done);
        self.stats = stats;
        Ok(())
    }

    /// Preview frames written before an interruption come back from the checkpoint folder.
    fn restore_preview(&mut self, frames_done: usize) -> Result<(), MorphError> {
        for &index in self.preview_at.iter().filter(|&&i| i < frames_done) {
            let path = self.preview_path(index);
            let data = checkpoint::read_f64s(&path, self.run_id, 3 * self.particles)
                .map_err(|e| {
                    MorphError::Resume(format!(
                        "checkpoint file '{}' is damaged or not this run's ({e}); start over with --overwrite",
                        path.display()
                    ))
                })?;
            let x = data
                .chunks_exact(3)
                .map(Vector3::from_column_slice)
                .collect();
            self.preview.push((index + 1, x));
        }
        Ok(())
    }
}

impl Observer for FolderWriter<'_> {
    fn event(&mut self, event: &MorphEvent) {
        (self.on_event)(event);
    }

    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        self.collect(false)?;
        let index = frame.index;
        // A frame written again (a later pass) waits for the writer's earlier answers on it.
        if index < self.stats.len() {
            self.collect(true)?;
        }
        let mut stats = frame_stats(frame);
        stats.progress_iou = self
            .progress
            .iter()
            .map(|p| p.iou(&frame.state.x))
            .collect();
        self.recent.retain(|(i, _)| *i + 2 >= index && *i < index);
        if let [(a, older), (b, previous)] = self.recent.as_slice()
            && *a + 2 == index
            && *b + 1 == index
        {
            let dt = frame.prep.sim_frame_every() as f64 * frame.prep.model().dt;
            let v = &frame.world.v;
            let sum: f64 = v
                .iter()
                .zip(previous)
                .zip(older)
                .map(|((v, p), o)| (v - 2.0 * p + o).norm_squared())
                .sum();
            stats.rms_jerk = Some((sum / v.len().max(1) as f64).sqrt() / (dt * dt));
        }
        self.recent.push((index, frame.world.v.clone()));
        self.stats.truncate(index);
        self.stats.push(stats);
        self.work
            .send(FrameWork {
                index,
                time: frame.time,
                world: frame.world.clone(),
                state: frame.state.clone(),
            })
            .map_err(|_| MorphError::Output("the frame writer stopped".into()))?;
        self.pending += 1;
        for (f, t) in judged_frames(frame.prep) {
            if f == index + 1 {
                self.judged.retain(|j| (j.0, j.1) != (f, t));
                self.judged
                    .push((f, t, frame.prep.quality_against(frame.state, t)));
            }
        }
        if self.preview_at.contains(&index) {
            let path = self.preview_path(index);
            let x = frame.world.x.clone();
            let flat: Vec<f64> = x.iter().flat_map(|p| p.iter().copied()).collect();
            checkpoint::write_f64s(&path, self.run_id, &flat)
                .map_err(|e| out_err("checkpoint", &path, e))?;
            self.preview.push((index + 1, x));
        }
        Ok(())
    }

    fn segment_done(&mut self, progress: &RunProgress, segment: usize) -> Result<(), MorphError> {
        // A checkpoint counts only frames that are on disk.
        self.collect(true)?;
        let path = self.stats_path();
        checkpoint::write_json(&path, self.run_id, &self.stats)
            .map_err(|e| out_err("checkpoint", &path, e))?;
        checkpoint::save(self.dir, self.run_id, progress, segment)
    }

    fn stop_requested(&self) -> usize {
        self.stop.map_or(0, |s| s.load(Ordering::Relaxed))
    }
}

#[allow(clippy::too_many_arguments)]
fn write_run(
    prep: &Prepared,
    identity: &RunIdentity,
    run_id: &str,
    dir: &Path,
    resume: Option<RunProgress>,
    stop: Option<&AtomicUsize>,
    memory: MemoryPlan,
    setup_s: f64,
    clock: Instant,
    on_event: &mut dyn FnMut(&MorphEvent),
) -> Result<Summary, MorphError> {
    let settings = &prep.settings;
    for sub in ["frames", "meshes", "carried", checkpoint::FOLDER] {
        if (sub == "meshes" && !settings.surfaces.rebuilt())
            || (sub == "carried" && !settings.surfaces.carried())
        {
            continue;
        }
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).map_err(|e| out_err("folder", &d, e))?;
    }
    let to_world = prep.geometry.placement.sim_to_world();
    let spacing = prep.model().grid.dx / settings.particles_per_cell as f64;
    let n_frames = prep.frame_count();
    let resumed_from = resume
        .as_ref()
        .map(|p| checkpoint::describe(p, settings.passes, prep.settings.segments));
    let source = Path::new(&identity.inputs[0].path);
    let sinks = sinks::for_folder(prep, dir, source)?;
    let (work, queue) = sync_channel(super::memory::WRITE_QUEUE);
    let (answers, done) = channel();
    let mut writer = FolderWriter {
        dir,
        run_id,
        work,
        done,
        pending: 0,
        stats: Vec::new(),
        recent: Vec::new(),
        body_volume: prep.geometry.source_solid.volume,
        particles: prep.initial.len(),
        preview_at: (0..6).map(|i| i * (n_frames - 1) / 5).collect(),
        preview: Vec::new(),
        judged: Vec::new(),
        progress: prep.progress_judges(),
        stop,
        on_event,
    };
    if let Some(p) = &resume
        && p.pass + 1 == settings.passes
    {
        writer.restore_preview(p.frames)?;
        writer.restore_stats(p.frames)?;
    }
    let (result, mut sinks) = std::thread::scope(|scope| {
        let thread = scope.spawn(move || write_frames(sinks, n_frames, spacing, queue, answers));
        let result = run(prep, resume, &mut writer).and_then(|r| {
            writer.collect(true)?;
            Ok(r)
        });
        // Closing the queue ends the thread once it has written what it holds.
        let (closed, _) = sync_channel(0);
        drop(std::mem::replace(&mut writer.work, closed));
        match thread.join() {
            Ok(sinks) => Ok((result?, sinks)),
            Err(_) => Err(MorphError::Output("the frame writer panicked".into())),
        }
    })?;
    let preview = std::mem::take(&mut writer.preview);
    let frame_stats = std::mem::take(&mut writer.stats);
    let frames_summary = FramesSummary::of(&frame_stats);
    // The motion measures, from every frame's speed and progress (a resumed run restored the
    // earlier frames' from its checkpoint).
    let speeds: Vec<f64> = frame_stats.iter().map(|s| s.rms_speed).collect();
    let progress_to = |t: usize| -> Vec<f64> {
        frame_stats
            .iter()
            .filter_map(|s| s.progress_iou.get(t).copied())
            .collect()
    };
    let targets = settings.at.len();
    let motion = (speeds.len() == n_frames).then(|| {
        prep.motion_of(
            &speeds,
            &progress_to(targets - 1),
            1,
            n_frames,
            settings.at[targets - 1],
        )
    });
    let section_motion = |t: usize| {
        let from = if t == 0 { 1 } else { settings.at[t - 1] };
        let to = if t + 1 == targets {
            n_frames
        } else {
            settings.at[t]
        };
        (speeds.len() == n_frames)
            .then(|| prep.motion_of(&speeds, &progress_to(t), from, to, settings.at[t]))
    };
    let run_warnings = super::run_warnings(&result.segments);
    let mut judged = std::mem::take(&mut writer.judged);
    judged.sort_by_key(|(f, t, _)| (*f, *t));
    let frame_time = |f: usize| ((f - 1) * prep.sim_frame_every()) as f64 * prep.model().dt;
    let last = settings.at.len() - 1;
    let quality_over_time = judged
        .iter()
        .filter(|(_, t, _)| *t == last)
        .map(|(f, _, q)| JudgedFrame {
            frame: *f,
            time: frame_time(*f),
            fill: q.fill,
            iou: q.iou,
        })
        .collect();
    let keyframes = (0..settings.at.len())
        .map(|t| {
            let at = |f: usize| {
                judged
                    .iter()
                    .find(|(i, j, _)| (*i, *j) == (f, t))
                    .map(|(_, _, q)| *q)
            };
            let frame = settings.at[t];
            KeyframeReport {
                target: identity.inputs[1 + t].path.clone(),
                frame,
                time: frame_time(frame),
                quality: at(frame),
                halfway_frame: halfway(prep, t),
                halfway_quality: at(halfway(prep, t)),
                motion: section_motion(t),
            }
        })
        .collect();
    let optimize_s = clock.elapsed().as_secs_f64() - setup_s;

    // Every frame is on disk: the whole-sequence formats write now.
    let mut finish_s = std::collections::HashMap::new();
    for sink in &mut sinks {
        let clock = std::time::Instant::now();
        sink.finish()?;
        finish_s.insert(sink.name(), clock.elapsed().as_secs_f64());
    }
    let usd_s = finish_s.get("usd").copied().unwrap_or(0.0);

    // Final nodal mass grid, on world coordinates.
    let s = to_world.scale;
    let mass = prep.model().mass_grid(&result.final_state.x)?;
    let g = &prep.model().grid;
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
    let quality = Some(prep.quality(&result.final_state));
    let losses: Vec<(f64, f64)> = result
        .iterations
        .iter()
        .map(|r| (r.seconds, r.loss))
        .collect();
    let previews_clock = std::time::Instant::now();
    let loss_png = dir.join("loss.png");
    images::write_loss_plot(&loss_png, &losses).map_err(|e| out_err("plot", &loss_png, e))?;
    let preview_png = dir.join("preview.png");
    images::write_preview(&preview_png, &preview, 0.5 * spacing * s)
        .map_err(|e| out_err("preview", &preview_png, e))?;
    let previews_s =
        previews_clock.elapsed().as_secs_f64() + finish_s.get("gif").copied().unwrap_or(0.0);
    let frames: Vec<FrameEntry> = (0..n_frames)
        .map(|i| {
            let name = frame_name(i, n_frames);
            let step = i * prep.sim_frame_every();
            FrameEntry {
                index: i + 1,
                step,
                time: step as f64 * prep.model().dt,
                points: format!("frames/{name}.ply"),
                mesh: settings
                    .surfaces
                    .rebuilt()
                    .then(|| format!("meshes/{name}.obj")),
                carried: settings
                    .surfaces
                    .carried()
                    .then(|| format!("carried/{name}.obj")),
                stats: frame_stats.get(i).cloned(),
            }
        })
        .collect();
    let t = prep.geometry.placement.target_to_world;
    let total_s = clock.elapsed().as_secs_f64();
    let listed = outdir::list_files(dir, &[MANIFEST, checkpoint::FOLDER])
        .map_err(|e| out_err("(listing) folder", dir, e))?;
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
            usd_s,
            previews_s,
        },
        frames,
        final_mass: "final_mass.mgrid".into(),
        warnings: prep
            .geometry
            .warnings
            .iter()
            .chain(&run_warnings)
            .cloned()
            .collect(),
        memory: Some(memory),
        keyframes,
        quality_over_time,
    };
    let manifest_path = dir.join(MANIFEST);
    let json =
        serde_json::to_vec_pretty(&manifest).map_err(|e| MorphError::Output(e.to_string()))?;
    crate::io::write_atomically(&manifest_path, |w| std::io::Write::write_all(w, &json))
        .map_err(|e| out_err("manifest", &manifest_path, e))?;
    // The folder is complete: the checkpoint has served its purpose.
    let ck = dir.join(checkpoint::FOLDER);
    std::fs::remove_dir_all(&ck).map_err(|e| out_err("(removing) checkpoint", &ck, e))?;
    Ok(Summary {
        output: dir.to_path_buf(),
        particles: prep.initial.len(),
        frames: n_frames,
        initial_loss: result.initial_loss,
        final_loss: result.final_loss,
        fill,
        quality,
        frames_summary,
        motion,
        seconds: total_s,
        resumed_from,
        already_complete: false,
        warnings: run_warnings,
    })
}
