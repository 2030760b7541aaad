//! The morph: a chain of segments, each optimized so the body flows toward the target,
//! refined over several passes (design.md section 4).
//!
//! A pass runs the segments in order, each starting from the full particle state where the
//! previous one ended. Later passes start every segment from the previous pass's controls
//! and re-optimize them from the (now different) state the chain reaches. Frames come from
//! the accepted rollouts of the last pass.

pub mod basis;
pub mod checkpoint;
pub mod inbetween;
pub mod levels;
pub mod memory;
pub mod metrics;
pub mod motion;
pub mod output;
pub mod quality;
pub mod scene_file;
pub mod segment;
pub mod settings;
pub mod sinks;

use crate::geometry::{Jitter, LoadedMesh, MeshError, MorphGeometry};
use crate::integrator::{Engine, Integrator};
use crate::loss::{FINE_KERNEL, FineMassLoss, MassLoss};
use crate::mpm::model::Model;
use crate::mpm::{SimError, State};
use crate::scene::{EffectConfig, SceneConfig};
use nalgebra::{Matrix3, Vector3};
use segment::{Layers, OptimizerSettings, PathPoint, Segment};
use serde::{Deserialize, Serialize};
pub use settings::{MorphSettings, Preset};
pub use sinks::{FrameRecord, FrameSink, SinkFrame};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Progress of a morph, one value per event (printed as JSON lines by `--json`).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum MorphEvent {
    Setup {
        particles: usize,
        target_particles: usize,
        grid_cells: [usize; 3],
        dx: f64,
        dt: f64,
        segments: usize,
        passes: usize,
        iterations: usize,
        frames: usize,
        warnings: Vec<String>,
    },
    Iteration {
        pass: usize,
        segment: usize,
        iteration: usize,
        loss: f64,
        seconds: f64,
    },
    Segment {
        pass: usize,
        segment: usize,
        initial_loss: f64,
        loss: f64,
        evaluations: usize,
        seconds: f64,
    },
    /// A coarse-to-fine level starts (when `levels > 1`): level 1 is the coarsest, level
    /// `levels` the morph's own grid, the one whose frames are written.
    Level {
        level: usize,
        levels: usize,
        particles: usize,
        grid_cells: [usize; 3],
        segments: usize,
        iterations: usize,
    },
    Done {
        seconds: f64,
        loss: f64,
        frames: usize,
    },
}

/// JSON has no infinity: serde_json writes it as null, and null reads back as infinity.
fn null_is_infinite<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

/// The finer loss grid splits each simulation cell this many times per axis: one particle
/// per fine cell at the default two per cell.
pub const FINE_REFINE: usize = 2;

/// One optimizer evaluation, for the manifest and the loss plot.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct IterationRecord {
    pub pass: usize,
    pub segment: usize,
    pub iteration: usize,
    /// Infinite (written as null) for a step that was undone: it blew the simulation up, or,
    /// as a segment's first step, raised the objective.
    #[serde(deserialize_with = "null_is_infinite")]
    pub loss: f64,
    /// Wall seconds since the optimization started.
    pub seconds: f64,
}

/// Summary of one optimized segment.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SegmentRecord {
    pub pass: usize,
    pub segment: usize,
    #[serde(deserialize_with = "null_is_infinite")]
    pub initial_loss: f64,
    #[serde(deserialize_with = "null_is_infinite")]
    pub loss: f64,
    pub evaluations: usize,
    pub seconds: f64,
    /// The smallest and largest `J = det F` of any particle after any step of the segment's
    /// accepted rollout (absent in records written before they were kept).
    #[serde(default = "no_j", deserialize_with = "null_is_nan")]
    pub min_j: f64,
    #[serde(default = "no_j", deserialize_with = "null_is_nan")]
    pub max_j: f64,
    /// Norm of the objective's gradient (with respect to the optimizer's free values) at the
    /// segment's first and last gradient evaluation: gradient health (see docs/morph.md).
    #[serde(default = "no_j", deserialize_with = "null_is_nan")]
    pub grad_norm_first: f64,
    #[serde(default = "no_j", deserialize_with = "null_is_nan")]
    pub grad_norm_last: f64,
}

/// Not recorded (NaN, written as null).
fn no_j() -> f64 {
    f64::NAN
}

fn null_is_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Everything set up for a morph: particles, the model and its integrator, loss.
pub struct Prepared {
    pub settings: MorphSettings,
    pub geometry: MorphGeometry,
    pub engine: Engine,
    pub loss: MassLoss,
    /// The mass loss on the finer grid, when its weight is positive.
    pub fine_loss: Option<FineMassLoss>,
    pub initial: State,
    /// Simulation steps per morph step (see [`MorphSettings::dt`]).
    pub substeps: usize,
    /// Morph steps of each segment (see [`MorphSettings::shot`]).
    pub segment_steps: Vec<usize>,
    /// When each target is reached and what the segments before it aim at (`--at`).
    pub schedule: Schedule,
    /// Bytes the tape of one segment rollout may hold (`usize::MAX`: no cap); set by
    /// [`Prepared::plan_memory`].
    pub tape_budget: usize,
    /// The same morph on a grid half as fine, solved first when `settings.levels > 1`
    /// (itself with its own coarser level when more remain).
    pub coarse: Option<Box<Prepared>>,
}

/// Why a morph failed.
#[derive(Debug, thiserror::Error)]
pub enum MorphError {
    #[error("{0}")]
    Settings(String),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("simulation: {0}")]
    Sim(#[from] SimError),
    #[error("{0}")]
    Output(String),
    /// A refused or impossible `--resume`.
    #[error("{0}")]
    Resume(String),
    /// Stopped on request (`signal` is the signal number when a signal asked). `kept`: the
    /// staging folder holds a checkpoint for `--resume` (false when no segment had completed,
    /// and then the staging folder is removed).
    #[error("interrupted")]
    Interrupted { signal: usize, kept: bool },
}

/// When each keyframe target is reached, and the nodal masses a segment aims at before it
/// (see [`MorphSettings::at`]).
pub struct Schedule {
    /// Morph step by which each target is reached, in order (the last is the final target).
    pub steps: Vec<usize>,
    /// The nodal masses (simulation grid, fine loss grid) of each keyframe target before the
    /// last, in order; the last one's are the loss's target.
    pub keyframes: Vec<(Vec<f64>, Option<Vec<f64>>)>,
    /// Where the body would be on its own, by morph step: the source's positions at the end of
    /// each segment that ends before the first keyframe (and at each frame before it when the
    /// path term is on), from a run without controls. Empty
    /// when nothing moves a body at rest (no gravity, no initial velocity): it stays where it
    /// starts.
    pub passive: Vec<(usize, Vec<Vector3<f64>>)>,
}

