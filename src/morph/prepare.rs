//! Setting a morph up: `Prepared::from_meshes` places the meshes, fills the source, builds
//! the model with the effects the settings call for (`scene_effects`), the shot's timing
//! and substeps, the keyframe schedule and the losses; and what the chain asks of it
//! (each segment's targets, path, weights).

use super::{MorphError, MorphSettings, WorldFrame, inbetween, motion, quality, segment, settings};

use super::reach::ReachLoss;
use crate::engine::Engine;
use crate::geometry::{Jitter, LoadedMesh, MorphGeometry};
use crate::integrator::Integrator;
use crate::loss::{FINE_KERNEL, FineMassLoss, MassLoss};
use crate::mpm::model::Model;
use crate::mpm::{SimError, State};
use crate::scene::{EffectConfig, SceneConfig};
use nalgebra::Vector3;
use segment::PathPoint;
use std::path::Path;

/// Everything set up for a morph: particles, the model and its integrator, loss.
pub struct Prepared {
    pub settings: MorphSettings,
    /// What the thin parts' rule chose ([`super::sizing`]; `None` when it was off).
    pub sizing: Option<super::sizing::Sizing>,
    pub geometry: MorphGeometry,
    pub engine: Engine,
    pub loss: MassLoss,
    /// The mass loss on the finer grid, when its weight is positive.
    pub fine_loss: Option<FineMassLoss>,
    /// The reach cost of the final target, when its weight is positive.
    pub reach: Option<ReachLoss>,
    pub initial: State,
    /// Simulation steps per morph step (see [`MorphSettings::dt`]).
    pub substeps: usize,
    /// Morph steps of each segment (see [`MorphSettings::shot`]).
    pub segment_steps: Vec<usize>,
    /// When each target is reached and what the segments before it aim at (`--at`).
    pub schedule: KeyframeSchedule,
    /// Bytes the tape of one segment rollout may hold (`usize::MAX`: no cap); set by
    /// [`Prepared::plan_memory`].
    pub tape_budget: usize,
    /// The same morph on a grid half as fine, solved first when `settings.levels > 1`
    /// (itself with its own coarser level when more remain).
    pub coarse: Option<Box<Prepared>>,
}

