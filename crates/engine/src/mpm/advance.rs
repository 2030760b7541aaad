//! Stage P2: particle update. `F' = (I + dt C') Fe`, `x' = x + dt v'`.

use nalgebra::{Matrix3, Vector3};

/// Forward: returns `(x', F')`.
#[inline]
pub fn advance(
    x: &Vector3<f64>,
    fe: &Matrix3<f64>,
    vel: &Vector3<f64>,
    c: &Matrix3<f64>,
    dt: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    (x + dt * vel, fe + dt * c * fe)
}

/// Adjoints flowing back out of [`advance`].
pub struct AdvanceGrad {
    /// dL/dv' in total: the state's own adjoint plus `dt dL/dx'`.
    pub vel: Vector3<f64>,
    /// dL/dC' in total: the state's own adjoint plus `dt dL/dF' Fe^T`.
    pub c: Matrix3<f64>,
    /// dL/dFe from this stage: `(I + dt C')^T dL/dF'`.
    pub fe: Matrix3<f64>,
}

/// Reverse, given dL/d of the outputs (x', v', C', F'); dL/dx passes through unchanged.
#[inline]
pub fn advance_reverse(
    fe: &Matrix3<f64>,
    c: &Matrix3<f64>,
    dt: f64,
    grad_x: &Vector3<f64>,
    grad_vel: &Vector3<f64>,
    grad_c: &Matrix3<f64>,
    grad_f: &Matrix3<f64>,
) -> AdvanceGrad {
    AdvanceGrad {
        vel: grad_vel + dt * grad_x,
        c: grad_c + dt * grad_f * fe.transpose(),
        fe: grad_f + dt * c.transpose() * grad_f,
    }
}