impl Prepared {
    /// The resolution whose source fill comes nearest `settings.particles` by the shapes'
    /// volumes ([`MorphGeometry::estimate`]; the fill then refines it).
    pub fn resolution_for_budget(
        settings: &MorphSettings,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<usize, MorphError> {
        const PROBE: usize = 32;
        let budget = settings.particles.unwrap_or(0) as f64;
        let at_probe = MorphGeometry::estimate(
            source,
            targets,
            &settings.placement_options(PROBE),
            settings.particles_per_cell,
        )?;
        let limits = settings::limits::RESOLUTION;
        let r = PROBE as f64 * (budget / at_probe.source_particles.max(1.0)).cbrt();
        Ok((r.round() as usize).clamp(*limits.start(), *limits.end()))
    }

    /// The grid and particle counts this morph will have, estimated before setup (see
    /// [`MorphGeometry::estimate`]): what [`memory::check_before_setup`] checks.
    pub fn estimate(
        settings: &MorphSettings,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<crate::geometry::SizeEstimate, MorphError> {
        let resolution = match settings.particles {
            None => settings.resolution,
            Some(_) => Prepared::resolution_for_budget(settings, source, targets)?,
        };
        Ok(MorphGeometry::estimate(
            source,
            targets,
            &settings.placement_options(resolution),
            settings.particles_per_cell,
        )?)
    }

    /// Places the source and the targets (meshes a program holds: pass each through
    /// [`crate::geometry::prepare_mesh`], the checks and repairs loading applies, with the name
    /// its messages should use), fills the source with particles, builds the model and the
    /// losses. The targets are reached in turn, each at its frame in [`MorphSettings::at`]
    /// (spread over the shot when empty), the last being the final one. [`Job::prepare`] does
    /// the same from files.
    pub fn from_meshes(
        settings: &MorphSettings,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<Prepared, MorphError> {
        settings.validate().map_err(MorphError::Settings)?;
        if !settings.at.is_empty() && settings.at.len() != targets.len() {
            return Err(MorphError::Settings(format!(
                "--at gives {} frame(s) for {} target(s): give one frame per target",
                settings.at.len(),
                targets.len()
            )));
        }
        let jitter = (settings.jitter > 0.0).then_some(Jitter {
            amount: settings.jitter,
            seed: settings.seed,
        });
        let geometry_at = |resolution: usize| {
            let placement = settings.placement_options(resolution);
            MorphGeometry::with_keyframes(
                source,
                targets,
                &placement,
                settings.particles_per_cell,
                jitter,
            )
        };
        let mut settings = settings.clone();
        let geometry = match settings.particles {
            None => geometry_at(settings.resolution)?,
            Some(budget) => {
                // Start from the resolution the shapes' volumes call for, then step one
                // resolution at a time toward the budget while the count gets closer: the
                // count grows with the resolution, so a larger budget never gets fewer
                // particles.
                let limits = settings::limits::RESOLUTION;
                let mut r = Prepared::resolution_for_budget(&settings, source, targets)?;
                let mut best = geometry_at(r)?;
                let count = |g: &MorphGeometry| g.source.positions.len();
                let up = count(&best) < budget;
                for _ in 0..MAX_BUDGET_STEPS {
                    let next = if up { r + 1 } else { r.saturating_sub(1) };
                    if !limits.contains(&next) {
                        break;
                    }
                    let g = geometry_at(next)?;
                    if count(&g).abs_diff(budget) >= count(&best).abs_diff(budget) {
                        break;
                    }
                    let crossed = (count(&g) >= budget) == up;
                    (r, best) = (next, g);
                    if crossed {
                        break;
                    }
                }
                settings.resolution = r;
                best
            }
        };
        // The shot's timing decides the segments and the frame spacing (`--fps`, `--frames`).
        let shot = settings.shot();
        settings.segments = shot.segment_steps.len();
        settings.frame_every = shot.frame_every;
        if settings.at.is_empty() {
            // The last target near the end, earlier ones evenly before it.
            let last = settings::default_arrival(shot.frame_count());
            let n = targets.len();
            settings.at = (1..=n).map(|k| 1 + (last - 1) * k / n).collect();
        }
        settings.validate().map_err(MorphError::Settings)?;
        let settings = &settings;
        let grid = geometry.placement.grid.clone();
        let mut scene = SceneConfig {
            grid,
            dt: settings.dt.unwrap_or(shot.step),
            kernel: settings.kernel,
            material: settings.material.clone(),
            effects: scene_effects(settings, &geometry.placement, &shot),
        };
        let volumes = vec![geometry.source.volume; geometry.source.positions.len()];
        // Without a set dt, a morph step (1/120 s, or what --fps makes) is split into the
        // fewest equal substeps that keep each within half the elastic stability bound: a
        // stiffer material or a finer grid costs more substeps, never a shorter shot. A set
        // dt above the bound is refused, with the bound.
        let (limit, wave_speed) = scene.stable_dt();
        // Physics no control can move: refused with the setting to change, not run into a
        // body that never moves.
        let segment_seconds = settings.dt.unwrap_or(shot.step) * settings.steps_per_segment as f64;
        if limit > segment_seconds {
            return Err(MorphError::Settings(format!(
                "the material is too soft for its density: its elastic waves ({wave_speed:.3e} grid units per second) cross {:.2e} grid cells in a segment of {segment_seconds:.3} s, less than one, so no control can move the body; raise --youngs-modulus or lower --density",
                segment_seconds / limit
            )));
        }
        let frame_seconds = settings.dt.unwrap_or(shot.step) * shot.frame_every as f64;
        for (name, drag) in [
            ("drag", settings.drag),
            ("drag and settle drag", settings.drag + settings.settle_drag),
        ] {
            if drag * frame_seconds > MAX_DRAG_DAMPING {
                return Err(MorphError::Settings(format!(
                    "{name} {drag:.3e} leaves e^-{:.3e} of the body's speed from one frame to the next ({frame_seconds:.4} s apart), so nothing can move; use at most {:.3e}",
                    drag * frame_seconds,
                    MAX_DRAG_DAMPING / frame_seconds
                )));
            }
        }
        // The drag's explicit form keeps a share `1 - c dt` of the momentum each step: at
        // most half of it may go in one step.
        let most_drag = settings.drag + settings.settle_drag;
        let limit = if most_drag > 0.0 {
            limit.min(1.0 / most_drag)
        } else {
            limit
        };
        let substeps = match settings.dt {
            Some(dt) if dt > limit => {
                return Err(MorphError::Settings(format!(
                    "--dt {dt} is above the stable bound {limit:.4e} s of this material on this grid (elastic wave speed {wave_speed:.4} over a cell of {:.4}); use --dt {:.4e} or less, or leave it out to substep automatically",
                    scene.grid.dx,
                    0.5 * limit
                )));
            }
            Some(_) => 1,
            None => substeps_for(shot.step, 0.5 * limit).map_err(MorphError::Settings)?,
        };
        scene.dt /= substeps as f64;
        let mut model = scene.model(volumes)?;
        model.control_form = settings.control;
        let engine = Engine::new(model, settings.integrator)?;
        let target = geometry.target_masses(settings.kernel, settings.material.density)?;
        let loss = MassLoss::new(settings.loss, target);
        let fine_loss = if settings.fine_weight > 0.0 {
            let grid = FineMassLoss::refine(&geometry.placement.grid, FINE_REFINE);
            let target =
                geometry.target_masses_on(&grid, FINE_KERNEL, settings.material.density)?;
            Some(FineMassLoss {
                grid,
                loss: MassLoss::new(settings.loss, target),
                weight: settings.fine_weight,
            })
        } else {
            None
        };
        let mut initial = State::at_rest(geometry.source.positions.clone());
        let v0 = geometry.placement.world_to_sim.scale * Vector3::from(settings.initial_velocity);
        initial.v.iter_mut().for_each(|v| *v = v0);
        let keyframes = (0..geometry.keyframes.len())
            .map(|k| {
                let density = settings.material.density;
                let on_sim =
                    geometry.keyframe_masses_on(k, &scene.grid, settings.kernel, density)?;
                let on_fine = match &fine_loss {
                    Some(f) => {
                        Some(geometry.keyframe_masses_on(k, &f.grid, FINE_KERNEL, density)?)
                    }
                    None => None,
                };
                Ok((on_sim, on_fine))
            })
            .collect::<Result<Vec<_>, SimError>>()?;
        let steps: Vec<usize> = settings
            .at
            .iter()
            .map(|f| (f - 1) * settings.frame_every)
            .collect();
        // Where the body goes on its own, up to the first keyframe: a run without controls,
        // when anything moves a body at rest, kept at the segments' ends (and at every frame
        // when the path term needs it there).
        let mut passive = Vec::new();
        if settings.gravity.is_some() || v0 != Vector3::zeros() {
            let mut ends = Vec::new();
            let mut end = 0;
            for &n in &shot.segment_steps {
                if settings.path_weight > 0.0 {
                    let every = settings.frame_every;
                    ends.extend((end + 1..end + n).filter(|s| s.is_multiple_of(every)));
                }
                end += n;
                if end >= steps[0] {
                    break;
                }
                ends.push(end);
            }
            ends.retain(|&s| s < steps[0]);
            if let Some(&last) = ends.last() {
                let mut state = initial.clone();
                let mut on_step = |k: usize, st: &State| {
                    if (k + 1).is_multiple_of(substeps) && ends.contains(&((k + 1) / substeps)) {
                        passive.push(((k + 1) / substeps, st.x.clone()));
                    }
                };
                crate::with_integrator!(&engine, sim => {
                    sim.forward_observed(&mut state, &[], 0, last * substeps, None, Some(&mut on_step))
                })?;
            }
        }
        let coarse = if settings.levels > 1 {
            let mut below = settings.clone();
            below.resolution = settings.resolution.div_ceil(2);
            below.particles = None;
            below.levels -= 1;
            below.refine_iterations = None;
            below.surfaces = settings::Surfaces::None;
            // The coarsest level, checked here so the message names the levels asked for.
            let coarsest = (1..settings.levels).fold(settings.resolution, |r, _| r.div_ceil(2));
            let min = *settings::limits::RESOLUTION.start();
            if coarsest < min {
                return Err(MorphError::Settings(format!(
                    "--levels {} solves the morph on a grid of {coarsest} cells first, below the least resolution {min}: use fewer levels or a finer grid",
                    settings.levels
                )));
            }
            Some(Box::new(Prepared::from_meshes(&below, source, targets)?))
        } else {
            None
        };
        Ok(Prepared {
            settings: settings.clone(),
            geometry,
            engine,
            loss,
            fine_loss,
            initial,
            substeps,
            segment_steps: shot.segment_steps,
            schedule: Schedule {
                steps,
                keyframes,
                passive,
            },
            tape_budget: usize::MAX,
            coarse,
        })
    }

    /// The model (grid, time step, particles...) whichever integrator runs it.
    pub fn model(&self) -> &Model {
        self.engine.model()
    }

    /// A state in world units (the source mesh's coordinates): positions, velocities (world
    /// units per second) and the volume ratio `J = det F` of every particle.
    pub fn world_frame(&self, state: &State) -> WorldFrame {
        let to_world = self.geometry.placement.sim_to_world();
        let (s, shift) = (to_world.scale, Vector3::from(to_world.translation));
        WorldFrame {
            x: state.x.iter().map(|p| s * p + shift).collect(),
            v: state.v.iter().map(|v| s * v).collect(),
            j: state.f.iter().map(|f| f.determinant()).collect(),
        }
    }

    /// Simulation steps of segment `k` (its morph steps times the substeps).
    pub fn sim_segment_steps(&self, k: usize) -> usize {
        self.segment_steps[k] * self.substeps
    }

    /// The global simulation step segment `k` starts at.
    pub fn sim_segment_first(&self, k: usize) -> usize {
        self.segment_steps[..k].iter().sum::<usize>() * self.substeps
    }

    /// The longest segment's simulation steps.
    pub fn max_sim_segment_steps(&self) -> usize {
        self.segment_steps.iter().max().copied().unwrap_or(0) * self.substeps
    }

    /// Control layers of each segment.
    pub fn segment_layers(&self) -> Vec<usize> {
        let stride = self.settings.control_stride;
        self.segment_steps
            .iter()
            .map(|s| s.div_ceil(stride))
            .collect()
    }

    /// Simulation steps between control layers.
    pub fn sim_control_stride(&self) -> usize {
        self.settings.control_stride * self.substeps
    }

    /// Simulation steps between exported frames.
    pub fn sim_frame_every(&self) -> usize {
        self.settings.frame_every * self.substeps
    }

    /// What segment `k` aims at: [`Prepared::blend_at`] its last step.
    pub fn segment_blend(&self, k: usize) -> (usize, usize, f64) {
        self.blend_at(self.segment_steps[..=k].iter().sum())
    }

    /// Where the schedule puts the body after morph step `step`, as `(from, to, w)`: keyframe
    /// indices (0 = where the body is on its own, `i` = the `i`-th target) and the smoothstep
    /// weight `3u^2 - 2u^3` of `to`, `u` the step's time between the two keyframes' times.
    /// `w = 1`: `to` itself.
    pub fn blend_at(&self, step: usize) -> (usize, usize, f64) {
        let steps = &self.schedule.steps;
        match steps.iter().position(|&s| step < s) {
            None => (steps.len(), steps.len(), 1.0),
            Some(i) => {
                let start = if i == 0 { 0 } else { steps[i - 1] };
                let u = (step - start) as f64 / (steps[i] - start) as f64;
                (i, i + 1, u * u * (3.0 - 2.0 * u))
            }
        }
    }

    /// The weight of the kinetic energy left at segment `k`'s end: the settings' for a segment
    /// that starts at or after the final target's arrival (the held shape comes to rest), none
    /// before (braking at every segment's end made the body pulse at the segments' period,
    /// and braking the segment that still has to finish the shape cost fill).
    pub fn segment_arrival_weight(&self, k: usize) -> f64 {
        let start: usize = self.segment_steps[..k].iter().sum();
        let arrival = self.schedule.steps.last().copied().unwrap_or(0);
        if start >= arrival {
            self.settings.arrival_weight * self.weight_scale().arrival
        } else {
            0.0
        }
    }

    /// What the settings' weights are multiplied by on this grid, so that they weigh the same
    /// against the mass loss at any resolution (see [`WeightScale`]).
    pub fn weight_scale(&self) -> WeightScale {
        WeightScale::at(self.settings.resolution)
    }

    /// The volume cost's weight on this grid.
    pub fn volume_weight(&self) -> f64 {
        self.settings.volume_weight * self.weight_scale().volume
    }

    /// Keyframe `i`'s nodal masses on the simulation grid, and on the fine grid when `fine`
    /// and the fine loss is on, after morph step `step` (keyframe 0: where the body would be
    /// on its own then).
    fn keyframe_masses(
        &self,
        i: usize,
        step: usize,
        fine: bool,
    ) -> Result<(Vec<f64>, Option<Vec<f64>>), SimError> {
        let fine_loss = self.fine_loss.as_ref().filter(|_| fine);
        let n = self.schedule.steps.len();
        if i == n {
            let fine = fine_loss.map(|f| f.loss.target.clone());
            return Ok((self.loss.target.clone(), fine));
        }
        if i > 0 {
            let (coarse, fine) = &self.schedule.keyframes[i - 1];
            return Ok((coarse.clone(), fine.clone().filter(|_| fine_loss.is_some())));
        }
        let x = self
            .schedule
            .passive
            .iter()
            .find(|(s, _)| *s == step)
            .map_or(&self.initial.x, |(_, x)| x);
        let model = self.model();
        let fine = match fine_loss {
            Some(f) => Some(crate::mpm::transfer::mass_grid(
                &f.grid,
                FINE_KERNEL,
                x,
                &model.mass,
            )?),
            None => None,
        };
        Ok((model.mass_grid(x)?, fine))
    }

    /// The nodal masses the schedule puts the body at after morph step `step` (simulation grid,
    /// fine grid when `fine`).
    fn scheduled_masses(
        &self,
        step: usize,
        fine: bool,
    ) -> Result<(Vec<f64>, Option<Vec<f64>>), SimError> {
        let (from, to, w) = self.blend_at(step);
        if w == 1.0 {
            return self.keyframe_masses(to, step, fine);
        }
        let (a, a_fine) = self.keyframe_masses(from, step, fine)?;
        let (b, b_fine) = self.keyframe_masses(to, step, fine)?;
        let blend =
            |grid: &crate::mpm::grid::GridSpec, a: &[f64], b: &[f64]| match self.settings.inbetween
            {
                settings::Inbetween::Crossfade => a
                    .iter()
                    .zip(b)
                    .map(|(s, t)| (1.0 - w) * s + w * t)
                    .collect(),
                settings::Inbetween::Shape => {
                    inbetween::in_between(grid.nodes(), a, b, w, self.full_nodal_mass(grid.dx))
                }
            };
        let coarse = blend(&self.model().grid, &a, &b);
        let fine = match (a_fine, b_fine, &self.fine_loss) {
            (Some(a), Some(b), Some(f)) => Some(blend(&f.grid, &a, &b)),
            _ => None,
        };
        Ok((coarse, fine))
    }

    /// The nodal mass of a node deep inside the body at rest on a grid of spacing `dx`
    /// (simulation units): the particles' mean mass times the particles per cell.
    fn full_nodal_mass(&self, dx: f64) -> f64 {
        let mass = &self.model().mass;
        let mean = mass.iter().sum::<f64>() / mass.len().max(1) as f64;
        let spacing = self.model().grid.dx / self.settings.particles_per_cell as f64;
        mean * (dx / spacing).powi(3)
    }

    /// The losses segment `k` optimizes at its end: against the nodal masses of
    /// [`Prepared::segment_blend`], the final target's once it is reached.
    pub fn segment_losses(
        &self,
        k: usize,
    ) -> Result<
        (
            std::borrow::Cow<'_, MassLoss>,
            Option<std::borrow::Cow<'_, FineMassLoss>>,
        ),
        SimError,
    > {
        use std::borrow::Cow;
        let (from, to, _) = self.segment_blend(k);
        if from == to && to == self.schedule.steps.len() {
            return Ok((
                Cow::Borrowed(&self.loss),
                self.fine_loss.as_ref().map(Cow::Borrowed),
            ));
        }
        let end = self.segment_steps[..=k].iter().sum();
        let (coarse, fine) = self.scheduled_masses(end, true)?;
        let loss = MassLoss::new(self.loss.kind, coarse);
        let fine = self.fine_loss.as_ref().map(|f| {
            Cow::Owned(FineMassLoss {
                grid: f.grid.clone(),
                loss: MassLoss::new(f.loss.kind, fine.expect("made with the fine loss")),
                weight: f.weight,
            })
        });
        Ok((Cow::Owned(loss), fine))
    }

    /// The path points inside segment `k`: the state at each frame before the segment's end,
    /// against the nodal masses the schedule puts the body at then (simulation grid only: the
    /// fine loss weighs on the segment's end).
    pub fn segment_path(&self, k: usize) -> Result<Vec<PathPoint>, SimError> {
        if self.settings.path_weight == 0.0 {
            return Ok(Vec::new());
        }
        let first: usize = self.segment_steps[..k].iter().sum();
        let end = first + self.segment_steps[k];
        let every = self.settings.frame_every;
        (first + 1..end)
            .filter(|s| s.is_multiple_of(every))
            .map(|s| {
                Ok(PathPoint {
                    step: s * self.substeps - 1,
                    loss: MassLoss::new(self.loss.kind, self.scheduled_masses(s, false)?.0),
                })
            })
            .collect()
    }

    /// Frames the chain exports: the initial state and every `frame_every`-th step.
    pub fn frame_count(&self) -> usize {
        self.segment_steps.iter().sum::<usize>() / self.settings.frame_every + 1
    }

    /// The quality judge's verdict on `state` (see [`quality`]).
    pub fn quality(&self, state: &State) -> quality::Quality {
        self.quality_against(state, self.schedule.steps.len() - 1)
    }

    /// The judge's verdict on `state` against target `t` (0-based, in keyframe order; the
    /// last is the final target).
    pub fn quality_against(&self, state: &State, t: usize) -> quality::Quality {
        let spacing = self.model().grid.dx / self.settings.particles_per_cell as f64;
        let (mesh, positions) = match self.geometry.keyframes.get(t) {
            Some(k) => (&k.sim, &k.particles.positions),
            None => (&self.geometry.target_sim, &self.geometry.target.positions),
        };
        let judge = quality::Judge::new(mesh, spacing, positions);
        let j: Vec<f64> = state.f.iter().map(|f| f.determinant()).collect();
        judge.judge(&state.x, &j)
    }

    /// A progress measure toward each target in keyframe order (see [`motion`]).
    pub fn progress_judges(&self) -> Vec<quality::Progress> {
        let spacing = self.model().grid.dx / self.settings.particles_per_cell as f64;
        self.geometry
            .keyframes
            .iter()
            .map(|k| &k.sim)
            .chain(std::iter::once(&self.geometry.target_sim))
            .map(|mesh| quality::Progress::new(mesh, &self.initial.x, spacing))
            .collect()
    }

    /// The motion measures of frames `from..=to` (1-based) of a run whose frames measured
    /// `stats`, against target `t` reached on frame `arrive` (see [`motion`]).
    pub fn motion_of(
        &self,
        speeds: &[f64],
        iou: &[f64],
        from: usize,
        to: usize,
        arrive: usize,
    ) -> motion::MotionMeasures {
        let every = self.settings.frame_every as f64;
        let mut boundaries = Vec::new();
        let mut end = 0;
        for &n in &self.segment_steps {
            end += n;
            boundaries.push(1 + (end as f64 / every).round() as usize);
        }
        let per_segment = self.segment_steps.iter().sum::<usize>() as f64
            / self.segment_steps.len().max(1) as f64
            / every;
        let section: Vec<usize> = boundaries
            .iter()
            .filter(|&&b| b >= from && b <= to)
            .map(|b| b + 1 - from)
            .collect();
        let to = to.min(speeds.len());
        let from = from.clamp(1, to.max(1));
        let iou = if iou.len() >= to {
            &iou[from - 1..to]
        } else {
            &[][..]
        };
        motion::measure(
            &speeds[from - 1..to],
            iou,
            &section,
            per_segment,
            arrive + 1 - from,
        )
    }

    pub fn loss_of(&self, state: &State) -> Result<f64, SimError> {
        let mass = self.model().mass_grid(&state.x)?;
        Ok(self.loss.value_and_grad(&mass).0)
    }
}

/// One exported frame: which, when, and the particles in world units.
pub struct Frame<'a> {
    /// 0-based frame number.
    pub index: usize,
    /// Global simulation step.
    pub step: usize,
    /// Simulated time, `step * dt` (seconds).
    pub time: f64,
    /// Positions, velocities and volume ratios in the source mesh's units.
    pub world: WorldFrame,
    /// The simulation state (simulation units), for writers that work on the grid's scale.
    pub state: &'a State,
    /// The morph the frame belongs to (its placement maps simulation to world units).
    pub prep: &'a Prepared,
}

impl<'a> Frame<'a> {
    fn new(prep: &'a Prepared, index: usize, step: usize, state: &'a State) -> Frame<'a> {
        Frame {
            index,
            step,
            time: step as f64 * prep.model().dt,
            world: prep.world_frame(state),
            state,
            prep,
        }
    }
}

/// A mesh a [`Job`] morphs: a file, or a mesh a program holds (checked and repaired by
/// [`crate::geometry::prepare_mesh`]) with the name its messages use.
pub enum MeshSource {
    File(PathBuf),
    Memory { name: String, mesh: LoadedMesh },
}

impl MeshSource {
    /// The mesh itself: the one held in memory, or `file`, what loading this one gave.
    fn mesh<'a>(&'a self, file: &'a Option<LoadedMesh>) -> &'a LoadedMesh {
        match (self, file) {
            (MeshSource::Memory { mesh, .. }, _) => mesh,
            (MeshSource::File(_), Some(mesh)) => mesh,
            (MeshSource::File(p), None) => unreachable!("'{}' was not loaded", p.display()),
        }
    }

