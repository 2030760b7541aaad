//! The ODE state `S = {x, v, F}` and its time derivative, which share one layout (so RK4's
//! stage combinations `S + h k` are plain axpys). The adjoint of a state uses it too.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Below this many particles the element-wise operations stay on the calling thread.
const MIN_LEN: usize = 4096;

/// Particle positions, velocities and deformation gradients (no APIC `C`: in the ODE form the
/// velocity gradient is recomputed from the grid at every evaluation).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OdeState {
    pub x: Vec<Vector3<f64>>,
    pub v: Vec<Vector3<f64>>,
    pub f: Vec<Matrix3<f64>>,
}

impl OdeState {
    /// Bytes per particle: `x`, `v` and `F`.
    pub const BYTES_PER_PARTICLE: usize =
        2 * size_of::<Vector3<f64>>() + size_of::<nalgebra::Matrix3<f64>>();

    /// Heap bytes this state holds.
    pub fn bytes(&self) -> usize {
        self.len() * Self::BYTES_PER_PARTICLE
    }
}

impl From<&crate::mpm::State> for OdeState {
    /// The ODE form's part of a state (the APIC matrix `c` is not part of it).
    fn from(s: &crate::mpm::State) -> OdeState {
        OdeState {
            x: s.x.clone(),
            v: s.v.clone(),
            f: s.f.clone(),
        }
    }
}

impl OdeState {
    /// Particles at `positions`, at rest and undeformed.
    pub fn at_rest(positions: Vec<Vector3<f64>>) -> OdeState {
        let n = positions.len();
        OdeState {
            x: positions,
            v: vec![Vector3::zeros(); n],
            f: vec![Matrix3::identity(); n],
        }
    }

    /// All zeros (a derivative or adjoint seed) for `n` particles.
    pub fn zeros(n: usize) -> OdeState {
        OdeState {
            x: vec![Vector3::zeros(); n],
            v: vec![Vector3::zeros(); n],
            f: vec![Matrix3::zeros(); n],
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// `self += a * other`, field by field.
    pub fn axpy(&mut self, a: f64, other: &OdeState) {
        self.x
            .par_iter_mut()
            .with_min_len(MIN_LEN)
            .zip(&other.x)
            .for_each(|(s, o)| *s += a * o);
        self.v
            .par_iter_mut()
            .with_min_len(MIN_LEN)
            .zip(&other.v)
            .for_each(|(s, o)| *s += a * o);
        self.f
            .par_iter_mut()
            .with_min_len(MIN_LEN)
            .zip(&other.f)
            .for_each(|(s, o)| *s += a * o);
    }

    /// `out = self + a * other` into an existing buffer (no allocation once sized).
    pub fn combine_into(&self, a: f64, other: &OdeState, out: &mut OdeState) {
        out.clone_from(self);
        out.axpy(a, other);
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
                } else if !self.f[p].iter().all(|a| a.is_finite()) {
                    Some((p, "deformation gradient F"))
                } else {
                    None
                }
            })
    }

    /// Sum of `<self, other>` over all fields (for directional-derivative checks).
    pub fn dot(&self, other: &OdeState) -> f64 {
        let x: f64 = self.x.iter().zip(&other.x).map(|(a, b)| a.dot(b)).sum();
        let v: f64 = self.v.iter().zip(&other.v).map(|(a, b)| a.dot(b)).sum();
        let f: f64 = self.f.iter().zip(&other.f).map(|(a, b)| a.dot(b)).sum();
        x + v + f
    }
}
