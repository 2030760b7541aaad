//! Per-particle state that evolves over steps, and the same layout for its adjoint.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Particle state advanced by each step: position `x`, velocity `v`, APIC affine velocity `c`
/// and deformation gradient `f`. Masses and rest volumes do not change and live in the
/// [`super::model::Model`]. Both integrators use it: the ODE form (RK4) carries no `c` (it
/// recomputes the velocity gradient at every evaluation), so its states, rates and adjoints
/// leave `c` empty ([`State::ode_zeros`], [`State::ode_part`]), and RK4's stage combinations
/// `S + h k` are plain axpys over the fields there are.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct State {
    pub x: Vec<Vector3<f64>>,
    pub v: Vec<Vector3<f64>>,
    pub c: Vec<Matrix3<f64>>,
    pub f: Vec<Matrix3<f64>>,
}

/// A copy of `v` made by the worker threads, each writing its share in place.
pub fn par_copy<T: Copy + Send + Sync>(v: &[T]) -> Vec<T> {
    let mut out = Vec::with_capacity(v.len());
    out.par_extend(v.par_iter().copied());
    out
}

/// Gradient of a scalar loss with respect to every field of a [`State`].
pub type StateGrad = State;

/// Below this many particles a state's element-wise operations and checks stay on the calling
/// thread (the rope's controllers run many small rollouts at once).
const MIN_LEN: usize = 4096;

impl State {
    /// Particles at `positions`, at rest and undeformed.
    pub fn at_rest(positions: Vec<Vector3<f64>>) -> State {
        let n = positions.len();
        State {
            x: positions,
            v: vec![Vector3::zeros(); n],
            c: vec![Matrix3::zeros(); n],
            f: vec![Matrix3::identity(); n],
        }
    }

    /// A copy made by the worker threads (the tape's copies did not speed up with threads).
    pub fn par_clone(&self) -> State {
        State {
            x: par_copy(&self.x),
            v: par_copy(&self.v),
            c: par_copy(&self.c),
            f: par_copy(&self.f),
        }
    }

    /// All-zero state (the adjoint seed) for `n` particles.
    pub fn zeros(n: usize) -> State {
        State {
            x: vec![Vector3::zeros(); n],
            v: vec![Vector3::zeros(); n],
            c: vec![Matrix3::zeros(); n],
            f: vec![Matrix3::zeros(); n],
        }
    }

    /// The ODE form's state of `n` particles, all zero (a rate or an adjoint seed): no `c`.
    pub fn ode_zeros(n: usize) -> State {
        State {
            x: vec![Vector3::zeros(); n],
            v: vec![Vector3::zeros(); n],
            c: Vec::new(),
            f: vec![Matrix3::zeros(); n],
        }
    }

    /// Particles at `positions`, at rest and undeformed, as the ODE form holds them (no `c`).
    pub fn ode_at_rest(positions: Vec<Vector3<f64>>) -> State {
        let n = positions.len();
        State {
            x: positions,
            v: vec![Vector3::zeros(); n],
            c: Vec::new(),
            f: vec![Matrix3::identity(); n],
        }
    }

    /// The ODE form's part of this state: `x`, `v` and `F`, without `c`.
    pub fn ode_part(&self) -> State {
        State {
            x: self.x.clone(),
            v: self.v.clone(),
            c: Vec::new(),
            f: self.f.clone(),
        }
    }

    /// This state with a zero `c` where it has none (an ODE-form state handed to code that
    /// reads every field).
    pub fn with_affine(mut self) -> State {
        if self.c.is_empty() {
            self.c = vec![Matrix3::zeros(); self.len()];
        }
        self
    }

    /// `self += a * other`, field by field (`c` where both have one).
    pub fn axpy(&mut self, a: f64, other: &State) {
        fn field<T>(s: &mut [T], o: &[T], a: f64)
        where
            T: Copy + Send + Sync + std::ops::AddAssign + std::ops::Mul<f64, Output = T>,
        {
            s.par_iter_mut()
                .with_min_len(MIN_LEN)
                .zip(o)
                .for_each(|(s, o)| *s += *o * a);
        }
        field(&mut self.x, &other.x, a);
        field(&mut self.v, &other.v, a);
        field(&mut self.c, &other.c, a);
        field(&mut self.f, &other.f, a);
    }

    /// `out = self + a * other` into an existing buffer (no allocation once sized).
    pub fn combine_into(&self, a: f64, other: &State, out: &mut State) {
        out.clone_from(self);
        out.axpy(a, other);
    }

