//! The gradient controller: Adam on the control knots, with the horizon split into inner
//! batches of N steps. Each batch is optimized from the state the previous one ended in: a
//! forward RK4 run of the batch with a tape, the exact gradient of its kinetic-energy cost
//! through that run, an Adam step on the batch's own knots, projected onto the bounds. A step
//! that raises the cost is undone and the step size halved (near rest, a full Adam step
//! would only add energy). After the iterations the best evaluated controls of the batch are
//! committed and its end state carried over.

use super::{ControlEvent, ControllerRun, Online, free_knots};
use crate::engine::integrator::{Controlled, Steps};
use crate::engine::mpm::ControlParams;
use crate::engine::mpm::SimError;
use crate::engine::mpm::State;
use crate::optim::Adam;
use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct GradientSettings {
    /// Steps per inner batch (N).
    pub batch_steps: usize,
    /// Extra steps simulated (and costed) after each batch, whose controls are optimized
    /// too but only committed by the next batch: without them the knots near a batch's end
    /// see almost none of their effect and hand the next batch a body they stir up.
    pub lookahead_steps: usize,
    /// Adam iterations per batch.
    pub iterations: usize,
    /// Adam step size, as a fraction of each control's bound (so one setting suits offsets,
    /// speeds and accelerations alike).
    pub learning_rate: f64,
    pub beta1: f64,
    pub beta2: f64,
}

impl Default for GradientSettings {
    fn default() -> Self {
        GradientSettings {
            batch_steps: 50,
            lookahead_steps: 50,
            iterations: 5,
            learning_rate: 0.3,
            beta1: 0.9,
            beta2: 0.999,
        }
    }
}

impl GradientSettings {
    pub fn validate(&self, horizon: usize, interval: usize) -> Result<(), SimError> {
        let bad = |m: String| Err(SimError::InvalidScene(m));
        if self.batch_steps == 0 {
            return bad("gradient batch N must be at least 1 step".into());
        }
        if self.batch_steps > horizon {
            return bad(format!(
                "gradient batch N ({} steps) is larger than the horizon ({horizon} steps)",
                self.batch_steps
            ));
        }
        if !self.lookahead_steps.is_multiple_of(interval) {
            return bad(format!(
                "gradient lookahead ({}) must be a multiple of the control interval ({interval})",
                self.lookahead_steps
            ));
        }
        if !self.batch_steps.is_multiple_of(interval) || !horizon.is_multiple_of(self.batch_steps) {
            return bad(format!(
                "gradient batch N ({}) must be a multiple of the control interval ({interval}) and divide the horizon ({horizon})",
                self.batch_steps
            ));
        }
        if self.iterations == 0 {
            return bad("gradient iterations must be at least 1".into());
        }
        if !(self.learning_rate.is_finite() && self.learning_rate > 0.0) {
            return bad(format!(
                "learning rate must be positive and finite, got {}",
                self.learning_rate
            ));
        }
        for (name, b) in [("beta1", self.beta1), ("beta2", self.beta2)] {
            if !(b.is_finite() && (0.0..1.0).contains(&b)) {
                return bad(format!("Adam {name} must be in [0, 1), got {b}"));
            }
        }
        Ok(())
    }
}

/// Runs the gradient controller over the whole horizon from `init`.
pub fn gradient_control<S: Controlled>(
    sys: &S,
    init: &State,
    settings: &GradientSettings,
    horizon: usize,
    mut on_event: impl FnMut(ControlEvent),
) -> Result<ControllerRun, SimError> {
    let (plan, dt) = (sys.model().controls(), sys.model().dt);
    let (schedule, bounds) = (plan.schedule, plan.bounds());
    settings.validate(horizon, schedule.steps_per_interval)?;
    let mut run = Online::start(plan.zero_params(), init, horizon);
    let n = settings.batch_steps;
    for a in (0..horizon).step_by(n) {
        let len = (n + settings.lookahead_steps).min(horizon - a);
        let knots = free_knots(&schedule, a, a + len);
        let commit_knots = free_knots(&schedule, a, a + n);
        let ne = run.params.len();
        // Adam over this batch's knots: entry (e, knot, axis), stepped by the control's bound.
        let mut adam = Adam::new(ne * knots.len() * 3, settings.beta1, settings.beta2, 1e-12);
        let scale = |i: usize| bounds[i / (3 * knots.len())][i % 3];
        let mut best: Option<(f64, ControlParams, State, Vec<f64>)> = None;
        let mut lr = settings.learning_rate;
        let mut failures = 0;
        for _ in 0..settings.iterations {
            let mut s = run.state.clone();
            let mut tape = S::Tape::default();
            run.simulated_steps += len;
            let mut mid = None;
            let ran = sys.run(
                &mut s,
                &run.params,
                Steps::new(a, len),
                Some(&mut tape),
                &mut |k, st| {
                    if k + 1 == a + n {
                        mid = Some(st.clone());
                    }
                },
            );
            let energy = match ran {
                Ok(e) => e,
                Err(_) if best.is_some() => {
                    // The step left the stable region: go back to the best and halve it.
                    run.params = best.as_ref().unwrap().1.clone();
                    lr *= 0.5;
                    continue;
                }
                Err(e) => return Err(e),
            };
            let cost = dt * energy.iter().sum::<f64>();
            run.evaluated(cost);
            if best.as_ref().is_none_or(|b| cost < b.0) {
                let mid = mid.expect("the run passes the batch's end");
                best = Some((cost, run.params.clone(), mid, energy[..n].to_vec()));
                failures = 0;
            } else {
                // The step made things worse: go back to the best controls, shorten the step;
                // after two failures in a row the batch has converged.
                run.params = best.as_ref().unwrap().1.clone();
                lr *= 0.5;
                failures += 1;
                if failures == 2 {
                    break;
                }
                continue;
            }
            let grad = sys.kinetic_cost_gradient(&tape, &run.params, dt, None);
            // Adam on this batch's knots, then projection onto the bounds.
            let batch = |p: &ControlParams| -> Vec<f64> {
                p.iter()
                    .flat_map(|e| e[knots.clone()].iter().flat_map(|k| k.iter().copied()))
                    .collect()
            };
            let mut flat = batch(&run.params);
            adam.step(&mut flat, &batch(&grad.params), lr, scale);
            let mut values = flat.into_iter();
            for e in run.params.iter_mut() {
                for k in e[knots.clone()].iter_mut() {
                    for c in k.iter_mut() {
                        *c = values.next().expect("one value per entry");
                    }
                }
            }
            plan.project(&mut run.params);
        }
        let (cost, best_params, end, energy) = best.expect("at least one evaluation");
        // Commit the batch's best knots; the lookahead's knots are the next batch's warm
        // start, and knots past the window hold the window's last value.
        debug_assert!(commit_knots.end <= knots.end);
        let params = &mut run.params;
        for e in 0..params.len() {
            for j in knots.clone() {
                params[e][j] = best_params[e][j];
            }
            let next = knots.end.min(params[e].len());
            for j in next..params[e].len() {
                params[e][j] = best_params[e][knots.end - 1];
            }
        }
        run.state = end;
        run.commit("gradient", a, &energy, horizon, cost, &mut on_event);
    }
    Ok(run.finish())
}
