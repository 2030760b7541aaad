//! Morph settings and presets.

use super::basis::ControlResolution;
use super::segment::{Optimizer, OptimizerSettings};
use crate::engine::integrator::IntegratorKind;
use crate::engine::mpm::{ControlForm, KernelKind};
use crate::engine::scene::MaterialConfig;
use crate::geometry::TargetFit;
pub use crate::io::usd::UsdFormat;
use crate::loss::MassLossKind;
use serde::{Deserialize, Serialize};

pub mod knobs;
mod parts;
mod validate;
mod world;

pub use parts::{Body, Method, Outputs, PARTS, Shot, part_of};
pub use world::{Ground, MIN_WALL_THICKNESS, MeshCollider, WallSettings, World};

pub use validate::CheckedSettings;

/// Allowed ranges of the count settings; [`MorphSettings::validate`] and the CLI's `--help`
/// both read them.
pub mod limits {
    use std::ops::RangeInclusive;
    pub const RESOLUTION: RangeInclusive<usize> = crate::geometry::placement::RESOLUTION_LIMITS;
    /// Particle budget (`--particles`).
    pub const PARTICLES: RangeInclusive<usize> = 100..=20_000_000;
    pub const PARTICLES_PER_CELL: RangeInclusive<usize> = 1..=4;
    /// `thin_across`: particles across the thinnest parts, at most.
    pub const MAX_THIN_ACROSS: f64 = 8.0;
    pub const SEGMENTS: RangeInclusive<usize> = 1..=10_000;
    pub const STEPS: RangeInclusive<usize> = 1..=10_000;
    pub const PASSES: RangeInclusive<usize> = 1..=100;
    /// `--levels`: coarse-to-fine levels, the finest included.
    pub const LEVELS: RangeInclusive<usize> = 1..=4;
    pub const LOOKAHEAD: RangeInclusive<usize> = 0..=4;
    pub const ITERATIONS: RangeInclusive<usize> = 1..=100_000;
    pub const FRAME_EVERY: RangeInclusive<usize> = 1..=1_000_000;
    /// `--frames`: the rest shape and at least one more; at most an hour at 24 fps.
    pub const FRAMES: RangeInclusive<usize> = 2..=100_000;
    /// The first frame's number (a shot's 1001); names stay within 8 digits.
    pub const START_FRAME: RangeInclusive<usize> = 0..=9_000_000;
    /// Target meshes (keyframes) in one morph.
    pub const TARGETS: RangeInclusive<usize> = 1..=1_000;
    /// `--threads`: more than the machine's cores is lowered to them (with a warning).
    pub const THREADS: RangeInclusive<usize> = 1..=1024;
    /// `--fps` at most.
    pub const MAX_FPS: f64 = 1000.0;
}

/// The frame rate a sequence plays at unless told otherwise: film's.
pub const DEFAULT_FPS: f64 = 24.0;

/// Frames over which `settle_drag` eases in after the final target's arrival: switched on at
/// once it would be a jolt.
pub const SETTLE_RAMP_FRAMES: f64 = 6.0;

/// Named bundles of chain length and effort. See `docs/morph.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// A quick look: short chain (6 segments), 6 iterations per segment.
    Draft,
    /// The everyday setting: 12 segments, 12 iterations per segment.
    #[default]
    Default,
    /// The default settings on a chain twice as long (24 segments): the body has twice the
    /// time to take the target's shape and settle.
    Final,
}

impl Preset {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Preset; 3] = [Preset::Draft, Preset::Default, Preset::Final];

    /// What the preset measured: the quality judge's IoU with the target and fill, and the
    /// wall time, for sphere -> spot on 2 cores: docs/accuracy.md's "Presets" table (a test
    /// holds the two alike).
    pub fn measured(self) -> &'static str {
        match self {
            Preset::Draft => "sphere -> spot: IoU 0.855, fill 0.941, 16 s, 300 MB",
            Preset::Default => "sphere -> spot: IoU 0.879, fill 0.968, 74 s, 515 MB",
            Preset::Final => "sphere -> spot: IoU 0.915, fill 0.975, 9.1 min, 3.2 GB",
        }
    }
}

/// Everything that decides a morph's result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MorphSettings {
    pub preset: Preset,
    pub shot: Shot,
    pub body: Body,
    pub world: World,
    pub outputs: Outputs,
    pub method: Method,
}

/// The shape the schedule puts the body at between two keyframes (docs/morph.md, "Motion").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Inbetween {
    /// The two keyframes' nodal masses cross-faded by the easing weight (0.3.0).
    #[default]
    Crossfade,
    /// Their signed distances blended, at the cross-fade's mass (`morph/inbetween.rs`): a
    /// boundary that sweeps from one shape to the other.
    Shape,
}

