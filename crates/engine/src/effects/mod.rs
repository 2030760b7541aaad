//! Effects: the optional physics a scene switches on. A scene pays only for the effects it
//! lists; the step itself knows none of them.
//!
//! Both integrators run the same effects, through one hook pair: at every grid node with mass
//! an effect changes the node's motion (`apply_grid`), with its reverse beside it
//! (`reverse_grid`). For the symplectic-Euler step the motion is the node's velocity for the
//! step, after `v_i = p_i / m_i` (gravity `v += dt g`, colliders and walls project it); for
//! the ODE form (RK4) it is the node's velocity and acceleration (gravity `a += g`, drag
//! `a -= c v`, walls project both). The context says which (`GridForm`). Drag under Euler acts
//! on particle momentum before P2G instead (`m v -> (1 - dt drag) m v`, the reference code's
//! form). Effects run in list order (`mpm::effect::GridEffects`, the one sequencing both
//! integrators call); the reverse runs them backwards, each given what it saw as input. The
//! context carries the step and the time, so an effect may change over time; the tapes record
//! the step.
//!
//! Effects may have differentiable parameters (gravity's vector, a control's forces): the
//! reverse pass accumulates their gradients into a slice of length [`Effect::num_params`].

pub mod collider;
mod drag;
mod gravity;
mod walls;

pub use collider::{Collider, ColliderShape, Solid};
pub use drag::Drag;
pub use gravity::Gravity;
pub use walls::{WallMode, Walls};

/// The interface, filed with the engine that calls it.
pub use crate::mpm::effect::{Effect, GridContext, GridForm, GridRule, NodeMotion};

/// The check every effect's hook pair must pass, in both forms: at grid nodes where it acts
/// (in a wall layer, inside a collider) and where it does not, `reverse_grid` is the
/// derivative of `apply_grid` (central differences in every component of the node's velocity
/// and acceleration), and under the Euler step the acceleration stays zero. A new effect
/// adds its row to the test below.
#[cfg(test)]
mod checks {
    use super::*;
    use crate::mpm::GridSpec;
    use nalgebra::Vector3;
    use rand::{RngExt, SeedableRng};

    /// `<out.v, gv> + <out.a, ga>` of the effect's forward pass at `node` from `m`.
    fn scalar(
        e: &dyn Effect,
        ctx: &GridContext,
        node: usize,
        m: &NodeMotion,
        g: &NodeMotion,
    ) -> f64 {
        let mut out = *m;
        e.apply_grid(ctx, node, &mut out);
        out.v.dot(&g.v) + out.a.dot(&g.a)
    }

    fn hook_pair_matches_fd(e: &dyn Effect, spec: &GridSpec, nodes: &[usize]) {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let mut vec3 = |scale: f64| Vector3::from_fn(|_, _| rng.random_range(-scale..scale));
        let mass = vec![1.0; spec.node_count()];
        for form in [GridForm::Step, GridForm::Rate] {
            if !e.acts_on_grid(form) {
                continue;
            }
            let ctx = GridContext {
                form,
                spec,
                mass: &mass,
                dt: 0.01,
                step: 3,
                time: 0.03,
            };
            for &node in nodes {
                for _ in 0..20 {
                    let a = if form == GridForm::Step {
                        Vector3::zeros()
                    } else {
                        vec3(20.0)
                    };
                    let m = NodeMotion { v: vec3(2.0), a };
                    let g = NodeMotion {
                        v: vec3(1.0),
                        a: vec3(1.0),
                    };
                    if form == GridForm::Step {
                        let mut out = m;
                        e.apply_grid(&ctx, node, &mut out);
                        assert_eq!(out.a, Vector3::zeros(), "{}: a under Euler", e.name());
                    }
                    let mut grad = g;
                    let mut params = vec![0.0; e.num_params()];
                    e.reverse_grid(&ctx, node, &m, &mut grad, &mut params);
                    let h = 1e-7;
                    for k in 0..6 {
                        let along = |s: f64| {
                            let mut p = m;
                            if k < 3 {
                                p.v[k] += s;
                            } else {
                                p.a[k - 3] += s;
                            }
                            p
                        };
                        let fd = (scalar(e, &ctx, node, &along(h), &g)
                            - scalar(e, &ctx, node, &along(-h), &g))
                            / (2.0 * h);
                        let an = if k < 3 { grad.v[k] } else { grad.a[k - 3] };
                        // Under Euler the acceleration is not an input (it is zero).
                        if form == GridForm::Step && k >= 3 {
                            continue;
                        }
                        assert!(
                            (fd - an).abs() < 1e-6 * (1.0 + an.abs()),
                            "{} {form:?} node {node} input {k}: fd {fd} vs {an}",
                            e.name()
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn every_effects_hook_pair_matches_fd_in_both_forms() {
        let spec = GridSpec::centred_cube(8, 1.0);
        let s = spec.strides();
        let at = |i: usize, j: usize, k: usize| i * s[0] + j * s[1] + k * s[2];
        // A corner and a face node in the wall layers, the middle, and a node below the
        // ground's plane.
        let nodes = [at(0, 1, 1), at(4, 4, 8), at(4, 4, 4), at(4, 1, 4)];
        let ground = |friction| {
            Collider::on_grid(
                "ground".into(),
                ColliderShape::HalfSpace {
                    point: spec.origin_vec() + Vector3::new(0.0, 2.5, 0.0),
                    normal: Vector3::new(0.1, 1.0, -0.2),
                },
                friction,
                &spec,
            )
        };
        let effects: Vec<Box<dyn Effect>> = vec![
            Box::new(Drag::always(3.0)),
            Box::new(Drag {
                coefficient: 5.0,
                start: 0.02,
                ramp: 0.03,
            }),
            Box::new(Gravity {
                acceleration: Vector3::new(0.0, -9.8, 1.0),
            }),
            Box::new(Walls {
                mode: WallMode::Slip,
                thickness: 2,
            }),
            Box::new(Walls {
                mode: WallMode::Sticky,
                thickness: 2,
            }),
            Box::new(ground(0.0)),
            Box::new(ground(0.4)),
        ];
        for e in &effects {
            hook_pair_matches_fd(e.as_ref(), &spec, &nodes);
        }
    }
}
