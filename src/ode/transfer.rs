//! Transfers of the ODE form, forward and reverse side by side.
//!
//! Scatter (P2G): nodes hold `[m, p, f]` (7 numbers): `m_i += w m_p`, `p_i += w m_p v~_p` and
//! `f_i += w (K_p (x_i - x_p) + m_p b_p)`, where `K_p = -V_p D^-1 P(F_p) F_p^T` is the MLS
//! form of the stress force `-V P F^T grad w` and `b_p` a body acceleration. Gather (G2P):
//! `v^g_p = sum w v_i`, `a^g_p = sum w a_i` and the velocity gradient
//! `B_p = D^-1 sum w v_i (x_i - x_p)^T`. The scatter runs under the colouring of
//! [`crate::mpm::grid::Bins`]; its reverse is a gather, and the gather's reverse a scatter.

use crate::mpm::grid::SharedMut;
use crate::mpm::kernel::Stencil;
use nalgebra::{Matrix3, Vector3};

/// Node data of the ODE scatter: mass, momentum, force.
pub type Node = [f64; 7];

#[inline(always)]
fn grad_w<const N: usize>(s: &Stencil<N>, a: usize, b: usize, c: usize) -> Vector3<f64> {
    Vector3::new(
        s.dw[0][a] * s.w[1][b] * s.w[2][c],
        s.w[0][a] * s.dw[1][b] * s.w[2][c],
        s.w[0][a] * s.w[1][b] * s.dw[2][c],
    )
}

/// Particle data the scatter spreads.
pub struct ScatterInputs {
    pub mass: f64,
    /// Velocity handed to the grid (`v_p`, or the prescribed velocity of a clamped particle).
    pub velocity: Vector3<f64>,
    /// `K_p`, the stress force matrix.
    pub stress_force: Matrix3<f64>,
    /// `m_p b_p`, the body force.
    pub body_force: Vector3<f64>,
}

/// Forward scatter of one particle. Caller runs it under the colouring.
#[inline]
pub fn scatter<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    inp: &ScatterInputs,
    nodes: &SharedMut<Node>,
) {
    let mom = inp.mass * inp.velocity;
    s.for_each_node(strides, |i, w, d, _| {
        let f = inp.stress_force * d + inp.body_force;
        // SAFETY: the colouring gives this thread exclusive use of the stencil's nodes.
        let node = unsafe { nodes.get(i) };
        node[0] += w * inp.mass;
        for k in 0..3 {
            node[1 + k] += w * mom[k];
            node[4 + k] += w * f[k];
        }
    });
}

/// Adjoints of [`scatter`]'s particle inputs.
pub struct ScatterGrad {
    pub velocity: Vector3<f64>,
    pub stress_force: Matrix3<f64>,
    pub body_force: Vector3<f64>,
    pub x: Vector3<f64>,
}

/// Reverse of [`scatter`]: gathers node adjoints `[gm, gp, gf]`.
#[inline]
pub fn scatter_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    inp: &ScatterInputs,
    grad_nodes: &[Node],
) -> ScatterGrad {
    let mom = inp.mass * inp.velocity;
    let mut sum_gp = Vector3::zeros();
    let mut sum_gf = Vector3::zeros();
    let mut g_k = Matrix3::zeros();
    let mut g_x = Vector3::zeros();
    s.for_each_node(strides, |i, w, d, (a, b, c)| {
        let g = &grad_nodes[i];
        let gp = Vector3::new(g[1], g[2], g[3]);
        let gf = Vector3::new(g[4], g[5], g[6]);
        let f = inp.stress_force * d + inp.body_force;
        sum_gp += w * gp;
        sum_gf += w * gf;
        g_k += (w * gf) * d.transpose();
        g_x += grad_w(s, a, b, c) * (inp.mass * g[0] + mom.dot(&gp) + f.dot(&gf));
    });
    // d = x_i - x_p moves with the particle (derivative -I).
    g_x -= inp.stress_force.transpose() * sum_gf;
    ScatterGrad {
        velocity: inp.mass * sum_gp,
        stress_force: g_k,
        body_force: sum_gf,
        x: g_x,
    }
}

/// What [`gather`] returns for one particle.
#[derive(Clone, Copy, Debug)]
pub struct Gathered {
    pub velocity: Vector3<f64>,
    pub acceleration: Vector3<f64>,
    /// Velocity gradient `B_p`.
    pub grad_v: Matrix3<f64>,
}

/// Forward gather of grid velocity, acceleration and velocity gradient.
#[inline]
pub fn gather<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &[Vector3<f64>],
    grid_a: &[Vector3<f64>],
    inv_d: f64,
) -> Gathered {
    let mut vel = Vector3::zeros();
    let mut acc = Vector3::zeros();
    let mut b = Matrix3::zeros();
    s.for_each_node(strides, |i, w, d, _| {
        let wv = w * grid_v[i];
        vel += wv;
        acc += w * grid_a[i];
        b += wv * d.transpose();
    });
    Gathered {
        velocity: vel,
        acceleration: acc,
        grad_v: inv_d * b,
    }
}

/// Reverse of [`gather`]: scatters dL/dv_i and dL/da_i (under the colouring) and returns the
/// gather's part of dL/dx_p. `g` holds dL/d(outputs); `out` is the forward result.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn gather_reverse<const N: usize>(
    s: &Stencil<N>,
    strides: &[usize; 3],
    grid_v: &[Vector3<f64>],
    grid_a: &[Vector3<f64>],
    inv_d: f64,
    g: &Gathered,
    out: &Gathered,
    grad_grid_v: &SharedMut<Vector3<f64>>,
    grad_grid_a: &SharedMut<Vector3<f64>>,
) -> Vector3<f64> {
    let gb = inv_d * g.grad_v;
    let mut g_x = Vector3::zeros();
    s.for_each_node(strides, |i, w, d, (a, b, c)| {
        let u = g.velocity + gb * d;
        g_x += grad_w(s, a, b, c) * (grid_v[i].dot(&u) + grid_a[i].dot(&g.acceleration));
        // SAFETY: exclusive stencil access under the colouring.
        unsafe {
            *grad_grid_v.get(i) += w * u;
            *grad_grid_a.get(i) += w * g.acceleration;
        }
    });
    g_x - gb.transpose() * out.velocity
}