    /// The name messages use for this mesh.
    fn name(&self) -> PathBuf {
        match self {
            MeshSource::File(p) => p.clone(),
            MeshSource::Memory { name, .. } => PathBuf::from(name),
        }
    }
}

/// One morph: a source, the targets it passes through in turn (the last is the final
/// shape; each reached at its frame in `settings.at`, spread over the shot when empty), and
/// the settings. What the command line runs, as a library call.
pub struct Job {
    pub source: MeshSource,
    pub targets: Vec<MeshSource>,
    pub settings: MorphSettings,
}

impl Job {
    /// Loads and places the meshes, fills the source with particles, builds the model.
    pub fn prepare(&self) -> Result<Prepared, MorphError> {
        let loaded = |m: &MeshSource| -> Result<Option<LoadedMesh>, MorphError> {
            Ok(match m {
                MeshSource::File(p) => Some(crate::geometry::load_mesh(p)?),
                MeshSource::Memory { .. } => None,
            })
        };
        let source_file = loaded(&self.source)?;
        let target_files = self
            .targets
            .iter()
            .map(loaded)
            .collect::<Result<Vec<_>, _>>()?;
        let names: Vec<PathBuf> = self.targets.iter().map(MeshSource::name).collect();
        let targets: Vec<(&LoadedMesh, &Path)> = self
            .targets
            .iter()
            .zip(&target_files)
            .zip(&names)
            .map(|((m, file), name)| (m.mesh(file), name.as_path()))
            .collect();
        let source_name = self.source.name();
        Prepared::from_meshes(
            &self.settings,
            (self.source.mesh(&source_file), &source_name),
            &targets,
        )
    }

