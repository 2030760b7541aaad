//! The morph: a chain of segments, each optimized so the body flows toward the target,
//! refined over several passes (design.md section 4).
//!
//! A pass runs the segments in order, each starting from the full particle state where the
//! previous one ended. Later passes start every segment from the previous pass's controls
//! and re-optimize them from the (now different) state the chain reaches. Frames come from
//! the accepted rollouts of the last pass.

pub mod metrics;
pub mod output;
pub mod segment;
pub mod settings;

use crate::geometry::{Jitter, MeshError, MorphGeometry, PlacementOptions};
use crate::loss::MassLoss;
use crate::mpm::{SimError, Simulator, State};
use crate::scene::{EffectConfig, SceneConfig};
use nalgebra::Matrix3;
use segment::Segment;
use serde::Serialize;
pub use settings::{MorphSettings, Preset};
use std::path::Path;
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
    Done {
        seconds: f64,
        loss: f64,
        frames: usize,
    },
}

/// One optimizer evaluation, for the manifest and the loss plot.
#[derive(Clone, Debug, Serialize)]
pub struct IterationRecord {
    pub pass: usize,
    pub segment: usize,
    pub iteration: usize,
    pub loss: f64,
    /// Wall seconds since the optimization started.
    pub seconds: f64,
}

/// Summary of one optimized segment.
#[derive(Clone, Debug, Serialize)]
pub struct SegmentRecord {
    pub pass: usize,
    pub segment: usize,
    pub initial_loss: f64,
    pub loss: f64,
    pub evaluations: usize,
    pub seconds: f64,
}

/// Everything set up for a morph: particles, simulator, loss.
pub struct Prepared {
    pub settings: MorphSettings,
    pub geometry: MorphGeometry,
    pub sim: Simulator,
    pub loss: MassLoss,
    pub initial: State,
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
}

impl Prepared {
    /// Loads and places both meshes, fills them with particles, builds the simulator and the
    /// loss against the target's nodal masses.
    pub fn new(
        settings: &MorphSettings,
        source: &Path,
        target: &Path,
    ) -> Result<Prepared, MorphError> {
        settings.validate().map_err(MorphError::Settings)?;
        let placement = PlacementOptions {
            resolution: settings.resolution,
            target_fit: settings.target_fit,
            ..Default::default()
        };
        let jitter = (settings.jitter > 0.0).then_some(Jitter {
            amount: settings.jitter,
            seed: settings.seed,
        });
        let geometry = MorphGeometry::prepare(
            source,
            target,
            &placement,
            settings.particles_per_cell,
            jitter,
        )?;
        let grid = geometry.placement.grid.clone();
        let mut scene = SceneConfig {
            grid,
            dt: settings.dt.unwrap_or(1.0 / 120.0),
            kernel: settings.kernel,
            material: settings.material.clone(),
            effects: Vec::new(),
        };
        if settings.drag > 0.0 {
            scene.effects.push(EffectConfig::Drag {
                coefficient: settings.drag,
            });
        }
        // Slip walls three cells deep: a safety net so no kernel stencil can leave the grid.
        scene.effects.push(EffectConfig::Walls {
            mode: crate::effects::WallMode::Slip,
            thickness: 3,
        });
        let volumes = vec![geometry.source.volume; geometry.source.positions.len()];
        if settings.dt.is_none() {
            // Half the elastic stability limit at most.
            let probe = SceneConfig {
                dt: 1e-9,
                ..scene.clone()
            }
            .build(volumes.clone())?;
            let (limit, _) = probe.stable_dt();
            scene.dt = scene.dt.min(0.5 * limit);
        }
        let sim = scene.build(volumes)?;
        let target = geometry.target_masses(settings.kernel, settings.material.density)?;
        let loss = MassLoss::new(settings.loss, target);
        let initial = State::at_rest(geometry.source.positions.clone());
        Ok(Prepared {
            settings: settings.clone(),
            geometry,
            sim,
            loss,
            initial,
        })
    }

    /// Frames the chain exports: the initial state and every `frame_every`-th step.
    pub fn frame_count(&self) -> usize {
        self.settings.total_steps() / self.settings.frame_every + 1
    }

    pub fn loss_of(&self, state: &State) -> Result<f64, SimError> {
        let mass = self.sim.mass_grid(&state.x)?;
        Ok(self.loss.value_and_grad(&mass).0)
    }
}

