//! Static colliders: a ground plane or a closed mesh, as a signed-distance boundary on the
//! grid. Every grid node inside the solid (signed distance <= 0) carries the outward normal
//! `n` of the nearest surface; where a node's velocity points into the solid (`v . n < 0`)
//! its normal part is removed and Coulomb friction slows the tangential part:
//!
//! ```text
//!   v_n = v . n,  v_t = v - v_n n
//!   |v_t| <= -mu v_n :  v' = 0                          (sticks)
//!   otherwise        :  v' = v_t (1 + mu v_n / |v_t|)   (slides, slowed)
//! ```
//!
//! Nodes moving away from the solid are left alone, so a body can lift off. The inside nodes
//! and their normals are computed once, when the collider is built on a grid, so a step
//! costs one pass over those nodes only.
//!
//! The ODE form (RK4) states the same contact as rates. A node is in contact when it moves
//! into the solid or would within one step (`v_n + dt a_n < 0`, the nodes Euler's update
//! projects). There the inward normal velocity and the normal acceleration are removed (as
//! slip walls do), and what pressed the node into the solid, its inward acceleration and its
//! inward speed taken up within a step, `N = max(0, -a_n) + max(0, -v_n) / dt` (Euler's
//! `-v_n` per step), is the normal force per unit mass that Coulomb friction opposes the
//! sliding with:
//!
//! ```text
//!   a_t' = a_t - mu N v_t / sqrt(|v_t|^2 + (mu N dt)^2)
//! ```
//!
//! A sliding node slows at `mu N`, as under Euler. The regularization is one step's worth of
//! friction: below `mu N dt` the node is damped toward rest at a rate of about `1 / dt`, which
//! RK4 integrates stably, where an exact stick would need a whole step's velocity update.
//! It is smooth, so the reverse pass is its exact derivative.

use super::{Effect, GridContext, GridForm, NodeMotion};
use crate::mpm::GridSpec;
use nalgebra::Vector3;
use rayon::prelude::*;

/// No contact slot: the node is outside the solid.
const OUTSIDE: u32 = u32::MAX;

#[derive(Clone, Debug)]
pub struct Collider {
    /// What the collider is, for messages and reports ("ground", "collider 'rock.obj'").
    pub label: String,
    /// Coulomb friction coefficient (0: frictionless slip).
    pub friction: f64,
    /// Per grid node: its index in `normals`, or [`OUTSIDE`].
    slot: Vec<u32>,
    /// `(node, outward unit normal)` of every node inside the solid, in node order.
    normals: Vec<(usize, Vector3<f64>)>,
}

/// What a collider's solid is, in simulation coordinates.
pub enum ColliderShape<'a> {
    /// The half-space below a plane: `(x - point) . normal <= 0` is solid.
    HalfSpace {
        point: Vector3<f64>,
        normal: Vector3<f64>,
    },
    /// Any solid the layer above describes (a closed mesh, by its winding number).
    Solid(&'a dyn Solid),
}

/// A solid a collider is built from, in simulation coordinates: the engine asks which grid
/// nodes lie inside and where the nearest surface point is (a closed mesh implements it in
/// `morph::geometry`; the engine knows nothing of meshes).
pub trait Solid: Sync {
    /// Whether `q` lies inside the solid.
    fn contains(&self, q: &Vector3<f64>) -> bool;
    /// The point of the solid's surface nearest to `q`.
    fn nearest_surface_point(&self, q: &Vector3<f64>) -> Vector3<f64>;
}

impl Collider {
    /// The collider's boundary on `grid`: which nodes lie inside, and the outward normal of
    /// the nearest surface at each.
    pub fn on_grid(
        label: String,
        shape: ColliderShape,
        friction: f64,
        grid: &GridSpec,
    ) -> Collider {
        let n = grid.nodes();
        let origin = grid.origin_vec();
        let position = |node: usize| {
            let s = grid.strides();
            let idx = [node / s[0], (node / s[1]) % n[1], node % n[2]];
            origin + grid.dx * Vector3::new(idx[0] as f64, idx[1] as f64, idx[2] as f64)
        };
        let count = grid.node_count();
        let normals: Vec<(usize, Vector3<f64>)> = match shape {
            ColliderShape::HalfSpace { point, normal } => {
                let normal = normal.normalize();
                (0..count)
                    .filter(|&i| (position(i) - point).dot(&normal) <= 0.0)
                    .map(|i| (i, normal))
                    .collect()
            }
            ColliderShape::Solid(solid) => {
                let inside: Vec<usize> = (0..count)
                    .into_par_iter()
                    .filter(|&i| solid.contains(&position(i)))
                    .collect();
                inside
                    .into_par_iter()
                    .map(|i| {
                        let q = position(i);
                        let nearest = solid.nearest_surface_point(&q);
                        let out = nearest - q;
                        // A node on the surface itself: the normal of the triangle there.
                        let normal = if out.norm() > 1e-12 * grid.dx {
                            out.normalize()
                        } else {
                            Vector3::y()
                        };
                        (i, normal)
                    })
                    .collect()
            }
        };
        let mut slot = vec![OUTSIDE; count];
        for (k, (node, _)) in normals.iter().enumerate() {
            slot[*node] = k as u32;
        }
        Collider {
            label,
            friction,
            slot,
            normals,
        }
    }

