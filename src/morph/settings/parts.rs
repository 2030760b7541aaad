//! The parts of [`super::MorphSettings`]: shot, body, world (its own file), outputs and method. Every field
//! name is unique across the parts, so a scene file may give a key flat (`frames = 97`) or
//! under its part (`[shot] frames = 97`): [`super::part_of`].

use super::{Inbetween, RebuiltMethod, Surfaces, UsdFormat};
use super::{default_begin, default_start_frame, one_level, unit_weight};
use crate::engine::integrator::IntegratorKind;
use crate::engine::mpm::{ControlForm, KernelKind};
use crate::engine::scene::MaterialConfig;
use crate::geometry::TargetFit;
use crate::gpu::{DeviceKind, Precision};
use crate::loss::MassLossKind;
use crate::morph::basis::ControlResolution;
use crate::morph::segment::OptimizerSettings;
use serde::{Deserialize, Serialize};

/// Each part's keys, in the order its struct declares them: a scene file's flat key goes to
/// its part by this table ([`part_of`]); a test holds it to the structs.
pub const PARTS: [(&str, &[&str]); 5] = [
    (
        "shot",
        &["frames", "fps", "frame_every", "start_frame", "at", "begin"],
    ),
    (
        "body",
        &[
            "resolution",
            "particles",
            "particles_per_cell",
            "thin_across",
            "jitter",
            "seed",
            "target_fit",
            "material",
            "initial_velocity",
        ],
    ),
    (
        "world",
        &["effects", "gravity", "drag", "ground", "colliders", "walls"],
    ),
    ("outputs", &["surfaces", "rebuilt_method", "usd", "volume"]),
    (
        "method",
        &[
            "segments",
            "steps_per_segment",
            "control_stride",
            "control",
            "control_resolution",
            "passes",
            "levels",
            "refine_iterations",
            "optimizer",
            "loss",
            "arrival_weight",
            "volume_weight",
            "path_weight",
            "lookahead",
            "waypoint_weight",
            "control_smoothing",
            "carry_controls",
            "fine_weight",
            "reach_weight",
            "kernel",
            "integrator",
            "device",
            "precision",
            "settle_drag",
            "dt",
            "inbetween",
            "progress_timing",
        ],
    ),
];

/// The part a setting's key belongs to (`frames` -> `shot`).
pub fn part_of(key: &str) -> Option<&'static str> {
    PARTS
        .iter()
        .find(|(_, keys)| keys.contains(&key))
        .map(|(part, _)| *part)
}

/// The shot: how long the sequence is, how its frames are numbered and timed, and when the
/// targets are reached.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Shot {
    /// Frames in the sequence, the rest shape first: the chain is cut into segments of
    /// `steps_per_segment` steps (the last one shorter when they do not divide the shot).
    /// `None`: `segments` segments.
    #[serde(default)]
    pub frames: Option<usize>,
    /// Frames per second of the sequence (default [`DEFAULT_FPS`], film's 24): frames are
    /// exactly `1 / fps` apart, each `k` morph steps of `1 / (fps k)` s, the fewest steps no
    /// longer than the reference's 1/120 s. `None`: a frame every `frame_every` steps of
    /// 1/120 s (or of `dt`).
    #[serde(default)]
    pub fps: Option<f64>,
    /// Export every n-th step as a frame (when `fps` is `None`).
    pub frame_every: usize,
    /// The number of the first frame (the rest shape) in file names and USD time codes (a
    /// shot's 1001). Keyframes (`at`) still count from 1, the rest shape.
    #[serde(default = "default_start_frame")]
    pub start_frame: usize,
    /// The frame (1 = the rest shape) by which each target is reached, in order (`--at`;
    /// `--arrive` for one target). Between keyframes a segment aims at the nodal masses of
    /// the previous keyframe blended toward the next one's along a smoothstep in time; before
    /// the first, "the previous keyframe" is where the body would be on its own (at rest, or
    /// falling under gravity). After the last the shape holds and settles. Empty: the last
    /// target at [`default_arrival`] and any earlier ones evenly before it. `[1]`: aim at the
    /// target from the first segment on.
    #[serde(default)]
    pub at: Vec<usize>,
    /// The frame the shape change begins on (`--begin`; 1 = the rest shape, the default).
    /// Before it the body is left to its physics with no controls (it holds still, or falls
    /// and lands), and the easing curve toward the first keyframe starts here; the motion
    /// measures count from here. A shot that should hold still or settle first says so here.
    #[serde(default = "default_begin")]
    pub begin: usize,
}

