//! What a run writes about itself: the manifest and its parts, the run's identity (what decides
//! its bits, sealed into its checkpoint), and the per-frame measurements.

use super::super::memory::MemoryPlan;
use super::super::metrics::FillMetrics;
use super::super::motion::MotionMeasures;
use super::super::quality::Quality;
use super::super::{IterationRecord, MorphError, MorphSettings, SegmentRecord};
use super::sinks::RebuiltStats;
use crate::geometry::Similarity;
use crate::geometry::carried::CarriedStats;
use crate::geometry::fidelity::Fidelity;
use crate::geometry::likeness::Likeness;
use crate::io::sha256_file;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(super) struct InputFile {
    pub(super) path: String,
    sha256: String,
}

#[derive(Serialize, Deserialize)]
pub(super) struct TargetPlacement {
    pub(super) scale: f64,
    pub(super) translation: [f64; 3],
}

#[derive(Serialize, Deserialize)]
pub(super) struct FrameEntry {
    pub(super) index: usize,
    pub(super) step: usize,
    pub(super) time: f64,
    pub(super) points: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) mesh: Option<String>,
    /// The carried surface's file (with `--surface carried` or `both`).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        rename = "carried_mesh"
    )]
    pub(super) carried: Option<String>,
    /// The last target's carried surface (`--surface all`) and its weight on this frame: 0
    /// until the shape change begins, 1 from the last target's arrival, a smoothstep between
    /// (the share of the target's mesh in a render's cross-fade from the source's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) target_carried: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) target_weight: Option<f64>,
    /// The target's carried surface's fold share on this frame (measured once the sequence
    /// was complete).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) target_carried_fold_share: Option<f64>,
    #[serde(flatten)]
    pub(super) stats: Option<FrameStats>,
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
    /// order ([`crate::morph::quality::Progress`]): how far it has come toward each.
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
    /// The last frame's rebuilt surface's silhouettes and tips against the target
    /// ([`crate::geometry::likeness`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub likeness: Option<Likeness>,
    /// The same of the last frame's carried surface.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub carried_likeness: Option<Likeness>,
    /// The source's own fold share (the carried surface on the first frame) and the largest
    /// over the frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source_fold_share: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_carried_fold_share: Option<f64>,
    /// The rebuilt surface's crease share (past 30 degrees) on the first frame, the body at
    /// rest, and the largest over the frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rebuilt_first_crease_share: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_rebuilt_crease_share: Option<f64>,
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
    pub(super) fn of(stats: &[FrameStats]) -> Option<FramesSummary> {
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
            likeness: last.rebuilt.and_then(|r| r.likeness),
            carried_likeness: last.carried.and_then(|c| c.likeness),
            source_fold_share: first.carried.map(|c| c.fold_share),
            max_carried_fold_share: s.carried.map(|c| c.fold_share),
            rebuilt_first_crease_share: first.rebuilt.and_then(|r| r.crease_share),
            max_rebuilt_crease_share: stats
                .iter()
                .filter_map(|f| f.rebuilt.and_then(|r| r.crease_share))
                .reduce(f64::max),
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
    pub(super) tool: String,
    pub(super) version: String,
    /// The source, each target in keyframe order, then each collider mesh.
    pub(super) inputs: Vec<InputFile>,
    /// The settings, with each collider's mesh path replaced by its content's hash.
    pub(super) settings: MorphSettings,
}

impl RunIdentity {
    /// The source's file and the last target's (the one the shot ends on).
    pub(super) fn source_and_last_target(
        &self,
        prep: &crate::morph::Prepared,
    ) -> (&std::path::Path, &std::path::Path) {
        let targets = 1 + prep.geometry.placement.keyframes_to_world.len();
        let path = |k: usize| std::path::Path::new(&self.inputs[k].path);
        (path(0), path(targets))
    }

