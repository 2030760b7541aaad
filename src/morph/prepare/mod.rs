//! Setting a morph up: `Prepared::from_meshes` places the meshes, fills the source, builds
//! the model with the effects the settings call for (`scene_effects`), the shot's timing
//! and substeps, the keyframe schedule and the losses; and what the chain asks of it
//! (each segment's targets, path, weights).

use super::{
    CheckedSettings, MorphError, MorphSettings, WorldFrame, inbetween, motion, quality, segment,
    settings,
};

mod queries;
mod setup;
pub mod sim;

pub use setup::{
    FINE_REFINE, LONG_RUN_SECONDS, MAX_DRAG_DAMPING, MAX_SUBSTEPS, MORPH_STEP,
    STEPS_PER_THREAD_SECOND, substeps_for,
};

use super::reach::ReachLoss;
use crate::engine::mpm::model::Model;
use crate::engine::mpm::{SimError, State};
use crate::engine::scene::SceneConfig;
use crate::geometry::{LoadedMesh, MorphGeometry};
use crate::loss::{FINE_KERNEL, FineMassLoss, MassLoss};
use nalgebra::Vector3;
use segment::PathPoint;
use sim::Sim;
use std::path::Path;

/// Everything set up for a morph: particles, the model and its integrator, loss.
pub struct Prepared {
    pub settings: MorphSettings,
    /// What the thin parts' rule chose ([`super::sizing`]; `None` when it was off).
    pub sizing: Option<super::sizing::Sizing>,
    pub geometry: MorphGeometry,
    pub engine: Sim,
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
    /// The same morph on a grid half as fine, solved first when `settings.method.levels > 1`
    /// (itself with its own coarser level when more remain).
    pub coarse: Option<Box<Prepared>>,
}

/// A keyframe target's nodal masses: on the simulation grid, and on the fine loss's grid
/// when there is one.
pub type KeyframeMasses = (Vec<f64>, Option<Vec<f64>>);

/// The body's positions at a morph step of its own path (no controls).
pub type PassivePoint = (usize, Vec<Vector3<f64>>);

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
    pub keyframes: Vec<KeyframeMasses>,
    /// Where the body would be on its own, by morph step: the source's positions at the end of
    /// each segment that ends before the first keyframe (and at each frame before it when the
    /// path term is on), from a run without controls. Empty
    /// when nothing moves a body at rest (no gravity, no initial velocity): it stays where it
    /// starts.
    pub passive: Vec<PassivePoint>,
    /// For each section (keyframe `i` to `i + 1`), how far its shape in-between has come at
    /// each weight (simulation grid; made on first use).
    pub timings: std::sync::OnceLock<Vec<Option<inbetween::ProgressTiming>>>,
}

impl Prepared {
    /// The resolution whose source fill comes nearest `settings.body.particles` by the shapes'
    /// volumes ([`MorphGeometry::estimate`]; the fill then refines it).
    pub fn resolution_for_budget(
        settings: &MorphSettings,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<usize, MorphError> {
        const PROBE: usize = 32;
        let budget = settings.body.particles.unwrap_or(0) as f64;
        let at_probe = MorphGeometry::estimate(
            source,
            targets,
            &settings.placement_options(PROBE),
            settings.body.particles_per_cell,
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
        let resolution = match settings.body.particles {
            None => settings.body.resolution,
            Some(_) => Prepared::resolution_for_budget(settings, source, targets)?,
        };
        Ok(MorphGeometry::estimate(
            source,
            targets,
            &settings.placement_options(resolution),
            settings.body.particles_per_cell,
        )?)
    }

    /// Places the source and the targets (meshes a program holds: pass each through
    /// [`crate::geometry::prepare_mesh`], the checks and repairs loading applies, with the name
    /// its messages should use), fills the source with particles, builds the model and the
    /// losses. The targets are reached in turn, each at its frame in [`MorphSettings::at`]
    /// (spread over the shot when empty), the last being the final one. [`super::Job::prepare`] does
    /// the same from files.
    pub fn from_meshes(
        settings: &CheckedSettings,
        source: (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
    ) -> Result<Prepared, MorphError> {
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
        let (settings, mut geometry) = setup::geometry_in_budget(settings, source, targets)?;
        let (settings, shot) = setup::timed(settings, targets.len())?;
        let settings = &settings;
        let overlaps = setup::overlap_warnings(settings, &geometry)?;
        geometry.warnings.extend(overlaps);
        let mut scene = SceneConfig {
            grid: geometry.placement.grid.clone(),
            dt: settings.method.dt.unwrap_or(shot.step),
            kernel: settings.method.kernel,
            material: settings.body.material.clone(),
            effects: setup::scene_effects(settings, &geometry.placement, &shot),
        };
        let substeps = setup::substeps(settings, &scene, &shot)?;
        scene.dt /= substeps as f64;
        let counts = (geometry.source.positions.len(), scene.grid.node_count());
        if let Some(w) = setup::long_run_warning(settings, &shot, substeps, counts) {
            geometry.warnings.push(w);
        }
        let volumes = vec![geometry.source.volume; geometry.source.positions.len()];
        let mut model = scene.model_with(volumes, &crate::geometry::MeshSolids)?;
        model.control_form = settings.method.control;
        let m = &settings.method;
        let engine = Sim::new(model, m.integrator, m.device, m.precision)?;
        if let Sim::Gpu(g) = &engine
            && g.device().software
        {
            geometry.warnings.push(format!(
                "the device {} is a software Vulkan driver on the CPU, not a GPU: expect the CPU engine to be faster",
                g.device().name
            ));
        }
        let (loss, fine_loss, reach) = setup::losses(settings, &geometry)?;
        let mut initial = State::at_rest(geometry.source.positions.clone());
        let v0 =
            geometry.placement.world_to_sim.scale * Vector3::from(settings.body.initial_velocity);
        initial.v.iter_mut().for_each(|v| *v = v0);
        let keyframes =
            setup::keyframe_masses(settings, &geometry, &scene.grid, fine_loss.as_ref())?;
        let steps: Vec<usize> = settings
            .shot
            .at
            .iter()
            .map(|f| (f - 1) * settings.shot.frame_every)
            .collect();
        let begin = (settings.shot.begin - 1) * settings.shot.frame_every;
        let moving = settings.world.has_gravity() || v0 != Vector3::zeros();
        let passive = match moving {
            true => {
                let ends = setup::passive_ends(settings, &shot, steps[0], begin);
                setup::passive_path(&engine, &initial, &ends, substeps)?
            }
            false => Vec::new(),
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
            coarse: setup::coarse_level(settings, source, targets)?,
        })
    }

    /// The model (grid, time step, particles...) whichever integrator runs it.
    pub fn model(&self) -> &Model {
        self.engine.model()
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
    /// viewer see (docs/lab/2026-12-08-method-record.md, "Continuity by stiffness").
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