/// When each keyframe target is reached, and the nodal masses a segment aims at before it
/// (see [`MorphSettings::at`]).
pub struct KeyframeSchedule {
    /// Morph step by which each target is reached, in order (the last is the final target).
    pub steps: Vec<usize>,
    /// Morph step the shape change begins at ([`MorphSettings::begin`]): the easing toward
    /// the first keyframe starts here, and the segments that end by it run without controls.
    pub begin: usize,
    /// The nodal masses (simulation grid, fine loss grid) of each keyframe target before the
    /// last, in order; the last one's are the loss's target.
    pub keyframes: Vec<(Vec<f64>, Option<Vec<f64>>)>,
    /// Where the body would be on its own, by morph step: the source's positions at the end of
    /// each segment that ends before the first keyframe (and at each frame before it when the
    /// path term is on), from a run without controls. Empty
    /// when nothing moves a body at rest (no gravity, no initial velocity): it stays where it
    /// starts.
    pub passive: Vec<(usize, Vec<Vector3<f64>>)>,
    /// For each section (keyframe `i` to `i + 1`), how far its shape in-between has come at
    /// each weight (simulation grid; made on first use).
    pub timings: std::sync::OnceLock<Vec<Option<inbetween::ProgressTiming>>>,
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
    /// [`MorphGeometry::estimate`]; `settings` as [`super::sizing::size`] left them): what
    /// [`super::memory::check_before_setup`] checks.
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
    /// (spread over the shot when empty), the last being the final one. [`super::Job::prepare`] does
    /// the same from files.
    pub fn from_meshes(
        settings: &MorphSettings,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<Prepared, MorphError> {
        settings.validate().map_err(MorphError::Settings)?;
        settings
            .validate_targets(targets.len())
            .map_err(MorphError::Settings)?;
        let (settings, sizing) = super::sizing::size(settings, source, targets)?;
        Prepared::from_sized(&settings, sizing, source, targets)
    }

    /// [`Prepared::from_meshes`] with the thin parts' rule already applied to `settings`
    /// ([`super::sizing::size`]), which `sizing` records.
    pub fn from_sized(
        settings: &MorphSettings,
        sizing: Option<super::sizing::Sizing>,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<Prepared, MorphError> {
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
        let mut geometry = geometry;
        let overlaps = overlap_warnings(settings, &geometry)?;
        geometry.warnings.extend(overlaps);
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
        let counts = (geometry.source.positions.len(), scene.grid.node_count());
        if let Some(w) = long_run_warning(settings, &shot, substeps, counts) {
            geometry.warnings.push(w);
        }
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
        let reach = (settings.reach_weight > 0.0).then(|| {
            let spacing = geometry.placement.grid.dx / settings.particles_per_cell as f64;
            ReachLoss::new(&geometry.target_sim, spacing, settings.reach_weight)
        });
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
        let begin = (settings.begin - 1) * settings.frame_every;
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
            // The body's place where the shape change begins: the first section starts there.
            if begin > 0 && !ends.contains(&begin) {
                ends.push(begin);
                ends.sort_unstable();
            }
            ends.retain(|&s| s < steps[0]);
            if let Some(&last) = ends.last() {
                let mut state = initial.clone();
                let mut on_step = |k: usize, st: &State| {
                    if (k + 1).is_multiple_of(substeps) && ends.contains(&((k + 1) / substeps)) {
                        passive.push(((k + 1) / substeps, st.x.clone()));
                    }
                };
                crate::engine::with_integrator!(&engine, sim => {
                    sim.forward_observed(&mut state, &[], 0, last * substeps, None, Some(&mut on_step))
                })?;
            }
        }
        let coarse = if settings.levels > 1 {
            let mut below = settings.clone();
            below.resolution = settings.resolution.div_ceil(2);
            below.particles = None;
            below.thin_across = 0.0;
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
            sizing,
            geometry,
            engine,
            loss,
            fine_loss,
            reach,
            initial,
            substeps,
            segment_steps: shot.segment_steps,
            schedule: KeyframeSchedule {
                steps,
                begin,
                keyframes,
                passive,
                timings: std::sync::OnceLock::new(),
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

    /// The longest optimized rollout's simulation steps: a segment's, or its look-ahead
    /// window's.
    pub fn max_sim_segment_steps(&self) -> usize {
        (0..self.segment_steps.len())
            .map(|k| {
                (k..=self.window_end(k))
                    .map(|j| self.segment_steps[j])
                    .sum::<usize>()
            })
            .max()
            .unwrap_or(0)
            * self.substeps
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
                let start = if i == 0 {
                    self.schedule.begin
                } else {
                    steps[i - 1]
                };
                // Before the shape change begins the body is where it would be on its own.
                let u = step.saturating_sub(start) as f64 / (steps[i] - start) as f64;
                (i, i + 1, u * u * (3.0 - 2.0 * u))
            }
        }
    }

    /// Whether segment `k` ends by the frame the shape change begins on: it runs without
    /// controls (the body holds still, or falls and lands, as its physics has it) and is not
    /// optimized.
    pub fn segment_before_begin(&self, k: usize) -> bool {
        let end: usize = self.segment_steps[..=k].iter().sum();
        end <= self.schedule.begin
    }

    /// Whether segment `k` starts at or after the final target's arrival: the shape is held.
    fn segment_holds(&self, k: usize) -> bool {
        let start: usize = self.segment_steps[..k].iter().sum();
        start >= self.schedule.steps.last().copied().unwrap_or(0)
    }

    /// The weight of the kinetic energy left at segment `k`'s end: the settings' for a held
    /// segment (the held shape comes to rest), none before (braking at every segment's end
    /// made the body pulse at the segments' period, and braking the segment that still has
    /// to finish the shape cost fill).
    pub fn segment_arrival_weight(&self, k: usize) -> f64 {
        if self.segment_holds(k) {
            self.settings.arrival_weight * self.weight_scale().arrival
        } else {
            0.0
        }
    }

    /// The weight of segment `k`'s controls' continuity in time: the settings' before the
    /// final target's arrival, none for the held segments, which stop the flow rather than
    /// continue it (on a held-out horned figure the body still moved at 25% of its peak
    /// speed on the last frame with it, 16% without).
    pub fn segment_smoothing(&self, k: usize) -> f64 {
        if self.segment_holds(k) {
            0.0
        } else {
            self.settings.control_smoothing * self.weight_scale().smoothing
        }
    }

    /// What the settings' weights are multiplied by on this grid and for this material, so
    /// that they weigh the same at any resolution and stiffness (see [`WeightScale`]).
    pub fn weight_scale(&self) -> WeightScale {
        WeightScale::at(
            self.settings.resolution,
            self.settings.particles_per_cell,
            self.settings.material.mu,
        )
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
        // Re-timed so the in-between's own progress follows the easing curve, as far as the
        // settings ask (docs/morph.md, "Progress timing").
        let alpha = self.settings.progress_timing;
        let w = match (alpha > 0.0).then(|| self.section_timings()).transpose()? {
            Some(timings) => match &timings[from] {
                Some(t) => (1.0 - alpha) * w + alpha * t.weight_for(w),
                None => w,
            },
            None => w,
        };
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

    /// Each section's progress timing (see [`KeyframeSchedule::timings`]), from the section's
    /// first keyframe where it starts.
    fn section_timings(&self) -> Result<&[Option<inbetween::ProgressTiming>], SimError> {
        if let Some(t) = self.schedule.timings.get() {
            return Ok(t);
        }
        let grid = &self.model().grid;
        let full = self.full_nodal_mass(grid.dx);
        let mut made = Vec::new();
        for i in 0..self.schedule.steps.len() {
            let start = if i == 0 {
                self.schedule.begin
            } else {
                self.schedule.steps[i - 1]
            };
            let (a, _) = self.keyframe_masses(i, start, false)?;
            let (b, _) = self.keyframe_masses(i + 1, start, false)?;
            made.push(inbetween::ProgressTiming::new(
                grid.nodes(),
                &a,
                &b,
                full,
                inbetween::TIMING_SAMPLES,
            ));
        }
        Ok(self.schedule.timings.get_or_init(|| made))
    }

    /// The nodal mass of a node deep inside the body at rest on a grid of spacing `dx`
    /// (simulation units): the particles' mean mass times the particles per cell.
    fn full_nodal_mass(&self, dx: f64) -> f64 {
        let mass = &self.model().mass;
        let mean = mass.iter().sum::<f64>() / mass.len().max(1) as f64;
        let spacing = self.model().grid.dx / self.settings.particles_per_cell as f64;
        mean * (dx / spacing).powi(3)
    }

    /// The reach cost segment `k` adds at its end: the final target's, where the segment ends
    /// at the final target itself (from its arrival on), none before. (Ramped in before the
    /// arrival, as the fourth power of the schedule's weight, the body ran ahead of its easing
    /// curve: sphere -> stanford-bunny's ease error 0.52, fill 0.885; docs/morph.md.)
    pub fn segment_reach(&self, k: usize) -> Option<&ReachLoss> {
        let (from, to, _) = self.segment_blend(k);
        (from == to && to == self.schedule.steps.len())
            .then_some(self.reach.as_ref())
            .flatten()
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

    /// The last segment of segment `k`'s look-ahead window: up to `lookahead` segments on,
    /// within the chain, while the window's control layers line up with each segment's
    /// (every segment but the window's last a whole number of layers); `k` itself when the
    /// look-ahead is off.
    pub fn window_end(&self, k: usize) -> usize {
        let s = &self.settings;
        let mut end = k;
        while end < k + s.lookahead
            && end + 1 < s.segments
            && self.segment_steps[end].is_multiple_of(s.control_stride)
        {
            end += 1;
        }
        end
    }

    /// The ends of segments `k..end` inside a look-ahead window, each against that
    /// segment's own target; segment `k`'s is `first` (the chain has it already, see
    /// [`Prepared::segment_losses`]).
    pub fn window_waypoints(
        &self,
        k: usize,
        end: usize,
        first: &MassLoss,
    ) -> Result<Vec<PathPoint>, SimError> {
        let end_step = |j: usize| self.sim_segment_first(j) + self.sim_segment_steps(j) - 1;
        let mut points = vec![PathPoint {
            step: end_step(k),
            loss: first.clone(),
        }];
        for j in k + 1..end {
            points.push(PathPoint {
                step: end_step(j),
                loss: self.segment_losses(j)?.0.into_owned(),
            });
        }
        Ok(points)
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
        judge.judge(&self.initial.x, &state.x, &j)
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
        motion::MotionMeasures {
            first_frame: from,
            ..motion::measure(
                &speeds[from - 1..to],
                iou,
                &section,
                per_segment,
                arrive + 1 - from,
            )
        }
    }

    pub fn loss_of(&self, state: &State) -> Result<f64, SimError> {
        let mass = self.model().mass_grid(&state.x)?;
        Ok(self.loss.value_and_grad(&mass).0)
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
    /// The controls' continuity, by the body's stiffness: a control is a rate of plastic
    /// flow, and a jump in it leaves the body strained by the jump, storing elastic energy
    /// in proportion to the shear modulus (the flow keeps volume), which the body gives back
    /// as a surge of motion. Weighed by the modulus, a jump costs what it would make a
    /// viewer see (docs/morph.md, "Continuity by stiffness").
    pub smoothing: f64,
}

impl WeightScale {
    /// The scales on a grid of `resolution` cells with `per_cell` particles per cell along
    /// each axis, for a body of shear modulus `mu`.
    pub fn at(resolution: usize, per_cell: usize, mu: f64) -> WeightScale {
        // Never up: on coarser grids the scaled-up weights made more iterations judge worse
        // (24 cells, 2 / 4 / 8 evaluations: fill 0.716, 0.827, 0.760).
        let ratio = (settings::TUNED_RESOLUTION as f64 / resolution as f64).min(1.0);
        // More particles per cell split each cell's mass among more of them the same way.
        let split = (settings::TUNED_PER_CELL as f64 / per_cell as f64).min(1.0);
        let particles = ratio.powi(3) * split.powi(3);
        WeightScale {
            volume: particles,
            arrival: particles,
            smoothing: mu / settings::TUNED_SHEAR_MODULUS,
        }
    }
}

/// The finer loss grid splits each simulation cell this many times per axis: one particle
/// per fine cell at the default two per cell.
pub const FINE_REFINE: usize = 2;

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

/// Particle-and-node steps a second one thread does in an optimizer's evaluation, forward
/// and reverse (measured: 1.58 M on 2 threads over the README's job, 144 evaluations of 60
/// steps over 11,752 particles and 22,308 nodes in 187 s).
pub const STEPS_PER_THREAD_SECOND: f64 = 0.75e6;

/// Runs estimated above this many seconds get a warning with the estimate before any work.
pub const LONG_RUN_SECONDS: f64 = 3600.0;

/// A warning with the run's estimated time when it is above [`LONG_RUN_SECONDS`]: every
/// evaluation of every segment's window, a forward and a reverse pass over its steps, each
/// step over the particles and the grid's nodes.
fn long_run_warning(
    settings: &MorphSettings,
    shot: &settings::Shot,
    substeps: usize,
    (particles, nodes): (usize, usize),
) -> Option<String> {
    let steps: usize = shot.segment_steps.iter().sum();
    let window = settings.lookahead + 1;
    let evaluations = settings.passes * settings.optimizer.iterations.max(1) * window;
    let work = (steps * substeps) as f64 * evaluations as f64 * (particles + nodes) as f64;
    let threads = rayon::current_num_threads() as f64;
    let seconds = work / (STEPS_PER_THREAD_SECOND * threads);
    (seconds > LONG_RUN_SECONDS).then(|| {
        format!(
            "this run is long: about {:.1} hours on {threads} threads ({} frames, {} segments x {} passes x {} iterations of {particles} particles); fewer frames (--frames, --fps) or particles make it shorter, and --resume continues it after an interruption",
            seconds / 3600.0,
            shot.frame_count(),
            shot.segment_steps.len(),
            settings.passes,
            settings.optimizer.iterations
        )
    })
}

/// A warning for each collider (and the ground) that holds source particles at frame 1: the
/// first step pushes them out at once, a jolt no control asked for.
fn overlap_warnings(
    settings: &MorphSettings,
    geometry: &crate::geometry::MorphGeometry,
) -> Result<Vec<String>, MorphError> {
    let to_sim = &geometry.placement.world_to_sim;
    let particles = &geometry.source.positions;
    let share = |inside: usize| 100.0 * inside as f64 / particles.len().max(1) as f64;
    let mut warnings = Vec::new();
    if let Some(ground) = &settings.ground {
        let height = to_sim.apply(&Vector3::new(0.0, ground.height, 0.0)).y;
        let below = particles.iter().filter(|p| p.y < height).count();
        if below > 0 {
            warnings.push(format!(
                "the ground at height {} cuts the body at frame 1: {below} particles ({:.1}%) start below it and are pushed out by the first step; lower the ground or move the source",
                ground.height,
                share(below)
            ));
        }
    }
    for c in &settings.colliders {
        let mesh = crate::geometry::load_mesh(&c.mesh)?;
        let winding = crate::geometry::winding::WindingNumber::new(&to_sim.apply_mesh(&mesh.mesh));
        let inside = {
            use rayon::prelude::*;
            particles.par_iter().filter(|p| winding.at(p) > 0.5).count()
        };
        if inside > 0 {
            warnings.push(format!(
                "collider {} overlaps the body at frame 1: {inside} particles ({:.1}%) start inside it and are pushed out by the first step; move the collider or the source",
                c.mesh.display(),
                share(inside)
            ));
        }
    }
    Ok(warnings)
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
