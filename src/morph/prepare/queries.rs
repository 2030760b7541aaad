//! What the chain asks of a prepared morph: each segment's steps, blend, weights, targets,
//! path and window, and the judges of its states.

use super::*;

impl Prepared {
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
        let stride = self.settings.method.control_stride;
        self.segment_steps
            .iter()
            .map(|s| s.div_ceil(stride))
            .collect()
    }

    /// Simulation steps between control layers.
    pub fn sim_control_stride(&self) -> usize {
        self.settings.method.control_stride * self.substeps
    }

    /// Simulation steps between exported frames.
    pub fn sim_frame_every(&self) -> usize {
        self.settings.shot.frame_every * self.substeps
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
            self.settings.method.arrival_weight * self.weight_scale().arrival
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
            self.settings.method.control_smoothing * self.weight_scale().smoothing
        }
    }

    /// What the settings' weights are multiplied by on this grid and for this material, so
    /// that they weigh the same at any resolution and stiffness (see [`WeightScale`]).
    pub fn weight_scale(&self) -> WeightScale {
        WeightScale::at(
            self.settings.body.resolution,
            self.settings.body.particles_per_cell,
            self.settings.body.material.mu,
        )
    }

    /// The volume cost's weight on this grid.
    pub fn volume_weight(&self) -> f64 {
        self.settings.method.volume_weight * self.weight_scale().volume
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
            Some(f) => Some(crate::engine::mpm::transfer::mass_grid(
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
        // settings ask (docs/lab/2026-12-08-method-record.md, "Progress timing").
        let alpha = self.settings.method.progress_timing;
        let w = match (alpha > 0.0).then(|| self.section_timings()).transpose()? {
            Some(timings) => match &timings[from] {
                Some(t) => (1.0 - alpha) * w + alpha * t.weight_for(w),
                None => w,
            },
            None => w,
        };
        let (a, a_fine) = self.keyframe_masses(from, step, fine)?;
        let (b, b_fine) = self.keyframe_masses(to, step, fine)?;
        let blend = |grid: &crate::engine::mpm::grid::GridSpec, a: &[f64], b: &[f64]| match self
            .settings
            .method
            .inbetween
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
        let spacing = self.model().grid.dx / self.settings.body.particles_per_cell as f64;
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
        if self.settings.method.path_weight == 0.0 {
            return Ok(Vec::new());
        }
        let first: usize = self.segment_steps[..k].iter().sum();
        let end = first + self.segment_steps[k];
        let every = self.settings.shot.frame_every;
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
        while end < k + s.method.lookahead
            && end + 1 < s.method.segments
            && self.segment_steps[end].is_multiple_of(s.method.control_stride)
        {
            end += 1;
        }
        end
    }

    /// What the look-ahead window `k..=end` aims at beyond segment `k`'s own: segment
    /// `end`'s losses and the waypoints on its way (nothing when the window is `k` alone).
    #[allow(clippy::type_complexity)]
    pub fn window_targets(
        &self,
        k: usize,
        end: usize,
        first: &MassLoss,
    ) -> Result<
        (
            Option<std::borrow::Cow<'_, MassLoss>>,
            Option<std::borrow::Cow<'_, FineMassLoss>>,
            Vec<PathPoint>,
        ),
        SimError,
    > {
        if end == k {
            return Ok((None, None, Vec::new()));
        }
        let (end_loss, fine) = self.segment_losses(end)?;
        Ok((Some(end_loss), fine, self.window_waypoints(k, end, first)?))
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
        self.segment_steps.iter().sum::<usize>() / self.settings.shot.frame_every + 1
    }

    /// The quality judge's verdict on `state` (see [`quality`]).
    pub fn quality(&self, state: &State) -> quality::Quality {
        self.quality_against(state, self.schedule.steps.len() - 1)
    }

    /// The judge's verdict on `state` against target `t` (0-based, in keyframe order; the
    /// last is the final target).
    pub fn quality_against(&self, state: &State, t: usize) -> quality::Quality {
        let spacing = self.model().grid.dx / self.settings.body.particles_per_cell as f64;
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
        let spacing = self.model().grid.dx / self.settings.body.particles_per_cell as f64;
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
        let every = self.settings.shot.frame_every as f64;
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