    /// Prepares and runs the morph; the observer sees events and frames (world units) and
    /// may cancel it. Returns the prepared morph with its result.
    pub fn run(&self, observer: &mut dyn Observer) -> Result<(Prepared, MorphResult), MorphError> {
        let prep = self.prepare()?;
        let result = run(&prep, None, observer)?;
        Ok((prep, result))
    }
}

/// What the volume and arrival weights are multiplied by on a grid of `r` cells across,
/// so that a morph asks the same of its optimizer at any resolution. The simulation measures
/// lengths in cells of the [`settings::TUNED_RESOLUTION`] grid whatever `r`, so the body's
/// mass and the mass loss stay about the same while each particle carries `(32/r)^3` of the
/// mass: the volume cost, a sum over particles of their own `(ln J)^2`, grows as `r^3`
/// against the rest and is scaled by `(32/r)^3` on finer grids (never up on coarser ones). The arrival term is scaled alike: measured
/// on sphere -> spot (draft, r48), scaling volume alone lifted the fill from 0.727 to 0.828,
/// both together to 0.870 (r32 is unchanged, 0.911; docs/accuracy.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightScale {
    pub volume: f64,
    pub arrival: f64,
}

impl WeightScale {
    pub fn at(resolution: usize) -> WeightScale {
        // Never up: on coarser grids the scaled-up weights made more iterations judge worse
        // (24 cells, 2 / 4 / 8 evaluations: fill 0.716, 0.827, 0.760).
        let ratio = (settings::TUNED_RESOLUTION as f64 / resolution as f64).min(1.0);
        WeightScale {
            volume: ratio.powi(3),
            arrival: ratio.powi(3),
        }
    }
}