    pub(super) fn new(
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
        for mesh in settings.world.meshes_mut() {
            let file = input(mesh)?;
            *mesh = PathBuf::from(format!("sha256:{}", file.sha256));
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
    pub(super) fn id(&self) -> String {
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
    pub(super) fn differences(&self, other: &RunIdentity) -> Vec<String> {
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
                    i if i < self.inputs.len() - self.settings.world.meshes().count() => {
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
pub(super) struct Manifest {
    pub(super) tool: String,
    pub(super) version: String,
    /// SHA-256 of the run identity (tool version, input hashes, settings).
    pub(super) run_id: String,
    /// Every other file of the folder, relative, with `/`: what `--overwrite` may replace
    /// (see [`outdir::check_owned`]).
    pub(super) files: Vec<String>,
    pub(super) inputs: Vec<InputFile>,
    pub(super) settings: MorphSettings,
    pub(super) grid_cells: [usize; 3],
    pub(super) dx_sim: f64,
    /// The simulation time step (a morph step over its substeps).
    pub(super) dt: f64,
    /// Frames per second of the written sequence: frames are `1 / fps` apart in simulated
    /// time (absent in manifests written before it was recorded).
    #[serde(default)]
    pub(super) fps: Option<f64>,
    /// Sim -> world (source mesh coordinates): world = scale * sim + translation.
    pub(super) sim_to_world: Similarity,
    /// Target mesh -> world: world = scale * mesh + translation.
    pub(super) target: TargetPlacement,
    pub(super) particles: usize,
    /// What the thin parts' rule chose for the particles ([`crate::morph::sizing`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) sizing: Option<crate::morph::sizing::Sizing>,
    pub(super) target_particles: usize,
    pub(super) initial_loss: f64,
    pub(super) final_loss: f64,
    pub(super) fill: FillMetrics,
    /// The quality judge's verdict on the final state (`morph::quality`).
    #[serde(default)]
    pub(super) quality: Option<Quality>,
    /// The worst of the frames' measurements (each frame's are in `frames`).
    #[serde(default)]
    pub(super) frames_summary: Option<FramesSummary>,
    /// What a viewer sees of the motion: pulse, dip, wobble, settle, ease error
    /// ([`super::motion`]), over the whole sequence against the final target.
    #[serde(default)]
    pub(super) motion: Option<MotionMeasures>,
    pub(super) iterations: Vec<IterationRecord>,
    /// The coarse-to-fine levels solved before the morph's own grid (none with one level).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(super) levels: Vec<crate::morph::LevelRecord>,
    pub(super) segments: Vec<SegmentRecord>,
    pub(super) timings: Timings,
    pub(super) frames: Vec<FrameEntry>,
    pub(super) final_mass: String,
    pub(super) warnings: Vec<String>,
    /// How the run's memory was planned (absent in manifests written before it was).
    #[serde(default)]
    pub(super) memory: Option<MemoryPlan>,
    /// How the optimization went: evaluations, steps undone, segments that moved (absent in
    /// manifests written before it was).
    #[serde(default)]
    pub(super) optimization: Option<crate::morph::OptimizationReport>,
    /// Each target's keyframe: the quality judge against that target on the frame it is
    /// reached and on the frame halfway there from the previous keyframe.
    #[serde(default)]
    pub(super) keyframes: Vec<KeyframeReport>,
    /// The judge on frames a quarter of the sequence apart (and the `--arrive` ones): how
    /// the shape approaches the target over time (frames written before a `--resume` are
    /// missing).
    #[serde(default)]
    pub(super) quality_over_time: Vec<JudgedFrame>,
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

/// The device of a manifest written before it was recorded.
fn cpu() -> String {
    "cpu".into()
}

#[derive(Clone, Serialize, Deserialize)]
pub struct Timings {
    pub setup_s: f64,
    pub optimize_s: f64,
    pub total_s: f64,
    /// Writing the USD sequence, and the previews (PNG, GIF), after the frames.
    #[serde(default)]
    pub usd_s: f64,
    #[serde(default)]
    pub previews_s: f64,
    /// What ran the optimization, so timings from two machines can be read side by side:
    /// worker threads, and the vector instruction set of the lane kernels (`baseline`,
    /// `avx2`, `avx512`; it changes the speed, never the bits). Absent in manifests written
    /// before they were recorded.
    #[serde(default)]
    pub threads: usize,
    #[serde(default)]
    pub simd: String,
    /// The device the steps ran on: `cpu`, or the GPU adapter's name (`--device`).
    #[serde(default = "cpu")]
    pub device: String,
    /// The most resident memory the process held, in MB, when the manifest was written (the
    /// kernel's high-water mark of this process's own pages: Linux; absent elsewhere, and in
    /// manifests written before it was recorded). A library call counts its host's memory too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_resident_mb: Option<f64>,
}

fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The judge's verdict on one frame of the sequence.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct JudgedFrame {
    pub frame: usize,
    pub time: f64,
    pub fill: f64,
    pub iou: f64,
}
