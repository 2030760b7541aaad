//! [`MorphSettings::validate`]: every setting checked, in the order a message is wanted
//! (counts before anything is sized by them), each message naming the option.

use super::{MorphSettings, default_arrival, limits};

impl MorphSettings {
    /// Checks every setting; the message names the option. Counts are checked before
    /// anything is sized by them.
    pub fn validate(&self) -> Result<(), String> {
        self.validate_counts()?;
        self.validate_numbers()?;
        self.validate_shot()?;
        self.validate_world()?;
        self.validate_device()
    }

    /// The GPU device runs the Euler step.
    fn validate_device(&self) -> Result<(), String> {
        use crate::engine::integrator::IntegratorKind;
        if self.method.device == crate::gpu::DeviceKind::Gpu
            && self.method.integrator != IntegratorKind::Euler
        {
            return Err(
                "--device gpu runs the Euler integrator; use --set integrator=euler or --device cpu"
                    .into(),
            );
        }
        if self.method.device == crate::gpu::DeviceKind::Cpu
            && self.method.precision != crate::gpu::Precision::F64
        {
            return Err(
                "`precision` f32 is the GPU device's; the CPU engine runs in f64 (use --device gpu)"
                    .into(),
            );
        }
        Ok(())
    }

    /// The counts and sizes (grid, particles, segments, steps, passes...).
    fn validate_counts(&self) -> Result<(), String> {
        range("resolution", self.body.resolution, limits::RESOLUTION)?;
        if let Some(n) = self.body.particles {
            range("particles", n, limits::PARTICLES)?;
        }
        range(
            "particles-per-cell",
            self.body.particles_per_cell,
            limits::PARTICLES_PER_CELL,
        )?;
        if !(self.body.thin_across.is_finite()
            && (0.0..=limits::MAX_THIN_ACROSS).contains(&self.body.thin_across))
        {
            return Err(format!(
                "thin_across must be between 0 (off) and {}, got {}",
                limits::MAX_THIN_ACROSS,
                self.body.thin_across
            ));
        }
        range("segments", self.method.segments, limits::SEGMENTS)?;
        range("steps", self.method.steps_per_segment, limits::STEPS)?;
        range(
            "control-stride",
            self.method.control_stride,
            1..=self.method.steps_per_segment,
        )?;
        range("passes", self.method.passes, limits::PASSES)?;
        range(
            "iterations",
            self.method.optimizer.iterations,
            limits::ITERATIONS,
        )?;
        range("levels", self.method.levels, limits::LEVELS)?;
        range("lookahead", self.method.lookahead, limits::LOOKAHEAD)?;
        if let Some(n) = self.method.refine_iterations {
            range("refine-iterations", n, limits::ITERATIONS)?;
        }
        range("frame-every", self.shot.frame_every, limits::FRAME_EVERY)?;
        range("start-frame", self.shot.start_frame, limits::START_FRAME)?;
        Ok(())
    }