    /// Grid nodes inside the solid.
    pub fn inside_nodes(&self) -> usize {
        self.normals.len()
    }

    /// The projected velocity (see the module doc).
    #[inline]
    fn project(&self, n: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
        let vn = v.dot(n);
        if vn >= 0.0 {
            return *v;
        }
        let vt = v - vn * n;
        let speed = vt.norm();
        if speed <= -self.friction * vn {
            Vector3::zeros()
        } else {
            vt * (1.0 + self.friction * vn / speed)
        }
    }

    /// Reverse of [`Collider::project`]: dL/dv from dL/dv' `g`, at the input velocity `v`.
    #[inline]
    fn project_reverse(
        &self,
        n: &Vector3<f64>,
        v: &Vector3<f64>,
        g: &Vector3<f64>,
    ) -> Vector3<f64> {
        let vn = v.dot(n);
        if vn >= 0.0 {
            return *g;
        }
        let vt = v - vn * n;
        let speed = vt.norm();
        if speed <= -self.friction * vn {
            return Vector3::zeros();
        }
        // v' = s v_t with s = 1 + mu v_n / |v_t|:
        //   dv'/dv = s (I - n n^T) + v_t (ds/dv)^T,  ds/dv = mu (n / |v_t| - v_n v_t / |v_t|^3).
        let s = 1.0 + self.friction * vn / speed;
        let g_t = g - g.dot(n) * n;
        let ds = self.friction * (n / speed - vn * vt / (speed * speed * speed));
        s * g_t + vt.dot(g) * ds
    }
}

impl Effect for Collider {
    fn name(&self) -> &'static str {
        "collider"
    }

    fn acts_on_grid(&self, _: GridForm) -> bool {
        true
    }

    fn apply_grid(&self, ctx: &GridContext, node: usize, m: &mut NodeMotion) {
        let Some(n) = self.normal_at(node) else {
            return;
        };
        match ctx.form {
            GridForm::Step => m.v = self.project(&n, &m.v),
            GridForm::Rate => self.contact_rates(&n, ctx.dt, &mut m.v, &mut m.a),
        }
    }

    fn reverse_grid(
        &self,
        ctx: &GridContext,
        node: usize,
        input: &NodeMotion,
        grad: &mut NodeMotion,
        _: &mut [f64],
    ) {
        let Some(n) = self.normal_at(node) else {
            return;
        };
        match ctx.form {
            GridForm::Step => grad.v = self.project_reverse(&n, &input.v, &grad.v),
            GridForm::Rate => self.contact_rates_reverse(&n, ctx.dt, input, grad),
        }
    }
}

impl Collider {
    /// The outward normal at `node`, if it lies inside the solid.
    #[inline]
    fn normal_at(&self, node: usize) -> Option<Vector3<f64>> {
        let k = self.slot[node];
        (k != OUTSIDE).then(|| self.normals[k as usize].1)
    }

    /// The rate form's contact at a node inside the solid with outward normal `n` (see the
    /// module doc).
    fn contact_rates(&self, n: &Vector3<f64>, dt: f64, v: &mut Vector3<f64>, a: &mut Vector3<f64>) {
        let n = *n;
        let (vn, an) = (v.dot(&n), a.dot(&n));
        // In contact: moving into the solid, or pressed into it within one step (the node
        // Euler's update would project).
        if vn >= 0.0 && vn + dt * an >= 0.0 {
            return;
        }
        let vt = *v - vn * n;
        if vn < 0.0 {
            *v = vt;
        }
        if vn < 0.0 || an < 0.0 {
            *a -= an * n;
        }
        let pressed = contact_force(vn, an, dt);
        if self.friction > 0.0 && pressed > 0.0 {
            let limit = self.friction * pressed;
            let d = (vt.norm_squared() + (limit * dt).powi(2)).sqrt();
            *a -= (limit / d) * vt;
        }
    }

    /// Reverse of [`Collider::contact_rates`]: `grad` from dL/d(outputs) to dL/d(inputs) at the
    /// motion `input` the forward pass received.
    fn contact_rates_reverse(
        &self,
        n: &Vector3<f64>,
        dt: f64,
        input: &NodeMotion,
        grad: &mut NodeMotion,
    ) {
        let n = *n;
        let (v_in, a_in) = (&input.v, &input.a);
        let (vn, an) = (v_in.dot(&n), a_in.dot(&n));
        if vn >= 0.0 && vn + dt * an >= 0.0 {
            return;
        }
        let project = |g: Vector3<f64>| g - g.dot(&n) * n;
        let (gv, ga) = (grad.v, grad.a);
        let mut g_v = if vn < 0.0 { project(gv) } else { gv };
        let mut g_a = if vn < 0.0 || an < 0.0 {
            project(ga)
        } else {
            ga
        };
        let pressed = contact_force(vn, an, dt);
        if self.friction > 0.0 && pressed > 0.0 {
            // a' -= limit vt / d, limit = mu N, d = sqrt(|vt|^2 + (limit dt)^2), vt = P v_in.
            let mu = self.friction;
            let vt = v_in - vn * n;
            let limit = mu * pressed;
            let e = limit * dt;
            let d = (vt.norm_squared() + e * e).sqrt();
            let vt_ga = vt.dot(&ga);
            g_v -= project(limit * (ga / d - vt * (vt_ga / (d * d * d))));
            // d(-limit vt / d)/dN . ga, with dlimit/dN = mu and dd/dN = e mu dt / d.
            let g_n = -mu * vt_ga / d + limit * vt_ga * e * mu * dt / (d * d * d);
            if vn < 0.0 {
                g_v -= (g_n / dt) * n;
            }
            if an < 0.0 {
                g_a -= g_n * n;
            }
        }
        grad.v = g_v;
        grad.a = g_a;
    }
}