/// One frame in world units, see [`Prepared::world_frame`].
#[derive(Clone, Debug)]
pub struct WorldFrame {
    pub x: Vec<Vector3<f64>>,
    pub v: Vec<Vector3<f64>>,
    pub j: Vec<f64>,
}

/// Where a chain stands after a completed segment: everything a bitwise continuation needs.
/// Adam's moments and step size live within one segment's optimization, so the controls of
/// every segment and the particle state are the whole optimizer state between segments.
#[derive(Clone, Debug)]
pub struct RunProgress {
    pub pass: usize,
    /// Segments of `pass` completed.
    pub segments_done: usize,
    /// The full particle state at the end of the last completed segment.
    pub state: State,
    /// Controls per segment, per layer, per particle. Empty for a segment never optimized
    /// (its controls are zero) and, to keep memory flat, for a completed segment of the last
    /// pass once its checkpoint holds them (nothing reads them again).
    pub controls: Vec<Layers>,
    pub iterations: Vec<IterationRecord>,
    pub segments: Vec<SegmentRecord>,
    /// Frames exported so far.
    pub frames: usize,
    /// Wall seconds spent optimizing before this run (earlier, interrupted runs).
    pub elapsed_s: f64,
}

/// What watches a chain run: progress events, exported frames, completed segments (to
/// checkpoint them) and whether to stop.
pub trait Observer {
    fn event(&mut self, _event: &MorphEvent) {}
    /// An exported frame, in world units (and the simulation state it came from).
    fn frame(&mut self, _frame: &Frame) -> Result<(), MorphError> {
        Ok(())
    }
    /// A segment is complete; `segment` is the index whose controls changed.
    fn segment_done(&mut self, _progress: &RunProgress, _segment: usize) -> Result<(), MorphError> {
        Ok(())
    }
    /// A nonzero value stops the run at the next evaluation with [`MorphError::Interrupted`]
    /// carrying it (the CLI stores the signal number).
    fn stop_requested(&self) -> usize {
        0
    }
}