    /// The rates, weights, material constants and time step.
    fn validate_numbers(&self) -> Result<(), String> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!(
                    "{} must be a positive number, got {v}",
                    shown(name)
                ))
            }
        };
        let non_negative = |name: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(format!("{} must be >= 0, got {v}", shown(name)))
            }
        };
        positive("learning-rate", self.method.optimizer.learning_rate)?;
        positive("density", self.body.material.density)?;
        positive("mu", self.body.material.mu)?;
        non_negative("lambda", self.body.material.lambda)?;
        non_negative("arrival-weight", self.method.arrival_weight)?;
        non_negative("volume-weight", self.method.volume_weight)?;
        non_negative("path-weight", self.method.path_weight)?;
        non_negative("waypoint-weight", self.method.waypoint_weight)?;
        non_negative("control-smoothing", self.method.control_smoothing)?;
        non_negative("fine-weight", self.method.fine_weight)?;
        non_negative("reach-weight", self.method.reach_weight)?;
        non_negative("settle-drag", self.method.settle_drag)?;
        if !(self.method.carry_controls.is_finite()
            && (0.0..=1.0).contains(&self.method.carry_controls))
        {
            return Err(format!(
                "`carry_controls` must be in 0..=1, got {}",
                self.method.carry_controls
            ));
        }
        if !(self.method.progress_timing.is_finite()
            && (0.0..=1.0).contains(&self.method.progress_timing))
        {
            return Err(format!(
                "`progress_timing` must be in 0..=1, got {}",
                self.method.progress_timing
            ));
        }
        if !(self.body.jitter.is_finite() && (0.0..=1.0).contains(&self.body.jitter)) {
            return Err(format!(
                "`jitter` must be between 0 and 1, got {}",
                self.body.jitter
            ));
        }
        if let Some(dt) = self.method.dt {
            positive("dt", dt)?;
            if self.shot.fps.is_some() {
                return Err("`dt` and --fps cannot be combined: --fps chooses the step".into());
            }
        }
        if let Some(fps) = self.shot.fps
            && !(fps.is_finite() && fps > 0.0 && fps <= limits::MAX_FPS)
        {
            return Err(format!(
                "--fps must be above 0 and at most {}, got {fps}",
                limits::MAX_FPS
            ));
        }
        Ok(())
    }

    /// The shot: its length, frame rate, keyframes and where the shape change begins.
    fn validate_shot(&self) -> Result<(), String> {
        // The shot's length, counted before any list is sized by it.
        let (step, frame_every) = self.step_and_frame_every();
        if let Some(n) = self.shot.frames {
            range("frames", n, limits::FRAMES)?;
            let segments = ((n - 1) as u128 * frame_every as u128)
                .div_ceil(self.method.steps_per_segment.max(1) as u128);
            if segments > *limits::SEGMENTS.end() as u128 {
                return Err(format!(
                    "--frames {n} makes {segments} segments of {} steps, more than {}; raise `steps` (--set steps=N) or lower the frame spacing",
                    self.method.steps_per_segment,
                    limits::SEGMENTS.end()
                ));
            }
        }
        let interval = self.method.dt.unwrap_or(step) * frame_every as f64;
        if 1.0 / interval > limits::MAX_FPS * (1.0 + 1e-9) {
            return Err(format!(
                "frames {interval:.3e} s apart play at {:.3e} frames per second, more than {}: raise `dt` or `frame_every` (--set)",
                1.0 / interval,
                limits::MAX_FPS
            ));
        }
        let frames = self.timing().frame_count();
        if frames < 2 {
            let total: usize = self.timing().segment_steps.iter().sum();
            return Err(format!(
                "the shot lasts {} steps ({:.3} s) but frames are {frame_every} steps ({interval:.3} s) apart: only the rest shape would be written; lower the frame spacing (--fps, `frame_every`) or lengthen the shot (--frames, --seconds, `segments`)",
                total,
                total as f64 * self.method.dt.unwrap_or(step)
            ));
        }
        for (k, &a) in self.shot.at.iter().enumerate() {
            let first = if k == 0 { 1 } else { self.shot.at[k - 1] + 1 };
            if !(first..=frames).contains(&a) {
                return Err(format!(
                    "--at: keyframe {} at frame {a} must be {}at most the last frame, {frames}",
                    k + 1,
                    if k == 0 {
                        "at least 1 and ".to_string()
                    } else {
                        format!(
                            "after the previous keyframe's frame {} and ",
                            self.shot.at[k - 1]
                        )
                    }
                ));
            }
        }
        // The shape change begins before the first keyframe (the default arrival when none
        // is given), so the easing curve has frames to run over.
        let first_key = self
            .shot
            .at
            .first()
            .copied()
            .unwrap_or_else(|| default_arrival(frames));
        if self.shot.begin < 1 || (self.shot.begin > 1 && self.shot.begin >= first_key) {
            return Err(format!(
                "--begin {} must be at least 1 and before the first keyframe, frame {first_key}",
                self.shot.begin
            ));
        }
        Ok(())
    }

    /// The world's effects and the start velocity.
    fn validate_world(&self) -> Result<(), String> {
        self.world.validate()?;
        if !self.body.initial_velocity.iter().all(|v| v.is_finite()) {
            return Err(format!(
                "initial_velocity must be finite, got {:?}",
                self.body.initial_velocity
            ));
        }
        if self.body.target_fit == crate::geometry::TargetFit::OnGround
            && self.world.ground().is_none()
        {
            return Err("--target-fit on-ground needs a ground plane (a scene's [ground])".into());
        }
        Ok(())
    }
}

/// A setting as a message names it: a method knob by its key (`--set path_weight=...`), an
/// option of `morph --help` by the option.
fn shown(name: &str) -> String {
    let key = name.replace('-', "_");
    let knob = super::knobs::knobs()
        .iter()
        .any(|k| k.key.rsplit('.').next() == Some(key.as_str()))
        || super::knobs::ALIASES.iter().any(|(a, _)| *a == key);
    if knob {
        format!("`{key}`")
    } else {
        format!("--{name}")
    }
}

fn range(name: &str, v: usize, r: std::ops::RangeInclusive<usize>) -> Result<(), String> {
    if r.contains(&v) {
        Ok(())
    } else {
        Err(format!(
            "{} must be between {} and {}, got {v}",
            shown(name),
            r.start(),
            r.end()
        ))
    }
}

/// Settings that passed [`MorphSettings::validate`]: what a morph's set-up takes, so that they
/// are checked once, where they are made (the command line, a scene file, the Python module,
/// a program's own [`MorphSettings`]), and nowhere below.
#[derive(Clone, Debug)]
pub struct CheckedSettings(MorphSettings);

impl std::ops::Deref for CheckedSettings {
    type Target = MorphSettings;
    fn deref(&self) -> &MorphSettings {
        &self.0
    }
}

impl MorphSettings {
    /// These settings, checked ([`MorphSettings::validate`]).
    pub fn checked(self) -> Result<CheckedSettings, String> {
        self.validate()?;
        Ok(CheckedSettings(self))
    }
}

impl CheckedSettings {
    pub fn into_inner(self) -> MorphSettings {
        self.0
    }

    /// Settings the set-up derives from checked ones (the thin parts' particles, the grid a
    /// budget gives, the shot's timing, a coarser level), which hold what the checks ask by
    /// construction; debug builds check them again.
    pub(crate) fn derived(settings: MorphSettings) -> CheckedSettings {
        debug_assert_eq!(settings.validate(), Ok(()));
        CheckedSettings(settings)
    }
}
