//! The device as one more integrator of the engine's `Integrator` trait: whatever is written
//! once against it (the morph's segments, their recomputed reverse, the chain) runs on the
//! device as it is. Boundary controls (knots) are not run here yet.

use crate::euler::GpuEuler;
use crate::tape::GpuTape;
use morph_engine::integrator::{Controls, Integrator, OnStep, SeedAfter, Steps};
use morph_engine::mpm::{Gradients, SimError, State, StateGrad};

impl Integrator for GpuEuler {
    type Tape = GpuTape;

    fn forward_observed(
        &self,
        state: &mut State,
        controls: Controls,
        steps: Steps,
        tape: Option<&mut GpuTape>,
        on_step: Option<&mut OnStep>,
    ) -> Result<(), SimError> {
        if controls.knots.is_some() {
            return Err(SimError::InvalidScene(
                "the GPU step does not run boundary controls yet".into(),
            ));
        }
        let on_step = on_step.map(|f| f as &mut dyn FnMut(usize, &State));
        self.run(state, controls.f, steps.first, steps.count, tape, on_step)
    }

    fn tape_bytes_per_step(&self, particles: usize) -> usize {
        self.state_bytes() * particles
    }

    fn backward_seeded(
        &self,
        tape: &GpuTape,
        controls: Controls,
        grad_last: StateGrad,
        seed_after: &mut SeedAfter,
    ) -> Gradients {
        let seed: &mut dyn FnMut(usize, &State, &mut StateGrad) = seed_after;
        self.backward_with(tape, controls.f, grad_last, Some(seed))
    }
}
