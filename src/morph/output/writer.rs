//! The frame writer: takes the chain's frames as they come, measures them, hands them to a
//! thread that drives the sinks, and checkpoints each completed segment.

use super::manifest::FrameStats;
use super::sinks::{FrameRecord, FrameSink, SinkFrame, out_err};
use crate::engine::mpm::State;
use crate::io::outdir::LockId;
use crate::morph::memory::WRITE_QUEUE;
use crate::morph::quality::{Progress, Quality, close_neighbour_share};
use crate::morph::{
    Frame, MorphError, MorphEvent, MorphResult, Observer, Prepared, RunProgress, WorldFrame,
    checkpoint, run_prepared,
};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, SyncSender, channel, sync_channel};

/// The sinks, after the last frame (to finish).
pub(super) type Sinks = Vec<Box<dyn FrameSink + Send>>;

/// What the writer kept of a run's frames (with those a resumed run wrote before).
pub(super) struct WrittenFrames {
    /// Each frame's measurements, in frame order.
    pub stats: Vec<FrameStats>,
    /// The preview's frames: (frame number, world positions).
    pub preview: Vec<(usize, Vec<Vector3<f64>>)>,
    /// The judge's verdicts on the frames [`judged_frames`] names: (frame, target, verdict),
    /// in frame order.
    pub judged: Vec<(usize, usize, Quality)>,
}

/// What the caller hands a run: its stop flag, its look at each frame
/// ([`super::OutputRequest`]) and its events.
pub(super) struct Caller<'a> {
    pub(super) stop: Option<&'a AtomicUsize>,
    pub(super) on_frame: Option<&'a dyn Fn(&Frame)>,
    pub(super) on_event: &'a mut dyn FnMut(&MorphEvent),
}

/// Runs the chain (from `resume` when given) with every frame written into `dir` through
/// `sinks` on a thread of their own; returns the chain's result, what the frames measured, and
/// the sinks to finish.
pub(super) fn run_writing_frames(
    prep: &Prepared,
    (dir, lock): (&Path, LockId),
    run_id: &str,
    resume: Option<RunProgress>,
    sinks: Sinks,
    caller: Caller,
) -> Result<(MorphResult, WrittenFrames, Sinks), MorphError> {
    let n_frames = prep.frame_count();
    let spacing = prep.model().grid.dx / prep.settings.body.particles_per_cell as f64;
    let (work, queue) = sync_channel(WRITE_QUEUE);
    let (answers, done) = channel();
    let mut writer = FolderWriter {
        dir,
        lock,
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
        stop: caller.stop,
        on_frame: caller.on_frame,
        on_event: caller.on_event,
    };
    if let Some(p) = &resume
        && p.pass + 1 == prep.settings.method.passes
    {
        writer.restore_preview(p.frames)?;
        writer.restore_stats(p.frames)?;
    }
    let (result, sinks) = std::thread::scope(|scope| {
        let thread = scope.spawn(move || {
            write_frames(
                sinks,
                (dir, lock),
                (prep.settings.shot.start_frame, n_frames),
                spacing,
                queue,
                answers,
            )
        });
        let result = run_prepared(prep, resume, &mut writer).and_then(|r| {
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
    let mut judged = writer.judged;
    judged.sort_by_key(|(f, t, _)| (*f, *t));
    let frames = WrittenFrames {
        stats: writer.stats,
        preview: writer.preview,
        judged,
    };
    Ok((result, frames, sinks))
}

/// The frame halfway (in time) between the previous keyframe's frame (the frame the shape
/// change begins on for the first) and target `t`'s.
pub(super) fn halfway(prep: &Prepared, t: usize) -> usize {
    let at = &prep.settings.shot.at;
    let before = if t == 0 {
        prep.settings.shot.begin
    } else {
        at[t - 1]
    };
    before + (at[t] - before) / 2
}

/// The frames the judge sees as the run goes (numbered from 1), each with the target it is
/// judged against: a quarter of the sequence apart against the final target, and each
/// target's keyframe and the frame halfway to it against that target.
fn judged_frames(prep: &Prepared) -> Vec<(usize, usize)> {
    let n = prep.frame_count();
    let last = prep.settings.shot.at.len() - 1;
    let mut f: Vec<(usize, usize)> = (1..=4).map(|q| (1 + q * (n - 1) / 4, last)).collect();
    for (t, &a) in prep.settings.shot.at.iter().enumerate() {
        f.extend([(a, t), (halfway(prep, t), t)]);
    }
    f.sort_unstable();
    f.dedup();
    f
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
        rms_speed: frame.world.rms_speed(),
        progress_iou: Vec::new(),
        surface_volume: None,
        surface_volume_error: None,
    }
}

/// Writes frames through its sinks as the chain produces them, checkpoints completed
/// segments, and passes on events and stop requests.
struct FolderWriter<'a> {
    dir: &'a Path,
    /// The staging folder's lock: `dir` is checked to be still this run's before each write.
    lock: LockId,
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
    progress: Vec<Progress>,
    stop: Option<&'a AtomicUsize>,
    /// The caller's look at each frame ([`super::OutputRequest::on_frame`]).
    on_frame: Option<&'a dyn Fn(&Frame)>,
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
/// more (the run stops on the error). Frames are numbered from `start`, `count` in all;
/// `spacing` (simulation units) is for the close-neighbour share.
fn write_frames(
    mut sinks: Sinks,
    (dir, lock): (&Path, LockId),
    (start, count): (usize, usize),
    spacing: f64,
    work: Receiver<FrameWork>,
    done: Sender<FrameDone>,
) -> Sinks {
    let mut failed = false;
    for job in work {
        if failed {
            continue;
        }
        let frame = SinkFrame {
            index: job.index,
            count,
            start,
            time: job.time,
            world: &job.world,
            state: &job.state,
            fill: Default::default(),
        };
        let mut record = FrameRecord::default();
        // Checked here too: a frame queued before the folder was taken is not written into it.
        let result = lock
            .check(dir)
            .map_err(MorphError::Output)
            .and_then(|()| {
                sinks
                    .iter_mut()
                    .try_for_each(|sink| sink.frame(&frame, &mut record))
            })
            .map(|()| {
                let close = close_neighbour_share(&job.state.x, spacing);
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
        if let Some(on_frame) = self.on_frame {
            on_frame(frame);
        }
        // Never a write into a folder another run made at this one's path.
        self.lock.check(self.dir).map_err(MorphError::Output)?;
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
        self.lock.check(self.dir).map_err(MorphError::Output)?;
        let path = self.stats_path();
        checkpoint::write_json(&path, self.run_id, &self.stats)
            .map_err(|e| out_err("checkpoint", &path, e))?;
        checkpoint::save(self.dir, self.run_id, progress, segment)
    }

    fn stop_requested(&self) -> usize {
        self.stop.map_or(0, |s| s.load(Ordering::Relaxed))
    }
}
