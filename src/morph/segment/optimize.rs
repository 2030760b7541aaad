//! A segment's optimizers: Adam with its undone steps and first-step halvings, and a line
//! search along the gradient; both over the flattened controls.

use super::*;

impl<I: Integrator> Segment<'_, I> {
    /// Optimizes the segment from `initial` controls (one per layer). `on_iteration` gets the
    /// loss of every accepted evaluation and returns whether to go on: `Ok(None)` when it
    /// asked to stop.
    pub fn optimize(
        &self,
        initial: Layers,
        settings: &OptimizerSettings,
        mut on_iteration: impl FnMut(usize, f64) -> bool,
    ) -> Result<Option<SegmentResult>, SimError> {
        assert_eq!(initial.len(), self.num_layers());
        match settings.kind {
            Optimizer::Adam => self.adam(initial, settings, &mut on_iteration),
            Optimizer::LineSearch => self.line_search(initial, settings, &mut on_iteration),
        }
    }

    fn adam(
        &self,
        mut layers: Layers,
        s: &OptimizerSettings,
        on_iteration: &mut dyn FnMut(usize, f64) -> bool,
    ) -> Result<Option<SegmentResult>, SimError> {
        const BETA1: f64 = 0.9;
        const BETA2: f64 = 0.999;
        const EPS: f64 = 1e-12;
        let iterations = s.iterations.max(1);
        let free = FreeControls::new(self, &layers);
        let mut params = free.params(&layers);
        let to_layers = |params: &[f64], layers: &mut Layers| free.to_layers(params, layers);
        let to_params = |grad: Layers| free.to_params(grad);
        let mut adam = Adam::new(params.len(), BETA1, BETA2, EPS);
        let mut current = self.rollout(self.start, &layers, 0, &[])?;
        let initial_loss = current.loss;
        let mut evaluations = 1;
        // The best so far, without its chunks (only the current rollout is reversed).
        let mut best: Option<(Layers, Rollout<I::Tape>)> = None;
        let mut norms = GradNorms::default();
        let mut lr = s.learning_rate;
        let mut iteration = 0;
        // Whether a step has been taken, and the free evaluations spent halving the first one
        // (see its check below): those do not count against the iterations.
        let mut moved = false;
        let mut halvings = 0;
        'outer: loop {
            if !on_iteration(iteration, current.loss) {
                return Ok(None);
            }
            let grad = if iteration - halvings + 1 < iterations {
                let g = to_params(self.gradient(&current, &layers, 0)?);
                norms.add(&g);
                Some(g)
            } else {
                None
            };
            // Reversed: its chunks go before the next rollout records its own.
            let done = current.settled();
            let from_loss = done.loss;
            if best.as_ref().is_none_or(|b| done.loss < b.1.loss) {
                best = Some((layers.clone(), done));
            }
            let Some(grad) = grad else { break };
            let saved = (params.clone(), adam.clone());
            loop {
                adam.step(&mut params, &grad, lr, |_| 1.0);
                to_layers(&params, &mut layers);
                evaluations += 1;
                iteration += 1;
                // An undone step: `Some(true)` the first step raised the objective, `Some(false)`
                // the step blew the simulation up.
                let undone = match self.rollout(self.start, &layers, 0, &[]) {
                    Ok(r) if moved || r.loss <= from_loss => {
                        moved = true;
                        current = r;
                        break;
                    }
                    // Adam's first step moves every control by the full step size; where
                    // little motion is asked for (early in a shot) it overshot so far that no
                    // later step came back, and the body froze.
                    Ok(_) => true,
                    Err(e) if blew_up(&e) => false,
                    Err(e) => return Err(e),
                };
                // Undo it and retry with half the step.
                (params, adam) = saved.clone();
                to_layers(&params, &mut layers);
                lr *= 0.5;
                if !on_iteration(iteration, f64::INFINITY) {
                    return Ok(None);
                }
                if iteration - halvings + 1 >= iterations {
                    // Out of iterations: a first step retried is free (at most
                    // MAX_FIRST_STEP_HALVINGS times), so a run of few iterations still takes one.
                    if !undone || halvings == MAX_FIRST_STEP_HALVINGS {
                        break 'outer;
                    }
                    halvings += 1;
                }
            }
        }
        let (layers, rollout) = best.expect("at least one evaluation");
        Ok(Some(SegmentResult {
            layers,
            loss: rollout.loss,
            initial_loss,
            j_range: rollout.j_range(),
            last: rollout.run.into_last(),
            grad_norms: norms.pair(),
            evaluations,
        }))
    }

    fn line_search(
        &self,
        mut layers: Layers,
        s: &OptimizerSettings,
        on_iteration: &mut dyn FnMut(usize, f64) -> bool,
    ) -> Result<Option<SegmentResult>, SimError> {
        // The accepted rollout of the whole segment, with a chunk starting at every layer.
        let mut accepted = self.rollout(self.start, &layers, 0, &[])?;
        let initial_loss = accepted.loss;
        if !on_iteration(0, accepted.loss) {
            return Ok(None);
        }
        let mut evaluations = 1;
        let mut iteration = 1;
        let mut norms = GradNorms::default();
        for layer in 0..layers.len() {
            let mut g0_norm = None;
            for _ in 0..s.iterations {
                let from_step = layer * self.stride;
                let grads = self.gradient(&accepted, &layers, layer)?;
                let g = &grads[0];
                let norm = g.iter().map(|m| m.norm_squared()).sum::<f64>().sqrt();
                norms.push(norm);
                let g0 = *g0_norm.get_or_insert(norm);
                if norm <= s.gd_tol * g0 || norm == 0.0 || !norm.is_finite() {
                    break;
                }
                let start = accepted
                    .run
                    .state_at(self.first_step + from_step)
                    .expect("a chunk starts at every layer")
                    .clone();
                let before = &accepted.after[..from_step];
                let mut alpha = s.learning_rate;
                let mut improved = None;
                for _ in 0..s.line_search_tries.max(1) {
                    let mut trial = layers.clone();
                    for (fc, gp) in trial[layer].iter_mut().zip(g) {
                        *fc -= (alpha / norm) * gp;
                    }
                    evaluations += 1;
                    match self.rollout(&start, &trial, layer, before) {
                        Ok(r) if r.loss < accepted.loss => {
                            improved = Some((trial, r));
                            break;
                        }
                        Ok(_) => alpha *= 0.5,
                        Err(e) if blew_up(&e) => alpha *= 0.5,
                        Err(e) => return Err(e),
                    }
                }
                match improved {
                    Some((trial, r)) => {
                        layers = trial;
                        // Splice the trial's steps after the unchanged prefix: no re-run.
                        accepted.splice(r, from_step);
                        if !on_iteration(iteration, accepted.loss) {
                            return Ok(None);
                        }
                        iteration += 1;
                    }
                    // Line search failed: the accepted rollout is untouched; next layer.
                    None => break,
                }
            }
        }
        Ok(Some(SegmentResult {
            layers,
            loss: accepted.loss,
            initial_loss,
            j_range: accepted.j_range(),
            last: accepted.run.into_last(),
            grad_norms: norms.pair(),
            evaluations,
        }))
    }
}