/// Result of a whole morph.
pub struct MorphResult {
    /// The coarse-to-fine levels solved before the last (none when `levels` is 1).
    pub levels: Vec<LevelRecord>,
    pub final_state: State,
    pub iterations: Vec<IterationRecord>,
    pub segments: Vec<SegmentRecord>,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub seconds: f64,
}

/// One coarse level's solve, as the manifest reports it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LevelRecord {
    /// 1 is the coarsest.
    pub level: usize,
    pub resolution: usize,
    pub particles: usize,
    pub evaluations: usize,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub seconds: f64,
}

/// A finer level's start: the controls the level below found for each segment, and the map
/// that carries them to this level's particles.
struct WarmStart {
    controls: Vec<Layers>,
    prolongation: levels::Prolongation,
}

/// Passes a coarser level's optimization progress on; its frames and completed segments
/// are nobody's business (the checkpoint and the files belong to the finest level).
struct LevelObserver<'a> {
    inner: &'a mut dyn Observer,
}

impl Observer for LevelObserver<'_> {
    fn event(&mut self, event: &MorphEvent) {
        if matches!(
            event,
            MorphEvent::Iteration { .. } | MorphEvent::Segment { .. }
        ) {
            self.inner.event(event);
        }
    }

    fn stop_requested(&self) -> usize {
        self.inner.stop_requested()
    }
}

impl Prepared {
    /// The event that starts this level of a morph of `levels` levels.
    fn level_event(&self, levels: usize) -> MorphEvent {
        let s = &self.settings;
        MorphEvent::Level {
            level: s.levels,
            levels,
            particles: self.initial.len(),
            grid_cells: self.model().grid.cells,
            segments: s.segments,
            iterations: self.level_iterations(),
        }
    }

    /// Evaluations per segment on this level.
    pub fn level_iterations(&self) -> usize {
        let s = &self.settings;
        match s.refine_iterations {
            Some(n) if s.levels > 1 => n,
            _ => s.optimizer.iterations,
        }
    }
}

/// The start of `prep`'s segments from its coarser level: that level solved (its own
/// coarser ones first), its controls, and the map carrying them up in material space.
/// `levels` is the whole morph's count (for the events).
fn warm_start(
    prep: &Prepared,
    levels: usize,
    observer: &mut dyn Observer,
    records: &mut Vec<LevelRecord>,
) -> Result<Option<WarmStart>, MorphError> {
    let Some(coarse) = prep.coarse.as_deref() else {
        return Ok(None);
    };
    let below = warm_start(coarse, levels, observer, records)?;
    observer.event(&coarse.level_event(levels));
    let clock = Instant::now();
    let progress = RunProgress::start(coarse);
    let mut quiet = LevelObserver { inner: observer };
    let (result, controls) = crate::with_integrator!(&coarse.engine, sim => {
        chain(coarse, sim, progress, clock, &mut quiet, below.as_ref(), true)
    })?;
    records.push(LevelRecord {
        level: coarse.settings.levels,
        resolution: coarse.settings.resolution,
        particles: coarse.initial.len(),
        evaluations: result.segments.iter().map(|r| r.evaluations).sum(),
        initial_loss: result.initial_loss,
        final_loss: result.final_loss,
        seconds: result.seconds,
    });
    // Both levels' rest positions in this level's simulation units (the grids are placed
    // apart by their padding, and scaled by their resolutions).
    let to_here = prep
        .geometry
        .placement
        .world_to_sim
        .after(&coarse.geometry.placement.sim_to_world());
    let rest: Vec<Vector3<f64>> = coarse.initial.x.iter().map(|x| to_here.apply(x)).collect();
    let spacing = to_here.scale / coarse.settings.particles_per_cell as f64;
    let prolongation = levels::Prolongation::new(&rest, &prep.initial.x, spacing);
    Ok(Some(WarmStart {
        controls,
        prolongation,
    }))
}

impl RunProgress {
    /// A chain not yet started.
    fn start(prep: &Prepared) -> RunProgress {
        RunProgress {
            pass: 0,
            segments_done: 0,
            state: prep.initial.clone(),
            controls: vec![Vec::new(); prep.settings.segments],
            iterations: Vec::new(),
            segments: Vec::new(),
            frames: 0,
            elapsed_s: 0.0,
        }
    }
}

/// Runs the chain, from the start or from `resume` (a checkpoint of an earlier run with the
/// same inputs and settings, which then continues bit for bit). The observer sees progress,
/// receives every exported frame of the last pass in order as soon as its segment is final,
/// and every completed segment.
pub fn run(
    prep: &Prepared,
    resume: Option<RunProgress>,
    observer: &mut dyn Observer,
) -> Result<MorphResult, MorphError> {
    let s = &prep.settings;
    let clock = Instant::now();
    observer.event(&MorphEvent::Setup {
        particles: prep.initial.len(),
        target_particles: prep.geometry.target.positions.len(),
        grid_cells: prep.model().grid.cells,
        dx: prep.model().grid.dx,
        dt: prep.model().dt,
        segments: s.segments,
        passes: s.passes,
        iterations: s.optimizer.iterations,
        frames: prep.frame_count(),
        warnings: prep.geometry.warnings.clone(),
    });
    let mut progress = match resume {
        Some(p) => {
            p.check(prep)?;
            p
        }
        None => RunProgress::start(prep),
    };
    if progress.segments_done == s.segments && progress.pass + 1 < s.passes {
        progress.pass += 1;
        progress.segments_done = 0;
    }
    // Coarse-to-fine: the levels below are solved again on a resume (deterministic, and an
    // eighth of the cost each) while some segment of the first pass has yet to start.
    let mut levels = Vec::new();
    let warm = if progress.pass == 0 && progress.segments_done < s.segments {
        warm_start(prep, s.levels, observer, &mut levels)?
    } else {
        None
    };
    if s.levels > 1 {
        observer.event(&prep.level_event(s.levels));
    }
    let (mut result, _) = crate::with_integrator!(&prep.engine, sim => {
        chain(prep, sim, progress, clock, observer, warm.as_ref(), false)
    })?;
    result.levels = levels;
    Ok(result)
}