    /// Sum of `<self, other>` over all fields (for directional-derivative checks).
    pub fn dot(&self, other: &State) -> f64 {
        let x: f64 = self.x.iter().zip(&other.x).map(|(a, b)| a.dot(b)).sum();
        let v: f64 = self.v.iter().zip(&other.v).map(|(a, b)| a.dot(b)).sum();
        let c: f64 = self.c.iter().zip(&other.c).map(|(a, b)| a.dot(b)).sum();
        let f: f64 = self.f.iter().zip(&other.f).map(|(a, b)| a.dot(b)).sum();
        x + v + c + f
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Bytes a state of `n` particles holds.
    pub const fn bytes_for(n: usize) -> usize {
        n * (2 * size_of::<Vector3<f64>>() + 2 * size_of::<Matrix3<f64>>())
    }

    /// Bytes a particle of the ODE form's state holds: `x`, `v` and `F`.
    pub const ODE_BYTES_PER_PARTICLE: usize =
        2 * size_of::<Vector3<f64>>() + size_of::<Matrix3<f64>>();

    /// Heap bytes this state holds.
    pub fn bytes(&self) -> usize {
        (self.x.len() + self.v.len()) * size_of::<Vector3<f64>>()
            + (self.c.len() + self.f.len()) * size_of::<Matrix3<f64>>()
    }

    /// Index and name of the first particle with a non-finite field, if any.
    pub fn first_non_finite(&self) -> Option<(usize, &'static str)> {
        (0..self.len())
            .into_par_iter()
            .with_min_len(MIN_LEN)
            .find_map_first(|p| {
                if !self.x[p].iter().all(|a| a.is_finite()) {
                    Some((p, "position"))
                } else if !self.v[p].iter().all(|a| a.is_finite()) {
                    Some((p, "velocity"))
                } else if self
                    .c
                    .get(p)
                    .is_some_and(|c| !c.iter().all(|a| a.is_finite()))
                {
                    Some((p, "affine velocity C"))
                } else if !self.f[p].iter().all(|a| a.is_finite()) {
                    Some((p, "deformation gradient F"))
                } else {
                    None
                }
            })
    }

    /// Total linear momentum for per-particle masses `m`.
    pub fn linear_momentum(&self, m: &[f64]) -> Vector3<f64> {
        self.v
            .iter()
            .zip(m)
            .fold(Vector3::zeros(), |acc, (v, &m)| acc + m * v)
    }

    /// Total angular momentum about the origin, including the APIC affine (spin) part
    /// `m * eps : (C D)^T` with `D = 1/inv_d` (Jiang et al. 2015), which transfers conserve.
    pub fn angular_momentum(&self, m: &[f64], inv_d: f64) -> Vector3<f64> {
        let d = 1.0 / inv_d;
        let mut l = Vector3::zeros();
        for (((x, v), c), &mp) in self.x.iter().zip(&self.v).zip(&self.c).zip(m) {
            let b = c * d;
            let spin = Vector3::new(
                b[(2, 1)] - b[(1, 2)],
                b[(0, 2)] - b[(2, 0)],
                b[(1, 0)] - b[(0, 1)],
            );
            l += mp * (x.cross(v) + spin);
        }
        l
    }

    /// Kinetic energy `1/2 sum m |v|^2` (translational part).
    pub fn kinetic_energy(&self, m: &[f64]) -> f64 {
        self.v
            .iter()
            .zip(m)
            .map(|(v, &m)| 0.5 * m * v.norm_squared())
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ODE form's states leave `c` empty: the arithmetic RK4 does on them skips it, the
    /// checks find non-finite values in the fields there are, and `with_affine` hands code
    /// that reads every field a zero `c`.
    #[test]
    fn ode_states_go_without_c() {
        let n = 5;
        let mut s = State::ode_at_rest((0..n).map(|i| Vector3::repeat(i as f64)).collect());
        assert!(s.c.is_empty() && s.len() == n);
        assert_eq!(s.bytes(), n * State::ODE_BYTES_PER_PARTICLE);
        let mut k = State::ode_zeros(n);
        k.v[2] = Vector3::new(1.0, -2.0, 0.5);
        k.f[4] = Matrix3::identity();
        s.axpy(0.5, &k);
        assert_eq!(s.v[2], Vector3::new(0.5, -1.0, 0.25));
        assert_eq!(s.f[4], Matrix3::identity() * 1.5);
        assert!(s.c.is_empty());
        assert_eq!(s.dot(&k), 0.5 * 5.25 + 1.5 * 3.0);
        assert_eq!(s.first_non_finite(), None);
        s.f[3][(1, 2)] = f64::NAN;
        assert_eq!(s.first_non_finite(), Some((3, "deformation gradient F")));
        let full = s.with_affine();
        assert_eq!(full.c, vec![Matrix3::zeros(); n]);
        assert_eq!(full.bytes(), State::bytes_for(n));
        // A full state's part for the ODE form, and back.
        let part = full.ode_part();
        assert!(part.c.is_empty() && part.x == full.x && part.v == full.v);
    }
}
