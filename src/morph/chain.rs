//! Running a morph: the coarse-to-fine levels (`run`), the passes over the chain of
//! segments (`chain`), where a chain stands between segments (`RunProgress`, what a
//! checkpoint holds), and the warnings a run's gradients call for.

use super::{
    Frame, IterationRecord, LevelRecord, MorphError, MorphEvent, MorphResult, MorphSettings,
    Observer, Prepared, SegmentRecord, levels, segment,
};

use crate::engine::integrator::Integrator;
use crate::engine::mpm::State;
use crate::loss::{FineMassLoss, MassLoss};
use nalgebra::{Matrix3, Vector3};
use segment::{Layers, OptimizerSettings, PathPoint, Segment};
use std::time::Instant;

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
    /// Segments after the last completed one whose controls its look-ahead window left
    /// (where their optimization starts; 0 without a look-ahead).
    pub ahead: usize,
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
            level: s.method.levels,
            levels,
            particles: self.initial.len(),
            grid_cells: self.model().grid.cells,
            segments: s.method.segments,
            iterations: self.level_iterations(),
        }
    }

    /// Evaluations per segment on this level.
    pub fn level_iterations(&self) -> usize {
        let s = &self.settings;
        match s.method.refine_iterations {
            Some(n) if s.method.levels > 1 => n,
            _ => s.method.optimizer.iterations,
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
    let (result, controls) = crate::morph::prepare::sim::with_sim!(&coarse.engine, sim => {
        chain(coarse, sim, progress, clock, &mut quiet, below.as_ref(), true)
    })?;
    records.push(LevelRecord {
        level: coarse.settings.method.levels,
        resolution: coarse.settings.body.resolution,
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
    let spacing = to_here.scale / coarse.settings.body.particles_per_cell as f64;
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
            controls: vec![Vec::new(); prep.settings.method.segments],
            iterations: Vec::new(),
            segments: Vec::new(),
            frames: 0,
            elapsed_s: 0.0,
            ahead: 0,
        }
    }
}

/// Runs the chain, from the start or from `resume` (a checkpoint of an earlier run with the
/// same inputs and settings, which then continues bit for bit). The observer sees progress,
/// receives every exported frame of the last pass in order as soon as its segment is final,
/// and every completed segment. ([`crate::run`] prepares a [`super::Job`] and calls it.)
pub fn run_prepared(
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
        segments: s.method.segments,
        passes: s.method.passes,
        iterations: s.method.optimizer.iterations,
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
    if progress.segments_done == s.method.segments && progress.pass + 1 < s.method.passes {
        progress.pass += 1;
        progress.segments_done = 0;
    }
    // Coarse-to-fine: the levels below are solved again on a resume (deterministic, and an
    // eighth of the cost each) while some segment of the first pass has yet to start.
    let mut levels = Vec::new();
    let warm = if progress.pass == 0 && progress.segments_done < s.method.segments {
        warm_start(prep, s.method.levels, observer, &mut levels)?
    } else {
        None
    };
    if s.method.levels > 1 {
        observer.event(&prep.level_event(s.method.levels));
    }
    let (mut result, _) = crate::morph::prepare::sim::with_sim!(&prep.engine, sim => {
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
        ..s.method.optimizer.clone()
    };
    let run = ChainRun {
        prep,
        sim,
        optimizer,
        clock,
        offset_s: progress.elapsed_s,
        warm,
        keep_controls,
    };
    let (first_pass, first_segment) = (progress.pass, progress.segments_done);
    for pass in first_pass..s.method.passes {
        let last_pass = pass + 1 == s.method.passes;
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
        for k in from..s.method.segments {
            run.segment(k, last_pass, &mut progress, observer)?;
        }
    }
    let final_loss = prep.loss_of(&progress.state)?;
    let seconds = run.seconds();
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

/// What every segment of one level's chain shares.
struct ChainRun<'a, I: Integrator> {
    prep: &'a Prepared,
    sim: &'a I,
    optimizer: OptimizerSettings,
    clock: Instant,
    /// Seconds spent before this run (a resumed run's).
    offset_s: f64,
    warm: Option<&'a WarmStart>,
    keep_controls: bool,
}

impl<I: Integrator> ChainRun<'_, I> {
    /// Seconds since the run began, the interrupted run's included.
    fn seconds(&self) -> f64 {
        self.offset_s + self.clock.elapsed().as_secs_f64()
    }

    /// Segment `k` of pass `progress.pass`: optimized (with its look-ahead window), recorded,
    /// replayed for its frames on the last pass, and kept in `progress`.
    fn segment(
        &self,
        k: usize,
        last_pass: bool,
        progress: &mut RunProgress,
        observer: &mut dyn Observer,
    ) -> Result<(), MorphError> {
        let (prep, pass) = (self.prep, progress.pass);
        let seg_clock = Instant::now();
        let (loss, fine_loss) = prep.segment_losses(k)?;
        // A segment before the shape change begins runs without controls: evaluated once,
        // not optimized, with no window reaching past it.
        let before_begin = prep.segment_before_begin(k);
        // The scheduled path of segment k, then of the rest of its look-ahead window.
        let end = if before_begin { k } else { prep.window_end(k) };
        let mut path = prep.segment_path(k)?;
        let own_path = path.len();
        for j in k + 1..=end {
            path.extend(prep.segment_path(j)?);
        }
        // The last control layer before segment k, which its first continues.
        let anchor = k
            .checked_sub(1)
            .and_then(|j| progress.controls[j].last())
            .cloned();
        let start = (&progress.state, anchor.as_deref());
        let segment = self.segment_of(k, (&loss, fine_loss.as_deref()), start, &path[..own_path]);
        // What is optimized: segment k, or its look-ahead window k..=end, which ends at
        // segment end's target and passes through each earlier segment's on its way.
        let (window_loss, window_fine, waypoints) = prep.window_targets(k, end, &loss)?;
        let window = window_loss.as_deref().map(|loss| Segment {
            loss,
            fine_loss: window_fine.as_deref(),
            reach: prep.segment_reach(end),
            steps: (k..=end).map(|j| prep.sim_segment_steps(j)).sum(),
            arrival_weight: prep.segment_arrival_weight(end),
            path: &path,
            waypoints: &waypoints,
            ..segment
        });
        let init = self.initial_layers(progress, k, end, before_begin);
        let optimized = window.as_ref().unwrap_or(&segment);
        let settings = &OptimizerSettings {
            iterations: if before_begin {
                1
            } else {
                self.optimizer.iterations
            },
            ..self.optimizer.clone()
        };
        let result = self.optimize_observed(
            optimized,
            init,
            settings,
            (pass, k),
            &mut progress.iterations,
            observer,
        )?;
        let seconds = seg_clock.elapsed().as_secs_f64();
        let record = self.recorded(SegmentRecord::of(pass, k, &result, seconds), observer)?;
        progress.segments.push(record);
        // A window keeps segment k's layers; the rest start the next window's optimization
        // (and are in the checkpoint, so a resume continues bit for bit).
        let mut layers = result.layers;
        let mut rest = layers.split_off(segment.num_layers()).into_iter();
        for j in k + 1..=end {
            progress.controls[j] = rest.by_ref().take(prep.segment_layers()[j]).collect();
        }
        progress.ahead = end - k;
        // The kept controls once more: to write the frames (the optimization keeps no tape of
        // every step: memory stays within its budget), and to find where segment k ends when
        // a window was optimized.
        let last = match last_pass || window.is_some() {
            true => {
                let last = self.replay_frames(
                    &segment,
                    &layers,
                    last_pass,
                    &mut progress.frames,
                    observer,
                )?;
                debug_assert!(
                    window.is_some() || last == result.last,
                    "a replay reproduces the rollout"
                );
                last
            }
            false => result.last,
        };
        progress.controls[k] = layers;
        progress.state = last;
        progress.segments_done = k + 1;
        progress.elapsed_s = self.seconds();
        observer.segment_done(progress, k)?;
        // Segment k's last layer anchors segment k+1's first; the one before is done with.
        if last_pass && !self.keep_controls && k > 0 {
            progress.controls[k - 1] = Vec::new();
        }
        Ok(())
    }

    /// Segment `k` alone (what is kept, replayed and written): toward `losses`, from `start`
    /// (the state, and the control layer its first continues) along `path`.
    fn segment_of<'b>(
        &'b self,
        k: usize,
        (loss, fine_loss): (&'b MassLoss, Option<&'b FineMassLoss>),
        (start, anchor): (&'b State, Option<&'b [Matrix3<f64>]>),
        path: &'b [PathPoint],
    ) -> Segment<'b, I> {
        let (prep, s) = (self.prep, &self.prep.settings);
        Segment {
            sim: self.sim,
            loss,
            fine_loss,
            reach: prep.segment_reach(k),
            start,
            first_step: prep.sim_segment_first(k),
            steps: prep.sim_segment_steps(k),
            stride: prep.sim_control_stride(),
            arrival_weight: prep.segment_arrival_weight(k),
            volume_weight: prep.volume_weight(),
            path,
            path_weight: s.method.path_weight,
            waypoints: &[],
            waypoint_weight: s.method.waypoint_weight,
            smoothing: prep.segment_smoothing(k),
            anchor,
            resolution: s.method.control_resolution,
            tape_budget: prep.tape_budget,
        }
    }

    /// `record` reported to `observer`; refused when its figures are not finite.
    fn recorded(
        &self,
        record: SegmentRecord,
        observer: &mut dyn Observer,
    ) -> Result<SegmentRecord, MorphError> {
        observer.event(&MorphEvent::Segment {
            pass: record.pass,
            segment: record.segment,
            initial_loss: record.initial_loss,
            loss: record.loss,
            evaluations: record.evaluations,
            seconds: record.seconds,
        });
        match non_finite(&self.prep.settings, &record) {
            Some(why) => Err(MorphError::Optimization(why)),
            None => Ok(record),
        }
    }

    /// Optimizes `optimized` from `init`, each accepted evaluation recorded in `progress` and
    /// reported to `observer`, which may stop it (then [`MorphError::Interrupted`]).
    fn optimize_observed(
        &self,
        optimized: &Segment<'_, I>,
        init: Layers,
        settings: &OptimizerSettings,
        (pass, segment): (usize, usize),
        iterations: &mut Vec<IterationRecord>,
        observer: &mut dyn Observer,
    ) -> Result<segment::SegmentResult, MorphError> {
        let mut stop = observer.stop_requested();
        let result = optimized.optimize(init, settings, |iteration, loss| {
            let at = self.seconds();
            iterations.push(IterationRecord {
                pass,
                segment,
                iteration,
                loss,
                seconds: at,
            });
            observer.event(&MorphEvent::Iteration {
                pass,
                segment,
                iteration,
                loss,
                seconds: at,
            });
            stop = observer.stop_requested();
            stop == 0
        })?;
        result.filter(|_| stop == 0).ok_or(MorphError::Interrupted {
            signal: stop,
            kept: false,
        })
    }

    /// The segment run once more with its kept `layers`: its frames handed to `observer` on
    /// the last pass (counted in `frames`). Returns the state it ends at.
    fn replay_frames(
        &self,
        segment: &Segment<'_, I>,
        layers: &[Vec<Matrix3<f64>>],
        last_pass: bool,
        frames: &mut usize,
        observer: &mut dyn Observer,
    ) -> Result<State, MorphError> {
        let prep = self.prep;
        let mut frame_err = Ok(());
        let last = segment.replay(layers, &mut |global, state| {
            if last_pass && frame_err.is_ok() && (global + 1).is_multiple_of(prep.sim_frame_every())
            {
                frame_err = observer.frame(&Frame::new(prep, *frames, global + 1, state));
                *frames += 1;
            }
        })?;
        frame_err?;
        Ok(last)
    }

    /// The controls the optimization of segments `k..=end` starts from: what an earlier pass
    /// (or the coarser level, prolonged) found; zero before the shape change begins and where
    /// nothing was found, or `carry_controls` times the last layer before (continuing the
    /// flow) for a window's segments after k that were never optimized.
    fn initial_layers(
        &self,
        progress: &RunProgress,
        k: usize,
        end: usize,
        before_begin: bool,
    ) -> Layers {
        let (prep, s) = (self.prep, &self.prep.settings);
        let zeros =
            |j: usize| vec![vec![Matrix3::zeros(); prep.initial.len()]; prep.segment_layers()[j]];
        let start_of = |j: usize| match (&progress.controls[j], self.warm) {
            _ if before_begin => zeros(j),
            (l, None) if l.is_empty() => zeros(j),
            (l, Some(w)) if l.is_empty() => w.prolongation.apply(&w.controls[j]),
            (l, _) => l.clone(),
        };
        let mut init: Layers = Vec::new();
        for j in k..=end {
            let fresh = progress.controls[j].is_empty() && self.warm.is_none();
            let mut layers = start_of(j);
            let carried = init.last().filter(|_| {
                fresh && s.method.carry_controls > 0.0 && prep.segment_smoothing(j) > 0.0
            });
            if let Some(last) = carried {
                let layer: Vec<Matrix3<f64>> =
                    last.iter().map(|c| c * s.method.carry_controls).collect();
                layers.iter_mut().for_each(|l| l.clone_from(&layer));
            }
            init.extend(layers);
        }
        init
    }
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
            "no optimizer step improved segment(s) {} (its steps were too large, or a stiff material rang at every control layer: try a smaller `learning_rate` (--set learning_rate=...))",
            stalled.join(", ")
        ));
    }
    out
}