/// Result of a whole morph.
pub struct MorphResult {
    pub final_state: State,
    /// Controls per segment, per layer, per particle (of the last pass).
    pub controls: Vec<Vec<Vec<Matrix3<f64>>>>,
    pub iterations: Vec<IterationRecord>,
    pub segments: Vec<SegmentRecord>,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub seconds: f64,
}

/// Runs the chain. `on_event` sees progress; `on_frame(index, step, state)` receives every
/// exported frame of the last pass, in order, as soon as its segment is final.
pub fn run(
    prep: &Prepared,
    mut on_event: impl FnMut(&MorphEvent),
    mut on_frame: impl FnMut(usize, usize, &State) -> Result<(), MorphError>,
) -> Result<MorphResult, MorphError> {
    let s = &prep.settings;
    let clock = Instant::now();
    on_event(&MorphEvent::Setup {
        particles: prep.initial.len(),
        target_particles: prep.geometry.target.positions.len(),
        grid_cells: prep.sim.grid.cells,
        dx: prep.sim.grid.dx,
        dt: prep.sim.dt,
        segments: s.segments,
        passes: s.passes,
        iterations: s.optimizer.iterations,
        frames: prep.frame_count(),
        warnings: prep.geometry.warnings.clone(),
    });
    let initial_loss = prep.loss_of(&prep.initial)?;
    let n = prep.initial.len();
    let layers_per_segment = s.steps_per_segment.div_ceil(s.control_stride);
    let mut controls: Vec<Vec<Vec<Matrix3<f64>>>> =
        vec![vec![vec![Matrix3::zeros(); n]; layers_per_segment]; s.segments];
    let mut iterations = Vec::new();
    let mut segments = Vec::new();
    let mut state = prep.initial.clone();
    let mut frame = 0;
    for pass in 0..s.passes {
        let last_pass = pass + 1 == s.passes;
        state = prep.initial.clone();
        if last_pass {
            on_frame(frame, 0, &state)?;
            frame += 1;
        }
        #[allow(clippy::needless_range_loop)] // k also numbers steps, events and records
        for k in 0..s.segments {
            let seg_clock = Instant::now();
            let segment = Segment {
                sim: &prep.sim,
                loss: &prep.loss,
                start: &state,
                first_step: k * s.steps_per_segment,
                steps: s.steps_per_segment,
                stride: s.control_stride,
                arrival_weight: s.arrival_weight,
            };
            let init = std::mem::take(&mut controls[k]);
            let result = segment.optimize(init, &s.optimizer, |iteration, loss| {
                let seconds = clock.elapsed().as_secs_f64();
                iterations.push(IterationRecord {
                    pass,
                    segment: k,
                    iteration,
                    loss,
                    seconds,
                });
                on_event(&MorphEvent::Iteration {
                    pass,
                    segment: k,
                    iteration,
                    loss,
                    seconds,
                });
            })?;
            let record = SegmentRecord {
                pass,
                segment: k,
                initial_loss: result.initial_loss,
                loss: result.loss,
                evaluations: result.evaluations,
                seconds: seg_clock.elapsed().as_secs_f64(),
            };
            on_event(&MorphEvent::Segment {
                pass,
                segment: k,
                initial_loss: record.initial_loss,
                loss: record.loss,
                evaluations: record.evaluations,
                seconds: record.seconds,
            });
            segments.push(record);
            if last_pass {
                // States after local steps 1..=T: the next step's start state, then `last`.
                let tape = &result.tape;
                for local in 1..=s.steps_per_segment {
                    let global = k * s.steps_per_segment + local;
                    if global.is_multiple_of(s.frame_every) {
                        let st = if local < s.steps_per_segment {
                            &tape.steps[local].pre
                        } else {
                            &tape.last
                        };
                        on_frame(frame, global, st)?;
                        frame += 1;
                    }
                }
            }
            controls[k] = result.layers;
            state = result.tape.last;
        }
    }
    let final_loss = prep.loss_of(&state)?;
    let seconds = clock.elapsed().as_secs_f64();
    on_event(&MorphEvent::Done {
        seconds,
        loss: final_loss,
        frames: frame,
    });
    Ok(MorphResult {
        final_state: state,
        controls,
        iterations,
        segments,
        initial_loss,
        final_loss,
        seconds,
    })
}