impl Inbetween {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Inbetween; 2] = [Inbetween::Crossfade, Inbetween::Shape];
}

/// How the rebuilt surface is made (docs/geometry.md "Surfaces out").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RebuiltMethod {
    /// `deformed`, then each vertex moved onto the source's tangent planes that the
    /// particles near its surface carry and deform: sharp edges and corners (since 0.11.0).
    #[default]
    Sharp,
    /// Each particle's kernel deformed by its `F` (an ellipsoid that follows the material),
    /// two spacings wide, and the volume kept (0.3.0 to 0.10.0).
    Deformed,
    /// A narrow round kernel of one spacing per particle (0.2.0: shows the particle lattice
    /// as bumps).
    Lattice,
    /// splashsurf's reconstruction pipeline with its recommended settings (positions only).
    Splashsurf,
}

impl RebuiltMethod {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [RebuiltMethod; 4] = [
        RebuiltMethod::Sharp,
        RebuiltMethod::Deformed,
        RebuiltMethod::Lattice,
        RebuiltMethod::Splashsurf,
    ];
}

/// The surfaces written per frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Surfaces {
    /// Points only.
    None,
    /// The source mesh carried through the morph (its topology, UVs and groups; `carried/`).
    Carried,
    /// A closed surface rebuilt from the particles every frame (follows any topology;
    /// `meshes/`).
    Rebuilt,
    /// Both: the carried surface for texturing, the rebuilt one where the shape's topology
    /// changes (sphere -> torus) and the carried one cannot follow.
    #[default]
    Both,
    /// Both, and the last target's own mesh carried backward from the last frame
    /// (`target_carried/`): a shot can end on the target asset itself.
    All,
}

impl Surfaces {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Surfaces; 5] = [
        Surfaces::None,
        Surfaces::Carried,
        Surfaces::Rebuilt,
        Surfaces::Both,
        Surfaces::All,
    ];

    pub fn carried(self) -> bool {
        matches!(self, Surfaces::Carried | Surfaces::Both | Surfaces::All)
    }

    pub fn rebuilt(self) -> bool {
        matches!(self, Surfaces::Rebuilt | Surfaces::Both | Surfaces::All)
    }

    /// The last target's mesh carried backward (`target_carried/`).
    pub fn target_carried(self) -> bool {
        self == Surfaces::All
    }
}

fn one_level() -> usize {
    1
}

fn default_start_frame() -> usize {
    1
}

fn default_begin() -> usize {
    1
}

/// The resolution the objective's weights were tuned at: on other grids they are scaled to
/// weigh the same against the mass loss ([`super::WeightScale`]).
pub const TUNED_RESOLUTION: usize = 32;

/// The particles per cell (along each axis) the objective's weights were tuned at.
pub const TUNED_PER_CELL: usize = 2;

/// The shear modulus the controls' continuity was tuned at (the presets' material): for a
/// stiffer or softer body its weight is scaled by `mu / TUNED_SHEAR_MODULUS`
/// ([`super::WeightScale`]).
pub const TUNED_SHEAR_MODULUS: f64 = 38888.9;

/// The frame the last target is reached by default: 80% of the way through the sequence,
/// leaving the rest to hold the shape and settle.
pub fn default_arrival(frames: usize) -> usize {
    ((0.8 * frames.saturating_sub(1) as f64).round() as usize + 1).max(1)
}

/// The particle budget of the `final` preset.
pub const FINAL_PARTICLES: usize = 50_000;

impl Default for MorphSettings {
    fn default() -> Self {
        MorphSettings::preset(Preset::default())
    }
}