/// Why a run's optimization could not work, in one line that says what to change, or `None`
/// when it could: a segment whose objective or gradient was not finite ([`non_finite`]), or
/// a run where no segment's loss moved at all (every step undone, or steps too small to
/// change it), so the body did not go toward its target. `iterations` are the run's
/// evaluations (an undone step's loss is infinite). `began_there`: the source already had its
/// target's shape ([`ARRIVED_IOU`]), and a body that did not move is then no failure.
pub fn optimization_failure(
    settings: &MorphSettings,
    segments: &[SegmentRecord],
    iterations: &[IterationRecord],
    began_there: bool,
) -> Option<String> {
    if let Some(why) = segments.iter().find_map(|r| non_finite(settings, r)) {
        return Some(why);
    }
    if began_there {
        return None;
    }
    let outsized = settings.outsized_weights();
    let lower = lower_weights(&outsized);
    let optimized: Vec<&SegmentRecord> = segments.iter().filter(|r| r.evaluations > 1).collect();
    if optimized.is_empty() || optimized.iter().any(|r| moved(r)) {
        return None;
    }
    // Nothing moved. Undone steps raised the objective or blew the simulation up (steps too
    // large); accepted ones that left the loss where it was were too small to matter.
    let steps = iterations.iter().filter(|i| i.iteration > 0);
    let undone = steps.clone().filter(|i| !i.loss.is_finite()).count();
    let lr = settings.method.optimizer.learning_rate;
    let advice = match (2 * undone >= steps.count(), outsized.is_empty()) {
        (true, true) => format!(
            "most steps raised the objective or blew the simulation up: try a smaller `learning_rate` (now {lr:e}; --set learning_rate=...)"
        ),
        (true, false) => format!(
            "most steps raised the objective or blew the simulation up: {lower}, or try a smaller `learning_rate` (now {lr:e}; --set learning_rate=...)"
        ),
        (false, true) => format!(
            "its steps changed almost nothing: the learning rate {lr:e} is too small for these controls; try a larger `learning_rate` (--set learning_rate=...)"
        ),
        (false, false) => format!(
            "its steps changed almost nothing: {lower} (it drowns the mass loss), or try a larger `learning_rate` (now {lr:e}; --set learning_rate=...)"
        ),
    };
    Some(format!(
        "the optimization did not move the body: no segment's loss went down by {}% in {} evaluations ({undone} steps undone); {advice}",
        100.0 * MOVED_SHARE,
        optimized.iter().map(|r| r.evaluations).sum::<usize>()
    ))
}