/// The normal force per unit mass a contact node feels in the rate form: what presses it into
/// the solid, its acceleration inward and its inward speed taken up within one step (what
/// Euler's projection of `v + dt a` removes).
fn contact_force(vn: f64, an: f64, dt: f64) -> f64 {
    (-an).max(0.0) + (-vn).max(0.0) / dt
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reverse pass against central differences of the projection, in the sticking,
    /// sliding and separating regimes.
    #[test]
    fn projection_reverse_matches_finite_differences() {
        let c = Collider {
            label: "test".into(),
            friction: 0.4,
            slot: vec![],
            normals: vec![],
        };
        let n = Vector3::new(0.2, 1.0, -0.1).normalize();
        let g = Vector3::new(0.3, -0.7, 1.1);
        for v in [
            Vector3::new(1.0, -0.5, 0.3),  // slides
            Vector3::new(0.05, -1.0, 0.0), // sticks
            Vector3::new(0.4, 0.6, -0.2),  // separates
        ] {
            let analytic = c.project_reverse(&n, &v, &g);
            let h = 1e-6;
            for k in 0..3 {
                let (mut p, mut m) = (v, v);
                p[k] += h;
                m[k] -= h;
                let fd = (c.project(&n, &p).dot(&g) - c.project(&n, &m).dot(&g)) / (2.0 * h);
                assert!(
                    (fd - analytic[k]).abs() < 1e-7,
                    "v {v:?} axis {k}: fd {fd} vs {}",
                    analytic[k]
                );
            }
        }
    }

    /// The rate form's reverse (RK4) against central differences, with friction, in the
    /// sliding, nearly sticking and lifting-off regimes, and pressed or not.
    #[test]
    fn rate_reverse_matches_finite_differences() {
        let n = Vector3::new(0.2, 1.0, -0.1).normalize();
        let c = Collider {
            label: "test".into(),
            friction: 0.4,
            slot: vec![0],
            normals: vec![(0, n)],
        };
        let spec = GridSpec::centred_cube(4, 1.0);
        let mass = [1.0];
        let ctx = GridContext {
            form: GridForm::Rate,
            spec: &spec,
            mass: &mass,
            dt: 0.01,
            step: 0,
            time: 0.0,
        };
        let (gv, ga) = (Vector3::new(0.3, -0.7, 1.1), Vector3::new(-0.4, 0.2, 0.9));
        let out = |v: &Vector3<f64>, a: &Vector3<f64>| {
            let mut m = NodeMotion { v: *v, a: *a };
            c.apply_grid(&ctx, 0, &mut m);
            m.v.dot(&gv) + m.a.dot(&ga)
        };
        for (v, a) in [
            (Vector3::new(1.0, -0.5, 0.3), Vector3::new(0.2, -9.0, 0.1)), // slides, pressed
            (Vector3::new(0.01, -0.5, 0.0), Vector3::new(0.0, -9.0, 0.3)), // nearly sticks
            (Vector3::new(1.0, -0.5, 0.3), Vector3::new(0.2, 4.0, 0.1)),  // not pressed
            (Vector3::new(0.4, 0.6, -0.2), Vector3::new(0.2, -9.0, 0.1)), // lifts off
            (Vector3::new(0.1, 0.02, 0.3), Vector3::new(0.1, -9.0, 0.2)), // pressed in within a step
        ] {
            let mut grad = NodeMotion { v: gv, a: ga };
            c.reverse_grid(&ctx, 0, &NodeMotion { v, a }, &mut grad, &mut []);
            let (g_v, g_a) = (grad.v, grad.a);
            let h = 1e-6;
            for k in 0..3 {
                let e = Vector3::ith(k, h);
                let fd_v = (out(&(v + e), &a) - out(&(v - e), &a)) / (2.0 * h);
                let fd_a = (out(&v, &(a + e)) - out(&v, &(a - e))) / (2.0 * h);
                assert!(
                    (fd_v - g_v[k]).abs() < 1e-6,
                    "v {v:?} a {a:?} dv{k}: fd {fd_v} vs {}",
                    g_v[k]
                );
                assert!(
                    (fd_a - g_a[k]).abs() < 1e-6,
                    "v {v:?} a {a:?} da{k}: fd {fd_a} vs {}",
                    g_a[k]
                );
            }
        }
    }
}