/// The body: its material, how finely it is sampled (the grid and particles), how the shapes
/// are placed, and how it starts moving.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Body {
    /// Grid cells across the domain's longest side.
    pub resolution: usize,
    /// A particle budget: when set, the resolution is chosen so the source gets about this
    /// many particles, whatever the shapes' proportions (and `resolution` is ignored).
    #[serde(default)]
    pub particles: Option<usize>,
    /// Particles per cell along each axis (k; k^3 per cell).
    pub particles_per_cell: usize,
    /// Particles the shapes' thin parts should get across (0: off): when no budget is set,
    /// the particles per cell are raised on the same grid until the thinnest parts of the
    /// source and the targets get this many, within [`super::sizing::DETAIL_BUDGET`]
    /// (docs/morph.md, "Particles for thin parts"). A resolution or particles per cell given
    /// on the command line or in a scene file turns it off.
    #[serde(default)]
    pub thin_across: f64,
    /// Random particle offsets in particle spacings (0 = regular lattice).
    pub jitter: f64,
    pub seed: u64,
    pub target_fit: TargetFit,
    pub material: MaterialConfig,
    /// The body's velocity at the first frame, in the source mesh's units per second.
    #[serde(default)]
    pub initial_velocity: [f64; 3],
}

/// What a run writes besides each frame's points.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outputs {
    /// Which surfaces each frame gets besides its points (`--surface`).
    pub surfaces: Surfaces,
    /// How the rebuilt surface is made from the particles (`--rebuilt-method`).
    #[serde(default)]
    pub rebuilt_method: RebuiltMethod,
    /// The USD file of the whole sequence: binary, text or none (`--usd`).
    #[serde(default)]
    pub usd: UsdFormat,
    /// Each frame's fill field (the rebuilt surface's) as an OpenVDB density grid in
    /// `volumes/` (`--volume`), and a Volume prim in the USD file.
    #[serde(default)]
    pub volume: bool,
}