/// How a run's optimization went, for the manifest and the summary: every evaluation, the
/// steps undone (they raised the objective or blew the simulation up), and the segments whose
/// loss went down by [`MOVED_SHARE`] or more.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct OptimizationReport {
    pub evaluations: usize,
    pub undone_steps: usize,
    pub segments: usize,
    pub segments_moved: usize,
}

impl OptimizationReport {
    pub fn of(segments: &[SegmentRecord], iterations: &[IterationRecord]) -> OptimizationReport {
        OptimizationReport {
            evaluations: iterations.len(),
            undone_steps: iterations.iter().filter(|i| !i.loss.is_finite()).count(),
            segments: segments.len(),
            segments_moved: segments.iter().filter(|r| moved(r)).count(),
        }
    }
}

/// The judge's IoU with the target at which a source already is its target's shape (a body
/// that begins there and does not move is not a failed optimization).
pub const ARRIVED_IOU: f64 = 0.9;

/// The least share of its loss a segment's optimization removes to have moved the body (a
/// healthy morph's early segments remove 30-70%).
pub const MOVED_SHARE: f64 = 0.01;

/// What to lower: the weights set far above their defaults, or the weights in general.
fn lower_weights(outsized: &[String]) -> String {
    if outsized.is_empty() {
        "lower the objective's weights".to_string()
    } else {
        format!("lower {}", outsized.join(", "))
    }
}

