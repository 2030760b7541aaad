//! The morph's front door: a `Job` (the meshes and the settings), the `Observer` that
//! watches it run (events, frames, cancel), and what comes back (`MorphResult`, the
//! records of iterations, segments and levels, `MorphError`).

use super::{MorphSettings, Prepared, RunProgress, run_prepared};

use crate::engine::mpm::{SimError, State};
use crate::geometry::{LoadedMesh, MeshError};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

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
    /// The optimization could not work: its objective or gradient was not finite, or no
    /// segment's loss moved ([`crate::morph::chain::optimization_failure`]); the message says
    /// what to change. Nothing of the run is kept.
    #[error("{0}")]
    Optimization(String),
    /// The device asked for (`--device gpu`) cannot run the morph: no adapter, or a scene
    /// it does not run; the message says what is missing.
    #[error("{0}")]
    Device(String),
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
    pub(super) fn new(
        prep: &'a Prepared,
        index: usize,
        step: usize,
        state: &'a State,
    ) -> Frame<'a> {
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
/// shape; each reached at its frame in `settings.shot.at`, spread over the shot when empty), and
/// the settings. What the command line runs, as a library call.
pub struct Job {
    pub source: MeshSource,
    pub targets: Vec<MeshSource>,
    pub settings: MorphSettings,
}

impl Job {
    /// Checks the settings (here, where a program hands them in), loads and places the
    /// meshes, fills the source with particles, builds the model.
    pub fn prepare(&self) -> Result<Prepared, MorphError> {
        let settings = self
            .settings
            .clone()
            .checked()
            .map_err(MorphError::Settings)?;
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
            &settings,
            (self.source.mesh(&source_file), &source_name),
            &targets,
        )
    }

    /// Prepares and runs the morph; the observer sees events and frames (world units) and
    /// may cancel it. Returns the prepared morph with its result.
    pub fn run(&self, observer: &mut dyn Observer) -> Result<(Prepared, MorphResult), MorphError> {
        let prep = self.prepare()?;
        let result = run_prepared(&prep, None, observer)?;
        Ok((prep, result))
    }
}

/// One frame in world units, see [`Prepared::world_frame`].
#[derive(Clone, Debug)]
pub struct WorldFrame {
    pub x: Vec<Vector3<f64>>,
    pub v: Vec<Vector3<f64>>,
    pub j: Vec<f64>,
}

impl WorldFrame {
    /// The particles' mean volume ratio (an inverted particle counts as none): what a
    /// surface is put back to, times the body's volume.
    pub fn mean_j(&self) -> f64 {
        self.j.iter().map(|j| j.max(0.0)).sum::<f64>() / self.j.len().max(1) as f64
    }

    /// The particles' rms speed (world units per second): the motion measures' `s(f)`.
    pub fn rms_speed(&self) -> f64 {
        let n = self.v.len().max(1) as f64;
        (self.v.iter().map(|v| v.norm_squared()).sum::<f64>() / n).sqrt()
    }
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

impl SegmentRecord {
    /// The record of segment `segment` of pass `pass`, optimized to `result` in `seconds`.
    pub(crate) fn of(
        pass: usize,
        segment: usize,
        result: &super::segment::SegmentResult,
        seconds: f64,
    ) -> Self {
        let (min_j, max_j) = result.j_range;
        SegmentRecord {
            pass,
            segment,
            initial_loss: result.initial_loss,
            loss: result.loss,
            evaluations: result.evaluations,
            seconds,
            min_j,
            max_j,
            grad_norm_first: result.grad_norms.0,
            grad_norm_last: result.grad_norms.1,
        }
    }
}