/// The method's knobs: the chain of segments, the controls, the optimizer and the objective's
/// weights, the integrator and its time step, the schedule between keyframes. An artist
/// leaves them at the preset's values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Method {
    pub segments: usize,
    pub steps_per_segment: usize,
    /// Steps between control layers within a segment.
    pub control_stride: usize,
    /// How a control layer's `Fc` acts on `F`: a volume-preserving rest-shape factor
    /// (default) or the reference's `F + Fc` (docs/morph.md).
    #[serde(default)]
    pub control: ControlForm,
    /// Where Adam's free control values live: one per grid node (smooth across the body,
    /// default) or one per particle (the reference).
    #[serde(default)]
    pub control_resolution: ControlResolution,
    pub passes: usize,
    /// Coarse-to-fine levels, the morph's own grid included: 1 solves the morph on its grid
    /// alone; `n > 1` solves it first on a grid `2^(n-1)` times coarser, then on each grid
    /// twice as fine, every level's segments starting from the controls the level below
    /// found (`morph::levels`, docs/morph.md).
    #[serde(default = "one_level")]
    pub levels: usize,
    /// Evaluations per segment on the finest level when `levels > 1` (the coarser levels
    /// take `optimizer.iterations`). `None`: the same as the coarser levels.
    #[serde(default)]
    pub refine_iterations: Option<usize>,
    pub optimizer: OptimizerSettings,
    pub loss: MassLossKind,
    /// Weight of the kinetic energy at the end of each segment that ends after the final
    /// target's arrival: the held shape comes to rest.
    pub arrival_weight: f64,
    /// Weight of the volume cost (`loss::volume_cost`) averaged over every step of a segment.
    #[serde(default)]
    pub volume_weight: f64,
    /// Weight of the scheduled path: the mean mass loss, against where the schedule puts the
    /// body, of the states at the frames inside each segment (0: each segment's end alone).
    #[serde(default)]
    pub path_weight: f64,
    /// Look-ahead: each segment is optimized together with the next `lookahead` ones, as
    /// one window scored at every segment end inside it, and keeps its own controls; the
    /// next window starts from the rest (receding horizon, docs/morph.md "Motion"). 0: each
    /// segment alone.
    #[serde(default)]
    pub lookahead: usize,
    /// Weight of each earlier segment end inside a look-ahead window: its mass loss against
    /// that segment's target, times this (the window's end weighs 1).
    #[serde(default = "unit_weight")]
    pub waypoint_weight: f64,
    /// Weight of the controls' continuity in time: the mean over particles of
    /// `1/2 |Fc_l - Fc_(l-1)|^2` summed over a segment's layers, its first against the last
    /// layer kept before it (0: off).
    #[serde(default)]
    pub control_smoothing: f64,
    /// Where a look-ahead window's new segment starts: this share of the last control layer
    /// before it on every layer (0: zeros). Only with the continuity on, never on a held
    /// segment, and not on a finer level of `levels`, which starts from the coarser one's.
    #[serde(default)]
    pub carry_controls: f64,
    /// Weight of the mass loss on a grid twice as fine as the simulation's, which sees how
    /// particles are arranged within a cell (0: off).
    #[serde(default)]
    pub fine_weight: f64,
    /// Weight of the reach cost at the segment ends where the body should have taken the
    /// final target's shape (`morph::reach`): the target's surface pulls its nearest particle
    /// where that is farther than the tolerance (0: off).
    #[serde(default)]
    pub reach_weight: f64,
    pub kernel: KernelKind,
    /// The time integrator (Euler, or RK4 at four evaluations a step).
    #[serde(default)]
    pub integrator: IntegratorKind,
    /// Where the engine runs: the CPU, a GPU (the Euler step in f64, `morph_gpu`), or a GPU
    /// where one opens and the scene is one it runs (`--device`).
    #[serde(default)]
    pub device: DeviceKind,
    /// The GPU device's floating-point precision: f64 (the CPU engine's), or f32 for consumer
    /// GPUs (`--precision`; the CPU engine runs in f64).
    #[serde(default)]
    pub precision: Precision,
    /// Drag per second added once the final target is reached, eased in over
    /// [`SETTLE_RAMP_FRAMES`] frames: the held shape comes to rest (0: off).
    #[serde(default)]
    pub settle_drag: f64,
    /// Simulation time step in seconds, one per morph step; refused when above the elastic
    /// stability bound. `None` (the default): morph steps of 1/120 s (the reference's; with
    /// `fps`, see [`super::MorphSettings::timing`]), each simulated in the fewest equal substeps that
    /// stay within half the bound, so a stiffer material or a finer grid costs time, never a
    /// shorter shot.
    pub dt: Option<f64>,
    /// What a segment aims at between two keyframes (`--inbetween`).
    #[serde(default)]
    pub inbetween: Inbetween,
    /// How far the schedule is re-timed by the in-between's own progress, 0..=1
    /// (`--progress-timing`): at 1 the in-between's IoU gain toward the next keyframe follows
    /// the easing curve itself; at 0 the easing weight blends the two shapes as it is (the
    /// distance blend's IoU then lags the curve by up to a fifth: docs/morph.md).
    #[serde(default)]
    pub progress_timing: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::morph::settings::MorphSettings;
    use std::collections::BTreeSet;

    #[test]
    fn the_parts_table_lists_every_field_of_every_part() {
        // Every optional setting given, so that each field appears in the serialized table.
        let mut s = MorphSettings::default();
        s.shot.frames = Some(97);
        s.body.particles = Some(9000);
        s.method.refine_iterations = Some(3);
        s.method.dt = Some(1e-3);
        let table = toml::Table::try_from(&s).unwrap();
        for (part, keys) in PARTS {
            let fields: BTreeSet<&str> = (table[part].as_table().unwrap().keys())
                .map(String::as_str)
                .collect();
            // The world is its list; its shorthand keys are read only (settings::world).
            let listed: BTreeSet<&str> = match part {
                "world" => ["effects"].into(),
                _ => keys.iter().copied().collect(),
            };
            assert_eq!(fields, listed, "[{part}]");
        }
        assert_eq!(table.len(), PARTS.len() + 1, "the parts and the preset");
    }
}