impl MorphSettings {
    pub fn preset(preset: Preset) -> MorphSettings {
        // Chosen from the measured front of quality against time (docs/accuracy.md): a second
        // pass over the chain cost twice the time and judged no better.
        let (segments, passes, iterations) = match preset {
            Preset::Draft => (6, 1, 6),
            Preset::Default => (12, 1, 12),
            Preset::Final => (12, 1, 12),
        };
        // `final` spends its time on detail: the default chain on about FINAL_PARTICLES
        // particles, whatever the shapes' proportions (the study in docs/accuracy.md: on
        // sphere -> spot and sphere -> stanford-bunny the only lever left that raised the
        // judge; 24 segments at the default's grid judged below `default`).
        let particles = (preset == Preset::Final).then_some(FINAL_PARTICLES);
        // The motion an animator keeps (docs/lab/2026-12-08-method-record.md, "Look-ahead"): each segment optimized
        // with the next and scored along the scheduled path. It doubles a segment's cost, so
        // the quick look goes without.
        // The controls' continuity in time and light waypoints take out the pulse a window
        // leaves at the segments' period (docs/lab/2026-12-08-method-record.md, "Continuous controls").
        let (lookahead, path_weight, control_smoothing, waypoint_weight) = match preset {
            Preset::Draft => (0, 0.0, 0.0, 1.0),
            Preset::Default | Preset::Final => (1, 1.0, 3.0e4, 0.1),
        };
        // `default` starts each window's new segment from half the last control layer (the
        // pulse at the segments' period falls to 0.03-0.05 on the five motion morphs) and
        // brakes its held segments harder (they settle at 0.01-0.03 of their peak speed):
        // docs/lab/2026-12-08-method-record.md, "The carry and the brake". `final` keeps 0.8's, measured at its
        // budget; `draft`'s quick look keeps its own.
        let (carry_controls, arrival_weight) = match preset {
            Preset::Default => (0.5, 0.1),
            Preset::Draft | Preset::Final => (0.0, 0.03),
        };
        // `default` and `final` aim each segment at the two shapes' distance blend, re-timed
        // a quarter of the way to its own progress: every motion goal met on the five motion
        // morphs at `default`, bob -> spot's fill 0.781 -> 0.894 there (the README job's
        // 0.923 -> 0.896), and at `final` 0.858 -> 0.920 with spot and stanford-bunny level
        // (docs/lab/2026-12-08-method-record.md, "Progress timing"). `draft`'s quick look keeps the cross-fade.
        let (inbetween, progress_timing) = match preset {
            Preset::Default | Preset::Final => (Inbetween::Shape, 0.25),
            Preset::Draft => (Inbetween::Crossfade, 0.0),
        };
        // `final` pulls the target's thin parts in (docs/morph.md, "Reach"): at its budget
        // sphere -> stanford-bunny's fill 0.969 -> 0.981 and reach 2.95 / 4.78 -> 1.17 / 1.62
        // spacings, spot level (0.974 -> 0.975), bob -> spot 0.920 -> 0.914. An option at
        // the others (it wins on six of seven morphs at `default` and loses on a small one).
        let reach_weight = if preset == Preset::Final { 10.0 } else { 0.0 };
        // `default` gives a thin leg or ear particles to hold it where the grid's two per
        // cell cannot (docs/morph.md, "Particles for thin parts"); `final` has its budget,
        // `draft` is the quick look.
        let thin_across = if preset == Preset::Default { 2.5 } else { 0.0 };
        MorphSettings {
            preset,
            shot: Shot {
                frames: None,
                fps: Some(DEFAULT_FPS),
                frame_every: 3,
                start_frame: 1,
                at: Vec::new(),
                begin: default_begin(),
            },
            body: Body {
                resolution: 32,
                particles,
                particles_per_cell: TUNED_PER_CELL,
                thin_across,
                jitter: 0.0,
                seed: 0,
                target_fit: TargetFit::MatchVolume,
                material: MaterialConfig {
                    model: Default::default(),
                    mu: TUNED_SHEAR_MODULUS,
                    lambda: 58333.0,
                    density: 40.0,
                },
                initial_velocity: [0.0; 3],
            },
            world: World::preset(),
            outputs: Outputs {
                surfaces: Surfaces::default(),
                rebuilt_method: RebuiltMethod::default(),
                usd: UsdFormat::default(),
                volume: false,
            },
            method: Method {
                segments,
                steps_per_segment: 30,
                control_stride: 10,
                control: ControlForm::default(),
                control_resolution: ControlResolution::default(),
                passes,
                levels: 1,
                refine_iterations: None,
                optimizer: OptimizerSettings {
                    kind: Optimizer::Adam,
                    iterations,
                    learning_rate: Optimizer::Adam.default_learning_rate(),
                    line_search_tries: 15,
                    gd_tol: 1e-3,
                },
                loss: MassLossKind::Log,
                arrival_weight,
                volume_weight: 400.0,
                path_weight,
                lookahead,
                waypoint_weight,
                control_smoothing,
                carry_controls,
                fine_weight: 1.0,
                reach_weight,
                kernel: KernelKind::Cubic,
                integrator: IntegratorKind::Euler,
                device: crate::gpu::DeviceKind::Cpu,
                precision: crate::gpu::Precision::F64,
                settle_drag: 12.0,
                dt: None,
                inbetween,
                progress_timing,
            },
        }
    }

    /// Checks the number of targets a morph is given against [`limits::TARGETS`] and `at`
    /// (one frame per target), before any mesh is read.
    pub fn validate_targets(&self, targets: usize) -> Result<(), String> {
        if !limits::TARGETS.contains(&targets) {
            return Err(format!(
                "{targets} target meshes given; a morph takes {} to {}",
                limits::TARGETS.start(),
                limits::TARGETS.end()
            ));
        }
        if !self.shot.at.is_empty() && self.shot.at.len() != targets {
            return Err(format!(
                "--at gives {} frame(s) for {targets} target(s): give one frame per target",
                self.shot.at.len()
            ));
        }
        // Spread over the shot (no --at): each target needs a frame of its own after the
        // first, up to the default arrival.
        let frames = self.timing().frame_count();
        let room = default_arrival(frames).saturating_sub(1);
        if self.shot.at.is_empty() && targets > room {
            return Err(format!(
                "{targets} target meshes need a keyframe each, but a shot of {frames} frames has room for {room} (frames 2 to {}): give fewer targets, a longer shot (--frames, --seconds) or --at",
                room + 1
            ));
        }
        Ok(())
    }

