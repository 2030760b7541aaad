//! Linear drag on particle momentum, as in the reference morphing code: each step P2G
//! transfers `(1 - dt * coefficient) m v` instead of `m v`.

use super::Effect;

#[derive(Clone, Copy, Debug)]
pub struct Drag {
    pub coefficient: f64,
}

impl Effect for Drag {
    fn name(&self) -> &'static str {
        "drag"
    }

    fn momentum_retention(&self, dt: f64) -> f64 {
        1.0 - dt * self.coefficient
    }
}