/// Whether segment `r`'s optimization moved the body: its loss went down by [`MOVED_SHARE`].
fn moved(r: &SegmentRecord) -> bool {
    r.loss < (1.0 - MOVED_SHARE) * r.initial_loss
}

/// Why segment `r` could not be optimized, when its objective or its gradient was not finite
/// (a weight that overflows 64-bit floats: no control can move); checked as each segment
/// ends, so such a run stops at once.
pub fn non_finite(settings: &MorphSettings, r: &SegmentRecord) -> Option<String> {
    let lower = lower_weights(&settings.outsized_weights());
    let at = format!("pass {} segment {}", r.pass + 1, r.segment + 1);
    if !r.initial_loss.is_finite() {
        return Some(format!(
            "the objective is not finite ({at} starts at loss {}): {lower}",
            r.initial_loss
        ));
    }
    // No gradient is recorded (NaN) for a segment of one evaluation.
    let took_gradient = settings.method.optimizer.iterations > 1 && r.evaluations > 1;
    (took_gradient && !r.grad_norm_first.is_finite()).then(|| {
        format!(
            "the objective's gradient is not finite ({at}, loss {:.3e}), so no control could move: {lower}",
            r.initial_loss
        )
    })
}

impl RunProgress {
    /// A checkpoint must fit the run it continues (the identity hash already says the inputs
    /// and settings are the same; this guards against a damaged checkpoint).
    fn check(&self, prep: &Prepared) -> Result<(), MorphError> {
        let (s, particles) = (&prep.settings, prep.initial.len());
        let layers = prep.segment_layers();
        let fits = self.pass < s.method.passes
            && self.segments_done <= s.method.segments
            && self.state.len() == particles
            && self.controls.len() == s.method.segments
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