/// The passes over the chain of segments, with the integrator the settings chose.
fn chain<I: Integrator>(
    prep: &Prepared,
    sim: &I,
    mut progress: RunProgress,
    clock: Instant,
    observer: &mut dyn Observer,
    warm: Option<&WarmStart>,
    keep_controls: bool,
) -> Result<(MorphResult, Vec<Layers>), MorphError> {
    let s = &prep.settings;
    let initial_loss = prep.loss_of(&prep.initial)?;
    let optimizer = OptimizerSettings {
        iterations: prep.level_iterations(),
        ..s.optimizer.clone()
    };
    let offset_s = progress.elapsed_s;
    let seconds = |clock: &Instant| offset_s + clock.elapsed().as_secs_f64();
    let (first_pass, first_segment) = (progress.pass, progress.segments_done);
    for pass in first_pass..s.passes {
        let last_pass = pass + 1 == s.passes;
        progress.pass = pass;
        let from = if pass == first_pass { first_segment } else { 0 };
        if from == 0 {
            progress.state = prep.initial.clone();
            progress.segments_done = 0;
            if last_pass {
                observer.frame(&Frame::new(prep, progress.frames, 0, &progress.state))?;
                progress.frames += 1;
            }
        }
        for k in from..s.segments {
            let seg_clock = Instant::now();
            let (loss, fine_loss) = prep.segment_losses(k)?;
            let path = prep.segment_path(k)?;
            let segment = Segment {
                sim,
                loss: &loss,
                fine_loss: fine_loss.as_deref(),
                start: &progress.state,
                first_step: prep.sim_segment_first(k),
                steps: prep.sim_segment_steps(k),
                stride: prep.sim_control_stride(),
                arrival_weight: prep.segment_arrival_weight(k),
                volume_weight: prep.volume_weight(),
                path: &path,
                path_weight: s.path_weight,
                resolution: s.control_resolution,
                tape_budget: prep.tape_budget,
            };
            let init = match (&progress.controls[k], warm) {
                (l, None) if l.is_empty() => {
                    vec![vec![Matrix3::zeros(); prep.initial.len()]; segment.num_layers()]
                }
                (l, Some(w)) if l.is_empty() => w.prolongation.apply(&w.controls[k]),
                (l, _) => l.clone(),
            };
            let mut stop = observer.stop_requested();
            let iterations = &mut progress.iterations;
            let result = segment.optimize(init, &optimizer, |iteration, loss| {
                let at = seconds(&clock);
                iterations.push(IterationRecord {
                    pass,
                    segment: k,
                    iteration,
                    loss,
                    seconds: at,
                });
                observer.event(&MorphEvent::Iteration {
                    pass,
                    segment: k,
                    iteration,
                    loss,
                    seconds: at,
                });
                stop = observer.stop_requested();
                stop == 0
            })?;
            let Some(result) = result.filter(|_| stop == 0) else {
                return Err(MorphError::Interrupted {
                    signal: stop,
                    kept: false,
                });
            };
            let (min_j, max_j) = result.j_range;
            let record = SegmentRecord {
                pass,
                segment: k,
                initial_loss: result.initial_loss,
                loss: result.loss,
                evaluations: result.evaluations,
                seconds: seg_clock.elapsed().as_secs_f64(),
                min_j,
                max_j,
                grad_norm_first: result.grad_norms.0,
                grad_norm_last: result.grad_norms.1,
            };
            observer.event(&MorphEvent::Segment {
                pass,
                segment: k,
                initial_loss: record.initial_loss,
                loss: record.loss,
                evaluations: record.evaluations,
                seconds: record.seconds,
            });
            progress.segments.push(record);
            if last_pass {
                // The accepted controls once more, to write the frames (the optimization keeps
                // no tape of every step: memory stays within its budget).
                let mut frame_err = Ok(());
                let last = segment.replay(&result.layers, &mut |global, state| {
                    if frame_err.is_ok() && (global + 1).is_multiple_of(prep.sim_frame_every()) {
                        frame_err =
                            observer.frame(&Frame::new(prep, progress.frames, global + 1, state));
                        progress.frames += 1;
                    }
                })?;
                frame_err?;
                debug_assert!(last == result.last, "a replay reproduces the rollout");
            }
            progress.controls[k] = result.layers;
            progress.state = result.last;
            progress.segments_done = k + 1;
            progress.elapsed_s = seconds(&clock);
            observer.segment_done(&progress, k)?;
            if last_pass && !keep_controls {
                progress.controls[k] = Vec::new();
            }
        }
    }
    let final_loss = prep.loss_of(&progress.state)?;
    let seconds = seconds(&clock);
    observer.event(&MorphEvent::Done {
        seconds,
        loss: final_loss,
        frames: progress.frames,
    });
    Ok((
        MorphResult {
            levels: Vec::new(),
            final_state: progress.state,
            iterations: progress.iterations,
            segments: progress.segments,
            initial_loss,
            final_loss,
            seconds,
        },
        progress.controls,
    ))
}

/// The most drag may damp the body between two frames, as an exponent: `e^-10` leaves
/// 0.005% of its speed, nothing a viewer could see move.
pub const MAX_DRAG_DAMPING: f64 = 10.0;

/// Resolutions `--particles` steps through from its estimate, at most.
const MAX_BUDGET_STEPS: usize = 8;

/// The morph's step when no dt is set: the reference's 1/120 s (simulated in substeps
/// where the material or the grid needs a shorter one).
pub const MORPH_STEP: f64 = 1.0 / 120.0;

/// Substeps past which a morph is refused (the material is too stiff for its grid).
pub const MAX_SUBSTEPS: usize = 10_000;