    /// The objective's weights set far above their defaults (a hundred times, or above a
    /// million where the default is 0), as `--name value (default d)`: what to lower when the
    /// objective overflows or drowns the mass loss.
    pub fn outsized_weights(&self) -> Vec<String> {
        let d = MorphSettings::default();
        [
            (
                "volume-weight",
                self.method.volume_weight,
                d.method.volume_weight,
            ),
            ("path-weight", self.method.path_weight, d.method.path_weight),
            ("fine-weight", self.method.fine_weight, d.method.fine_weight),
            (
                "reach-weight",
                self.method.reach_weight,
                d.method.reach_weight,
            ),
            (
                "arrival-weight",
                self.method.arrival_weight,
                d.method.arrival_weight,
            ),
            (
                "waypoint-weight",
                self.method.waypoint_weight,
                d.method.waypoint_weight,
            ),
            (
                "control-smoothing",
                self.method.control_smoothing,
                d.method.control_smoothing,
            ),
        ]
        .into_iter()
        .filter(|&(_, v, d)| {
            let bound = if d > 0.0 { 1e2 * d } else { 1e6 };
            !(v.abs() <= bound)
        })
        .map(|(name, v, d)| format!("`{}` {v:e} (default {d})", name.replace('-', "_")))
        .collect()
    }

    /// The frames a shot of `seconds` holds at this frame rate, the rest shape first
    /// (`--seconds`; 4 s at 24 fps: 97).
    pub fn frames_for(&self, seconds: f64) -> Result<usize, String> {
        let shot = self.timing();
        let interval = self.method.dt.unwrap_or(shot.step) * shot.frame_every as f64;
        let frames = (seconds / interval).round() + 1.0;
        if !(seconds.is_finite() && seconds > 0.0) || frames > *limits::FRAMES.end() as f64 {
            return Err(format!(
                "--seconds must be above 0 and at most {} frames long, got {seconds}",
                limits::FRAMES.end()
            ));
        }
        Ok((frames as usize).max(*limits::FRAMES.start()))
    }

    /// How the shapes are placed on a grid of `resolution` cells across.
    pub fn placement_options(&self, resolution: usize) -> crate::geometry::PlacementOptions {
        crate::geometry::PlacementOptions {
            resolution,
            target_fit: self.body.target_fit,
            ground: self.world.ground().map(|(height, _)| height),
            ..Default::default()
        }
    }

    /// The morph step (seconds) and the morph steps between frames.
    fn step_and_frame_every(&self) -> (f64, usize) {
        match self.shot.fps {
            Some(fps) => {
                // The fewest steps per frame that keep each no longer than the reference's.
                let k = ((1.0 / fps) / super::MORPH_STEP * (1.0 - 1e-12))
                    .ceil()
                    .max(1.0);
                (1.0 / (fps * k), k as usize)
            }
            None => (super::MORPH_STEP, self.shot.frame_every),
        }
    }

    /// The shot's timing: the morph step, the steps between frames and each segment's steps.
    pub fn timing(&self) -> Timing {
        let (step, frame_every) = self.step_and_frame_every();
        let segment_steps = match self.shot.frames {
            Some(n) => {
                let total = n.saturating_sub(1) * frame_every;
                let per = self.method.steps_per_segment.max(1);
                (0..total.div_ceil(per))
                    .map(|i| (total - i * per).min(per))
                    .collect()
            }
            None => vec![self.method.steps_per_segment; self.method.segments],
        };
        Timing {
            step,
            frame_every,
            segment_steps,
        }
    }
}

/// The timing of a morph's sequence (see [`MorphSettings::timing`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Timing {
    /// Seconds per morph step (each simulated in substeps where the material needs them).
    pub step: f64,
    /// Morph steps between frames.
    pub frame_every: usize,
    /// Morph steps of each segment, in order.
    pub segment_steps: Vec<usize>,
}

impl Timing {
    /// Frames written: the rest shape, then one every `frame_every` steps.
    pub fn frame_count(&self) -> usize {
        self.segment_steps.iter().sum::<usize>() / self.frame_every.max(1) + 1
    }
}

/// A weight of 1: what a setting missing from an older file means.
fn unit_weight() -> f64 {
    1.0
}
