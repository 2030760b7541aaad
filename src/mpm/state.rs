//! Per-particle state that evolves over steps, and the same layout for its adjoint.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Particle state advanced by each step: position `x`, velocity `v`, APIC affine velocity `c`
/// and deformation gradient `f`. Masses and rest volumes do not change and live in the
/// [`super::Euler`].
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

    /// Heap bytes this state holds.
    pub fn bytes(&self) -> usize {
        State::bytes_for(self.len())
    }

    /// Index and name of the first particle with a non-finite field, if any.
    pub fn first_non_finite(&self) -> Option<(usize, &'static str)> {
        use rayon::prelude::*;
        (0..self.len()).into_par_iter().find_map_first(|p| {
            if !self.x[p].iter().all(|a| a.is_finite()) {
                Some((p, "position"))
            } else if !self.v[p].iter().all(|a| a.is_finite()) {
                Some((p, "velocity"))
            } else if !self.c[p].iter().all(|a| a.is_finite()) {
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
