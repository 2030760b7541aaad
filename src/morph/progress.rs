//! How far a run is, as a fraction of its work, from the events it sends: for a farm's
//! progress display (`morph --progress openjd`) or any observer. The work is the optimizer's
//! evaluations; a coarse-to-fine level below the morph's own grid counts an eighth of the one
//! above it (it has an eighth of the particles). A resumed run starts where its events say it
//! is, and the fraction never goes back.

use super::MorphEvent;

/// Follows a run's events; [`ProgressMeter::observe`] returns the fraction done (0 to 1).
#[derive(Clone, Debug, Default)]
pub struct ProgressMeter {
    /// The morph's own level: segments, passes, evaluations per segment.
    segments: usize,
    passes: usize,
    iterations: usize,
    /// The level running now and how many there are (1 and 1 without coarse-to-fine), with
    /// the level's segments and evaluations per segment.
    level: usize,
    levels: usize,
    level_segments: usize,
    level_iterations: usize,
    fraction: f64,
}

impl ProgressMeter {
    pub fn new() -> ProgressMeter {
        ProgressMeter {
            level: 1,
            levels: 1,
            ..ProgressMeter::default()
        }
    }

    /// The fraction of the run done after `event`.
    pub fn observe(&mut self, event: &MorphEvent) -> f64 {
        let done = match *event {
            MorphEvent::Setup {
                segments,
                passes,
                iterations,
                ..
            } => {
                (self.segments, self.passes, self.iterations) = (segments, passes, iterations);
                (self.level_segments, self.level_iterations) = (segments, iterations);
                None
            }
            MorphEvent::Level {
                level,
                levels,
                segments,
                iterations,
                ..
            } => {
                (self.level, self.levels) = (level, levels);
                (self.level_segments, self.level_iterations) = (segments, iterations);
                Some(self.overall(0.0))
            }
            MorphEvent::Iteration {
                pass,
                segment,
                iteration,
                ..
            } => {
                let within = (iteration + 1) as f64 / self.level_iterations.max(1) as f64;
                Some(self.overall(self.level_fraction(pass, segment as f64 + within.min(1.0))))
            }
            MorphEvent::Segment { pass, segment, .. } => {
                Some(self.overall(self.level_fraction(pass, (segment + 1) as f64)))
            }
            MorphEvent::Done { .. } => Some(1.0),
        };
        if let Some(f) = done {
            self.fraction = self.fraction.max(f.clamp(0.0, 1.0));
        }
        self.fraction
    }

    /// The passes and segments of the level running now, as the events announced them (the
    /// resolved shot: `--frames` sets the segment count, and a coarse level has its own).
    pub fn level_plan(&self) -> (usize, usize) {
        let passes = if self.level < self.levels {
            1
        } else {
            self.passes
        };
        (passes, self.level_segments)
    }

    /// How far the current level is, `segments_done` segments into pass `pass` (a coarse
    /// level's passes are not counted: it is a warm start, an eighth of the work or less).
    fn level_fraction(&self, pass: usize, segments_done: f64) -> f64 {
        let segments = self.level_segments.max(1) as f64;
        if self.level < self.levels {
            return segments_done / segments;
        }
        let passes = self.passes.max(1) as f64;
        ((pass as f64 * segments + segments_done) / (passes * segments)).min(1.0)
    }

    /// The run's fraction done when the current level is `level_done` done.
    fn overall(&self, level_done: f64) -> f64 {
        // Level l weighs 8^-(levels - l) of the morph's own level.
        let weight = |l: usize| 0.125f64.powi((self.levels - l) as i32);
        let total: f64 = (1..=self.levels).map(weight).sum();
        let before: f64 = (1..self.level).map(weight).sum();
        (before + weight(self.level) * level_done) / total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup(segments: usize, passes: usize, iterations: usize) -> MorphEvent {
        MorphEvent::Setup {
            particles: 1,
            target_particles: 1,
            grid_cells: [1; 3],
            dx: 1.0,
            dt: 1.0,
            segments,
            passes,
            iterations,
            frames: 2,
            warnings: Vec::new(),
        }
    }

    fn iteration(pass: usize, segment: usize, iteration: usize) -> MorphEvent {
        MorphEvent::Iteration {
            pass,
            segment,
            iteration,
            loss: 1.0,
            seconds: 0.0,
        }
    }

    fn level(level: usize, levels: usize, segments: usize) -> MorphEvent {
        MorphEvent::Level {
            level,
            levels,
            particles: 1,
            grid_cells: [1; 3],
            segments,
            iterations: 4,
        }
    }

    #[test]
    fn one_level_counts_passes_segments_and_evaluations() {
        let mut m = ProgressMeter::new();
        assert_eq!(m.observe(&setup(4, 2, 5)), 0.0);
        // Pass 1, segment 2 (0-based 1), third evaluation: (1 + 3/5) of 8 segments.
        let f = m.observe(&iteration(0, 1, 2));
        assert!((f - 1.6 / 8.0).abs() < 1e-12, "{f}");
        // A segment that converged early counts whole.
        let f = m.observe(&MorphEvent::Segment {
            pass: 0,
            segment: 1,
            initial_loss: 1.0,
            loss: 0.5,
            evaluations: 3,
            seconds: 0.0,
        });
        assert!((f - 2.0 / 8.0).abs() < 1e-12, "{f}");
        // Second pass, last evaluation of the last segment: done but for the end.
        let f = m.observe(&iteration(1, 3, 4));
        assert!((f - 1.0).abs() < 1e-12, "{f}");
        assert_eq!(
            m.observe(&MorphEvent::Done {
                seconds: 1.0,
                loss: 0.0,
                frames: 2
            }),
            1.0
        );
    }

    #[test]
    fn a_resumed_run_starts_where_it_is_and_never_goes_back() {
        let mut m = ProgressMeter::new();
        m.observe(&setup(4, 1, 5));
        // Resumed after two segments: the first event is the third segment's.
        let f = m.observe(&iteration(0, 2, 0));
        assert!((f - 2.2 / 4.0).abs() < 1e-12, "{f}");
        // An evaluation reported again (a retried step) does not move it back.
        assert_eq!(m.observe(&iteration(0, 1, 0)), f);
    }

    #[test]
    fn coarse_levels_weigh_an_eighth_each() {
        let mut m = ProgressMeter::new();
        m.observe(&setup(4, 1, 4));
        // Two levels: the coarse one is 1/9 of the work.
        assert_eq!(m.observe(&level(1, 2, 2)), 0.0);
        assert_eq!(
            m.level_plan(),
            (1, 2),
            "a coarse level's own segments, one pass"
        );
        let f = m.observe(&iteration(0, 1, 3)); // the coarse level's last evaluation
        assert!((f - 1.0 / 9.0).abs() < 1e-12, "{f}");
        let f = m.observe(&level(2, 2, 4));
        assert!((f - 1.0 / 9.0).abs() < 1e-12, "{f}");
        let f = m.observe(&iteration(0, 1, 3)); // half the morph's own level
        assert!((f - (1.0 + 8.0 * 0.5) / 9.0).abs() < 1e-12, "{f}");
    }
}
