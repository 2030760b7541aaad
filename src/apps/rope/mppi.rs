//! The MPPI baseline (model predictive path integral control). At every replanning point it
//! samples K perturbations of the nominal control knots over a planning horizon, rolls each
//! out from the current state (in parallel with rayon), weights them by
//! `exp(-(J_k - J_min) / lambda)`, replaces the nominal by the weighted average, and after
//! `refinements` such updates commits the first `replan` steps and shifts the window.
//! The noise-free nominal is always one of the samples, so an update never discards the
//! current plan's information. Noise is drawn per (window, refinement, sample) from a seeded
//! generator, so runs are identical whatever the thread count.

use super::{ControlEvent, ControllerRun, Online, free_knots};
use crate::engine::integrator::{Controlled, Steps};
use crate::engine::mpm::ControlParams;
use crate::engine::mpm::SimError;
use crate::engine::mpm::State;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct MppiSettings {
    /// Samples per update (K).
    pub samples: usize,
    /// Planning horizon in steps.
    pub horizon_steps: usize,
    /// Steps committed per replanning.
    pub replan_steps: usize,
    /// Updates per replanning point.
    pub refinements: usize,
    /// Temperature, relative to the spread of the sampled costs: weights are
    /// `exp(-(J - J_min) / (lambda (J_mean - J_min)))`, which keeps one setting meaningful
    /// across windows whose costs differ by orders of magnitude.
    pub lambda: f64,
    /// Noise standard deviation as a fraction of each control's bound.
    pub noise: f64,
    pub seed: u64,
}

impl Default for MppiSettings {
    fn default() -> Self {
        MppiSettings {
            samples: 256,
            horizon_steps: 50,
            replan_steps: 10,
            refinements: 1,
            lambda: 0.1,
            noise: 0.6,
            seed: 1,
        }
    }
}

impl MppiSettings {
    pub fn validate(&self, horizon: usize, interval: usize) -> Result<(), SimError> {
        let bad = |m: String| Err(SimError::InvalidScene(m));
        if self.samples < 2 {
            return bad(format!(
                "MPPI needs at least 2 samples, got {}",
                self.samples
            ));
        }
        if self.horizon_steps == 0 {
            return bad("MPPI horizon must be at least 1 step".into());
        }
        if self.replan_steps == 0 || self.replan_steps > self.horizon_steps {
            return bad(format!(
                "MPPI replans every {} steps; it must be 1..={} (its horizon)",
                self.replan_steps, self.horizon_steps
            ));
        }
        if !self.replan_steps.is_multiple_of(interval)
            || !self.horizon_steps.is_multiple_of(interval)
            || !horizon.is_multiple_of(self.replan_steps)
        {
            return bad(format!(
                "MPPI horizon ({}) and replan steps ({}) must be multiples of the control interval ({interval}), and the replan steps divide the run ({horizon})",
                self.horizon_steps, self.replan_steps
            ));
        }
        if self.refinements == 0 {
            return bad("MPPI refinements must be at least 1".into());
        }
        if !(self.lambda.is_finite() && self.lambda > 0.0) {
            return bad(format!(
                "MPPI lambda must be positive and finite, got {}",
                self.lambda
            ));
        }
        if !(self.noise.is_finite() && self.noise > 0.0) {
            return bad(format!(
                "MPPI noise must be positive and finite, got {}",
                self.noise
            ));
        }
        Ok(())
    }
}

/// Runs MPPI over the whole run of `total` steps from `init`.
pub fn mppi_control<S: Controlled>(
    sys: &S,
    init: &State,
    settings: &MppiSettings,
    total: usize,
    mut on_event: impl FnMut(ControlEvent),
) -> Result<ControllerRun, SimError> {
    let (plan, dt) = (sys.model().controls(), sys.model().dt);
    let (schedule, bounds) = (plan.schedule, plan.bounds());
    settings.validate(total, schedule.steps_per_interval)?;
    let mut run = Online::start(plan.zero_params(), init, total);
    for (window, k) in (0..total).step_by(settings.replan_steps).enumerate() {
        let len = settings.horizon_steps.min(total - k);
        let knots = free_knots(&schedule, k, k + len);
        let mut cost = f64::INFINITY;
        for r in 0..settings.refinements {
            let stream = (window * settings.refinements + r) as u64;
            let samples: Vec<ControlParams> = (0..settings.samples)
                .map(|i| {
                    let mut p = run.params.clone();
                    if i > 0 {
                        let mut rng = Pcg64::seed_from_u64(
                            settings.seed ^ (stream << 20) ^ (i as u64).wrapping_mul(0x9e37_79b9),
                        );
                        for (e, knots_e) in p.iter_mut().enumerate() {
                            for j in knots.clone() {
                                for c in 0..3 {
                                    let z: f64 = StandardNormal.sample(&mut rng);
                                    knots_e[j][c] += settings.noise * bounds[e][c] * z;
                                }
                            }
                        }
                        plan.project(&mut p);
                    }
                    p
                })
                .collect();
            let costs: Vec<f64> = samples
                .par_iter()
                .map(|p| {
                    let mut s = run.state.clone();
                    match sys.run(&mut s, p, Steps::new(k, len), None, &mut |_, _| {}) {
                        Ok(e) => dt * e.iter().sum::<f64>(),
                        Err(_) => f64::INFINITY,
                    }
                })
                .collect();
            run.simulated_steps += settings.samples * len;
            let finite: Vec<f64> = costs.iter().copied().filter(|c| c.is_finite()).collect();
            if finite.is_empty() {
                return Err(SimError::InvalidScene(format!(
                    "MPPI: every sampled rollout failed at step {k}; lower the noise"
                )));
            }
            let j_min = finite.iter().copied().fold(f64::INFINITY, f64::min);
            let j_mean = finite.iter().sum::<f64>() / finite.len() as f64;
            let temperature = (settings.lambda * (j_mean - j_min)).max(1e-300);
            let weights: Vec<f64> = costs
                .iter()
                .map(|&c| {
                    if c.is_finite() {
                        (-(c - j_min) / temperature).exp()
                    } else {
                        0.0
                    }
                })
                .collect();
            let total_w: f64 = weights.iter().sum();
            for e in 0..run.params.len() {
                for j in knots.clone() {
                    run.params[e][j] = samples
                        .iter()
                        .zip(&weights)
                        .map(|(p, w)| (w / total_w) * p[e][j])
                        .sum();
                }
            }
            cost = costs[0];
            run.evaluated(j_min);
        }
        // Commit the first steps of the plan and shift the window (new knots hold the plan's
        // last value as a warm start).
        let commit = settings.replan_steps.min(total - k);
        let steps = Steps::new(k, commit);
        let energy = sys.run(&mut run.state, &run.params, steps, None, &mut |_, _| {})?;
        run.simulated_steps += commit;
        for knots_e in run.params.iter_mut() {
            let last = knots_e[knots.end - 1];
            for k in knots_e[knots.end..].iter_mut() {
                *k = last;
            }
        }
        run.commit("mppi", k, &energy, total, cost, &mut on_event);
    }
    Ok(run.finish())
}