/// The effects a morph's settings call for, in the order they act: drag on the particles
/// (and the settle drag after the final arrival);
/// then on the grid gravity, the ground and the colliders, and last the walls. Nothing else
/// runs. World quantities (gravity, the ground's height, collider meshes) are mapped into
/// simulation units by `placement`.
fn scene_effects(
    settings: &MorphSettings,
    placement: &crate::geometry::Placement,
    shot: &settings::Shot,
) -> Vec<EffectConfig> {
    use crate::scene::ColliderConfig;
    let to_sim = placement.world_to_sim;
    let mut effects = Vec::new();
    if settings.drag > 0.0 {
        effects.push(EffectConfig::drag(settings.drag));
    }
    if settings.settle_drag > 0.0 {
        // From the final target's arrival frame on (frame 1 at time 0).
        let frame_seconds = settings.dt.unwrap_or(shot.step) * shot.frame_every as f64;
        let arrival = settings.at.last().copied().unwrap_or(1);
        effects.push(EffectConfig::Drag {
            coefficient: settings.settle_drag,
            start: (arrival - 1) as f64 * frame_seconds,
            ramp: settings::SETTLE_RAMP_FRAMES * frame_seconds,
        });
    }
    if let Some(g) = settings.gravity {
        effects.push(EffectConfig::Gravity {
            acceleration: (to_sim.scale * Vector3::from(g)).into(),
        });
    }
    if let Some(ground) = &settings.ground {
        effects.push(EffectConfig::Collider {
            shape: ColliderConfig::Plane {
                point: to_sim.apply(&Vector3::new(0.0, ground.height, 0.0)).into(),
                normal: [0.0, 1.0, 0.0],
            },
            friction: ground.friction,
        });
    }
    for c in &settings.colliders {
        effects.push(EffectConfig::Collider {
            shape: ColliderConfig::Mesh {
                path: c.mesh.clone(),
                scale: to_sim.scale,
                translation: to_sim.translation,
            },
            friction: c.friction,
        });
    }
    // Always: a safety net, so no kernel stencil can leave the grid.
    effects.push(EffectConfig::Walls {
        mode: settings.walls.mode,
        thickness: settings.walls.thickness,
    });
    effects
}

/// The fewest equal substeps of `step` that are each at most `bound` seconds.
pub fn substeps_for(step: f64, bound: f64) -> Result<usize, String> {
    let n = (step / bound).ceil();
    if !(n.is_finite() && n <= MAX_SUBSTEPS as f64) {
        return Err(format!(
            "the material needs a time step of {bound:.3e} s on this grid, {n:.0} substeps per 1/120 s step (at most {MAX_SUBSTEPS}); lower its stiffness or the resolution"
        ));
    }
    Ok(n.max(1.0) as usize)
}

/// A gradient this many times the first segment's first one has exploded.
pub const GRADIENT_EXPLODED: f64 = 1e6;
/// A gradient this many times smaller than the first segment's first one has vanished.
pub const GRADIENT_VANISHED: f64 = 1e-9;

/// Warnings about the gradients of a run's segments: a non-finite norm, or one that grew
/// past [`GRADIENT_EXPLODED`] or shrank below [`GRADIENT_VANISHED`] times the first
/// segment's first one (the scale this morph's objective set); and segments where no step
/// improved the objective while the morph was far from done.
pub fn run_warnings(segments: &[SegmentRecord]) -> Vec<String> {
    let Some(reference) = segments
        .iter()
        .map(|r| r.grad_norm_first)
        .find(|g| g.is_finite() && *g > 0.0)
    else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for r in segments {
        for g in [r.grad_norm_first, r.grad_norm_last] {
            let what = if g.is_nan() {
                continue; // No gradient taken (one iteration).
            } else if !g.is_finite() || g > GRADIENT_EXPLODED * reference {
                "exploded"
            } else if g < GRADIENT_VANISHED * reference {
                "vanished"
            } else {
                continue;
            };
            out.push(format!(
                "pass {} segment {}: the gradient {what} (norm {g:.3e}, first segment {reference:.3e}); its controls may not have moved as asked",
                r.pass + 1,
                r.segment + 1
            ));
            break;
        }
    }
    // A segment no step improved while it was far from its aim (its loss above half the
    // largest a segment started with): a body that has arrived, or that follows a schedule
    // of keyframes closely, has little left to gain, and is not warned about.
    let largest = segments
        .iter()
        .map(|r| r.initial_loss)
        .filter(|l| l.is_finite())
        .fold(0.0, f64::max);
    let stalled: Vec<String> = segments
        .iter()
        .filter(|r| r.evaluations > 1 && r.loss >= r.initial_loss && r.initial_loss > 0.5 * largest)
        .map(|r| format!("{}", r.segment + 1))
        .collect();
    if !stalled.is_empty() {
        out.push(format!(
            "no optimizer step improved segment(s) {} (its steps were too large, or a stiff material rang at every control layer: try a smaller --learning-rate)",
            stalled.join(", ")
        ));
    }
    out
}

impl RunProgress {
    /// A checkpoint must fit the run it continues (the identity hash already says the inputs
    /// and settings are the same; this guards against a damaged checkpoint).
    fn check(&self, prep: &Prepared) -> Result<(), MorphError> {
        let (s, particles) = (&prep.settings, prep.initial.len());
        let layers = prep.segment_layers();
        let fits = self.pass < s.passes
            && self.segments_done <= s.segments
            && self.state.len() == particles
            && self.controls.len() == s.segments
            && self.controls.iter().zip(&layers).all(|(l, &layers)| {
                l.is_empty() || (l.len() == layers && l.iter().all(|p| p.len() == particles))
            });
        if fits {
            Ok(())
        } else {
            Err(MorphError::Resume(
                "the checkpoint does not fit this run (damaged?); start over with --overwrite"
                    .into(),
            ))
        }
    }
}

#[cfg(test)]
mod warning_tests {
    use super::*;

    fn record(segment: usize, first: f64, last: f64, initial: f64, loss: f64) -> SegmentRecord {
        SegmentRecord {
            pass: 0,
            segment,
            initial_loss: initial,
            loss,
            evaluations: 4,
            seconds: 0.0,
            min_j: 1.0,
            max_j: 1.0,
            grad_norm_first: first,
            grad_norm_last: last,
        }
    }

    #[test]
    fn exploding_vanishing_and_stalled_segments_are_warned_about() {
        let healthy = [
            record(0, 100.0, 80.0, 10.0, 5.0),
            record(1, 90.0, 70.0, 5.0, 3.0),
        ];
        assert!(run_warnings(&healthy).is_empty());
        let w = run_warnings(&[
            record(0, 100.0, 80.0, 10.0, 5.0),
            record(1, 2e8, 1.0, 5.0, 3.0),
            record(2, 1e-8, 1e-8, 3.0, 2.0),
            record(3, f64::INFINITY, 1.0, 2.0, 1.0),
            record(4, f64::NAN, f64::NAN, 1.0, 1.0),
        ]);
        assert_eq!(w.len(), 3, "{w:?}");
        assert!(w[0].contains("segment 2: the gradient exploded"), "{w:?}");
        assert!(w[1].contains("segment 3: the gradient vanished"), "{w:?}");
        assert!(w[2].contains("segment 4: the gradient exploded"), "{w:?}");
        // No step improved the first segment: warned; the same late in a converged chain: not.
        let w = run_warnings(&[
            record(0, 100.0, 90.0, 10.0, 10.0),
            record(1, 1.0, 1.0, 1.0, 1.0),
        ]);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("segment(s) 1 "), "{w:?}");
    }
}
