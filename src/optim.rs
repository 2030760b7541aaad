//! Adam (Kingma & Ba 2015), the one optimizer step shared by the morph's segments and the
//! gradient controller. Parameters are a flat slice of f64; each entry may have its own step
//! scale (the controller scales by each control's bound).

/// Adam's state: first and second moment estimates and the step count.
#[derive(Clone, Debug)]
pub struct Adam {
    pub beta1: f64,
    pub beta2: f64,
    pub epsilon: f64,
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
}

impl Adam {
    /// Fresh moments for `n` parameters.
    pub fn new(n: usize, beta1: f64, beta2: f64, epsilon: f64) -> Adam {
        Adam {
            beta1,
            beta2,
            epsilon,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// One step: updates the moments with `grad` and moves every parameter by
    /// `-(lr * scale(i)) * m^ / (sqrt(v^) + epsilon)`, with bias-corrected moments.
    pub fn step(
        &mut self,
        params: &mut [f64],
        grad: &[f64],
        lr: f64,
        scale: impl Fn(usize) -> f64,
    ) {
        assert_eq!(params.len(), self.m.len());
        assert_eq!(grad.len(), self.m.len());
        self.t += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let (c1, c2) = (1.0 - b1.powi(self.t), 1.0 - b2.powi(self.t));
        for (i, ((p, &g), (m, v))) in params
            .iter_mut()
            .zip(grad)
            .zip(self.m.iter_mut().zip(self.v.iter_mut()))
            .enumerate()
        {
            *m = b1 * *m + (1.0 - b1) * g;
            *v = b2 * *v + (1.0 - b2) * (g * g);
            let step = (*m / c1) / ((*v / c2).sqrt() + self.epsilon);
            *p -= (lr * scale(i)) * step;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam walks a quadratic bowl to its minimum.
    #[test]
    fn adam_minimizes_a_quadratic() {
        let target = [1.0, -2.0, 0.5];
        let mut x = vec![0.0; 3];
        let mut adam = Adam::new(3, 0.9, 0.999, 1e-12);
        for k in 0..2000 {
            let grad: Vec<f64> = x.iter().zip(&target).map(|(x, t)| 2.0 * (x - t)).collect();
            let lr = if k < 1000 { 0.05 } else { 0.005 };
            adam.step(&mut x, &grad, lr, |_| 1.0);
        }
        for (x, t) in x.iter().zip(&target) {
            assert!((x - t).abs() < 1e-2, "{x} vs {t}");
        }
    }

    /// The first step moves each entry by lr * scale (the bias-corrected ratio is 1).
    #[test]
    fn first_step_is_lr_times_scale() {
        let mut x = vec![0.0, 0.0];
        let mut adam = Adam::new(2, 0.9, 0.999, 0.0);
        adam.step(&mut x, &[3.0, -0.5], 0.1, |i| [1.0, 2.0][i]);
        assert!(
            (x[0] + 0.1).abs() < 1e-15 && (x[1] - 0.2).abs() < 1e-15,
            "{x:?}"
        );
    }
}