/// Free halvings of a segment's first Adam step at most, once its iterations are spent and it
/// still raises the objective: the gradient is then no guide, and the segment keeps its
/// initial controls.
const MAX_FIRST_STEP_HALVINGS: usize = 8;

/// The first and the last gradient norm of an optimization.
#[derive(Default)]
struct GradNorms {
    first: Option<f64>,
    last: Option<f64>,
}

impl GradNorms {
    fn add(&mut self, grad: &[f64]) {
        self.push(grad.iter().map(|g| g * g).sum::<f64>().sqrt());
    }

    fn push(&mut self, norm: f64) {
        self.first.get_or_insert(norm);
        self.last = Some(norm);
    }

    fn pair(&self) -> (f64, f64) {
        (
            self.first.unwrap_or(f64::NAN),
            self.last.unwrap_or(f64::NAN),
        )
    }
}

/// The values Adam moves: one control per grid node (interpolated to the particles, added to
/// the initial controls) or one per particle.
struct FreeControls {
    basis: Option<ControlBasis>,
    /// The initial controls, which the grid's are added to.
    base: Layers,
}

impl FreeControls {
    fn new<I: Integrator>(segment: &Segment<'_, I>, layers: &Layers) -> FreeControls {
        let model = segment.sim.model();
        let basis = (segment.resolution == ControlResolution::Grid)
            .then(|| ControlBasis::new(&segment.start.x, &model.grid.origin_vec(), model.grid.dx));
        FreeControls {
            basis,
            base: layers.clone(),
        }
    }

    /// The free values of `layers` (zero on the grid: the initial controls are the base).
    fn params(&self, layers: &Layers) -> Vec<f64> {
        match &self.basis {
            Some(b) => vec![0.0; layers.len() * b.nodes() * 9],
            None => flatten(layers),
        }
    }

    /// The controls the free values `params` give.
    fn to_layers(&self, params: &[f64], layers: &mut Layers) {
        match &self.basis {
            Some(b) => {
                for (l, chunk) in params.chunks_exact(b.nodes() * 9).enumerate() {
                    let theta: Vec<Matrix3<f64>> = chunk
                        .chunks_exact(9)
                        .map(Matrix3::from_column_slice)
                        .collect();
                    layers[l] = b.to_particles(&theta, &self.base[l]);
                }
            }
            None => unflatten(params, layers),
        }
    }

    /// The gradient of the free values from the controls' `grad`.
    fn to_params(&self, grad: Layers) -> Vec<f64> {
        match &self.basis {
            Some(b) => flatten(&grad.iter().map(|g| b.to_nodes(g)).collect::<Vec<_>>()),
            None => flatten(&grad),
        }
    }
}
