//! Finite-difference checks of the whole reverse pass (f64, central differences) through
//! 12 steps of a deforming body, for both kernels and both losses: dL/dFc at several steps,
//! dL/dx0, dL/dv0, dL/dF0, dL/dC0, and effect parameters. The control acts by the default
//! plastic factor unless a test says otherwise; the reference's additive form has its own.

use crate::common;

use common::*;
use morph::engine::Engine;
use morph::engine::effects::{GridContext, GridForm, NodeMotion, WallMode};
use morph::engine::integrator::{Integrator, IntegratorKind};
use morph::engine::mpm::{ControlForm, KernelKind, State, Tape};
use morph::engine::scene::EffectConfig;
use morph::loss::{FINE_KERNEL, FineMassLoss, MassLoss, MassLossKind};
use nalgebra::{Matrix3, Vector3};

/// (name, <gradient, direction> for one field, perturb that field along the direction).
type FieldCheck = (
    &'static str,
    fn(&State, &State) -> f64,
    fn(&mut State, &State, f64),
);

const STEPS: usize = 12;
/// Control layers every this many steps.
const STRIDE: usize = 4;
const TOL: f64 = 1e-6;

/// Directional derivative by the fourth-order central difference
/// `(8 (f(h) - f(-h)) - (f(2h) - f(-2h))) / 12h`. The loss sums thousands of nodes, so its
/// roundoff divided by a tiny h would swamp the comparison; a larger h (1e-4) with the
/// O(h^2) term cancelled keeps both truncation and roundoff far below 1e-6.
fn fd(f: impl Fn(f64) -> f64) -> f64 {
    fd_step(f, H)
}

fn fd_step(f: impl Fn(f64) -> f64, h: f64) -> f64 {
    (8.0 * (f(h) - f(-h)) - (f(2.0 * h) - f(-2.0 * h))) / (12.0 * h)
}

const H: f64 = 1e-4;

/// Relative error of an analytic directional derivative against the finite difference.
fn rel_err(analytic: f64, fd: f64) -> f64 {
    (analytic - fd).abs() / analytic.abs().max(fd.abs()).max(1e-300)
}

fn check_case(kernel: KernelKind, kind: MassLossKind, effects: Vec<EffectConfig>) {
    check_case_with(kernel, kind, effects, STEPS, H, |_| {});
}

fn check_case_with(
    kernel: KernelKind,
    kind: MassLossKind,
    effects: Vec<EffectConfig>,
    steps: usize,
    h: f64,
    setup: impl Fn(&mut State),
) {
    check_scene(small_scene(kernel, effects), kind, steps, h, setup);
}

fn check_scene(
    scene: morph::engine::scene::SceneConfig,
    kind: MassLossKind,
    steps: usize,
    h: f64,
    setup: impl Fn(&mut State),
) {
    check_scene_on(scene, IntegratorKind::Euler, kind, steps, h, setup);
}

/// [`check_scene`] with the integrator `integrator`.
fn check_scene_on(
    scene: morph::engine::scene::SceneConfig,
    integrator: IntegratorKind,
    kind: MassLossKind,
    steps: usize,
    h: f64,
    setup: impl Fn(&mut State),
) {
    check_scene_form(
        scene,
        integrator,
        ControlForm::default(),
        kind,
        steps,
        h,
        setup,
    );
}

/// [`check_scene_on`] along one random direction per quantity instead of two (for the long
/// lists of rows that each add one effect to what the other tests check).
fn check_scene_once(
    scene: morph::engine::scene::SceneConfig,
    integrator: IntegratorKind,
    kind: MassLossKind,
    steps: usize,
    h: f64,
    setup: impl Fn(&mut State),
) {
    let (engine, init) = ball_engine_with(&scene, 3.2, integrator, ControlForm::default());
    morph::engine::with_integrator!(&engine, sim => check_rollout(sim, scene.kernel, init, kind, steps, h, 1, setup));
}

/// [`check_scene_on`] with the control acting by `form`.
fn check_scene_form(
    scene: morph::engine::scene::SceneConfig,
    integrator: IntegratorKind,
    form: ControlForm,
    kind: MassLossKind,
    steps: usize,
    h: f64,
    setup: impl Fn(&mut State),
) {
    let (engine, init) = ball_engine_with(&scene, 3.2, integrator, form);
    morph::engine::with_integrator!(&engine, sim => check_rollout(sim, scene.kernel, init, kind, steps, h, 2, setup));
}

/// The reverse pass of `steps` steps against central differences, along `trials` random
/// directions for each control layer and each part of the initial state.
#[allow(clippy::too_many_arguments)]
fn check_rollout<I: Integrator>(
    sim: &I,
    kernel: KernelKind,
    mut init: State,
    kind: MassLossKind,
    steps: usize,
    h: f64,
    trials: usize,
    setup: impl Fn(&mut State),
) {
    let fd = |f: &dyn Fn(f64) -> f64| fd_step(f, h);
    let model = sim.model();
    let mut rng = Lcg(42 + kernel as u64 * 7 + kind as u64);
    deform(&mut init, &mut rng);
    setup(&mut init);
    let n = init.len();
    let ctrl = controls(n, steps, STRIDE, 0.05, &mut rng);
    let loss = shifted_target(model, &init, Vector3::new(1.3, -0.7, 0.4), kind);

    let mut tape = I::Tape::default();
    let (l0, last) = rollout_loss(sim, &init, &ctrl, steps, &loss, Some(&mut tape));
    assert!(l0 > 0.0 && l0.is_finite());
    // The body must really deform: F changes noticeably over the rollout.
    let max_df = (0..n)
        .map(|p| (last.f[p] - init.f[p]).norm())
        .fold(0.0, f64::max);
    assert!(max_df > 0.05, "body barely deforms: max |dF| = {max_df}");
    let grads = sim.backward(&tape, &shared(&ctrl), loss_seed(model, &last, &loss));

    let label = format!("{kernel:?}/{kind:?}");
    let eval = |init: &State, ctrl: &[Option<Vec<Matrix3<f64>>>]| {
        rollout_loss(sim, init, ctrl, steps, &loss, None).0
    };

    for trial in 0..trials {
        // dL/dFc at each control layer (steps 0, 4, 8).
        for s in (0..steps).step_by(STRIDE) {
            let g = grads.controls[s].as_ref().expect("control gradient");
            let gmax = g.iter().map(|m| m.amax()).fold(0.0, f64::max);
            let dir: Vec<Matrix3<f64>> = g.iter().map(|m| m / gmax + 0.5 * rng.mat3()).collect();
            let an: f64 = g.iter().zip(&dir).map(|(a, b)| a.dot(b)).sum();
            let fd = fd(&|eps| {
                let mut c = ctrl.clone();
                for (fc, d) in c[s].as_mut().unwrap().iter_mut().zip(&dir) {
                    *fc += eps * d;
                }
                eval(&init, &c)
            });
            let e = rel_err(an, fd);
            assert!(
                e < TOL,
                "{label} dL/dFc step {s} trial {trial}: analytic {an:e} fd {fd:e} rel {e:e}"
            );
        }
        // Initial state: x, v, F, C.
        // Direction: the normalised gradient plus a random part. Along the gradient the
        // derivative stands far above the finite difference's roundoff floor; the random part
        // still probes the components orthogonal to it.
        let dir = {
            let g = &grads.initial;
            let mx = |v: &[Vector3<f64>]| v.iter().map(|a| a.amax()).fold(1e-300, f64::max);
            let mm = |v: &[Matrix3<f64>]| v.iter().map(|a| a.amax()).fold(1e-300, f64::max);
            let (sx, sv, sc, sf) = (mx(&g.x), mx(&g.v), mm(&g.c), mm(&g.f));
            let mut d = State::zeros(n);
            for p in 0..n {
                d.x[p] = g.x[p] / sx + 0.5 * rng.vec3();
                d.v[p] = g.v[p] / sv + 0.5 * rng.vec3();
                d.c[p] = g.c[p] / sc + 0.5 * rng.mat3();
                d.f[p] = g.f[p] / sf + 0.5 * rng.mat3();
            }
            d
        };
        let fields: [FieldCheck; 4] = [
            (
                "x0",
                |g, d| g.x.iter().zip(&d.x).map(|(a, b)| a.dot(b)).sum(),
                |s, d, e| s.x.iter_mut().zip(&d.x).for_each(|(a, b)| *a += e * b),
            ),
            (
                "v0",
                |g, d| g.v.iter().zip(&d.v).map(|(a, b)| a.dot(b)).sum(),
                |s, d, e| s.v.iter_mut().zip(&d.v).for_each(|(a, b)| *a += e * b),
            ),
            (
                "F0",
                |g, d| g.f.iter().zip(&d.f).map(|(a, b)| a.dot(b)).sum(),
                |s, d, e| s.f.iter_mut().zip(&d.f).for_each(|(a, b)| *a += e * b),
            ),
            (
                "C0",
                |g, d| g.c.iter().zip(&d.c).map(|(a, b)| a.dot(b)).sum(),
                |s, d, e| s.c.iter_mut().zip(&d.c).for_each(|(a, b)| *a += e * b),
            ),
        ];
        for (name, dot, perturb) in fields {
            let an = dot(&grads.initial, &dir);
            let fd = fd(&|eps| {
                let mut s = init.clone();
                perturb(&mut s, &dir, eps);
                eval(&s, &ctrl)
            });
            let e = rel_err(an, fd);
            assert!(
                e < TOL,
                "{label} dL/d{name} trial {trial}: analytic {an:e} fd {fd:e} rel {e:e}"
            );
        }
    }

    // Single components: the largest entry of dL/dx0 (one particle moved: the default step).
    let fd = |f: &dyn Fn(f64) -> f64| fd_step(f, H);
    let (p_max, _) = grads
        .initial
        .x
        .iter()
        .enumerate()
        .fold(
            (0, 0.0),
            |acc, (p, g)| if g.norm() > acc.1 { (p, g.norm()) } else { acc },
        );
    for a in 0..3 {
        let fd = fd(&|eps| {
            let mut s = init.clone();
            s.x[p_max][a] += eps;
            eval(&s, &ctrl)
        });
        let an = grads.initial.x[p_max][a];
        assert!(
            rel_err(an, fd) < TOL || (an - fd).abs() < 1e-9 * l0,
            "{label} dL/dx0[{p_max}][{a}]: {an:e} vs {fd:e}"
        );
    }
}

#[test]
fn reverse_pass_matches_fd_quadratic_log() {
    check_case(
        KernelKind::Quadratic,
        MassLossKind::Log,
        vec![EffectConfig::drag(0.5)],
    );
}

#[test]
fn reverse_pass_matches_fd_quadratic_l2() {
    check_case(
        KernelKind::Quadratic,
        MassLossKind::L2,
        vec![EffectConfig::drag(0.5)],
    );
}

#[test]
fn reverse_pass_matches_fd_cubic_log() {
    check_case(
        KernelKind::Cubic,
        MassLossKind::Log,
        vec![EffectConfig::drag(0.5)],
    );
}

#[test]
fn reverse_pass_matches_fd_cubic_l2() {
    check_case(
        KernelKind::Cubic,
        MassLossKind::L2,
        vec![EffectConfig::drag(0.5)],
    );
}

/// The materials' contract: every model `MaterialModel` lists, through the whole reverse pass
/// (a new material is checked here without a line of its own).
#[test]
fn every_material_matches_fd_through_the_reverse_pass() {
    for model in morph::engine::material::MaterialModel::ALL {
        let mut scene = small_scene(KernelKind::Cubic, vec![EffectConfig::drag(0.5)]);
        scene.material.model = model;
        check_scene(scene, MassLossKind::Log, STEPS, H, |_| {});
    }
}

#[test]
fn reverse_pass_matches_fd_with_gravity_and_walls() {
    let effects = vec![
        EffectConfig::Gravity {
            acceleration: [0.0, -30.0, 5.0],
        },
        EffectConfig::Walls {
            mode: WallMode::Sticky,
            thickness: 6,
        },
    ];
    check_case(KernelKind::Cubic, MassLossKind::Log, effects.clone());
}

/// Slip walls clamp a velocity component only when it points into the wall, a switch where the
/// loss has a kink. Once a body is stopped by the wall, normal velocities at the wall pass
/// through zero and any finite difference straddles switches; so this check drives the body
/// into the low-x wall (clear of the others) through the impact, and uses a small step (1e-6)
/// so that no clamp switches inside it (measured: the difference converges to the adjoint at
/// 1e-9 relative as h shrinks, and straddles switches for h >= 1e-5).
#[test]
fn reverse_pass_matches_fd_with_slip_walls() {
    let slip = vec![EffectConfig::Walls {
        mode: WallMode::Slip,
        thickness: 3,
    }];
    let into_wall = |s: &mut State| {
        for p in 0..s.len() {
            s.x[p][0] -= 4.0;
            s.v[p] = Vector3::new(-30.0, 0.0, 0.0);
            s.c[p] = Matrix3::zeros();
            s.f[p] = Matrix3::identity();
        }
    };
    check_case_with(
        KernelKind::Quadratic,
        MassLossKind::Log,
        slip.clone(),
        STEPS,
        1e-6,
        into_wall,
    );
    check_case_with(
        KernelKind::Cubic,
        MassLossKind::Log,
        slip,
        STEPS,
        1e-6,
        into_wall,
    );
}

/// A ground collider with friction, tilted, struck by the body at an angle: the contact nodes
/// slide with friction (and some stick), through the impact. As with slip walls, the contact
/// switches are kinks of the loss, so the difference step is small (1e-6). The RK4 form
/// (friction as a rate, see `effects/collider.rs`) through the same impact.
#[test]
fn reverse_pass_matches_fd_with_a_ground_collider() {
    use morph::engine::scene::ColliderConfig;
    let ground = |friction: f64| {
        vec![EffectConfig::Collider {
            shape: ColliderConfig::Plane {
                point: [0.0, -4.6, 0.0],
                normal: [0.15, 1.0, -0.05],
            },
            friction,
        }]
    };
    let onto_ground = |s: &mut State| {
        for p in 0..s.len() {
            s.v[p] = Vector3::new(12.0, -40.0, 3.0);
            s.c[p] = Matrix3::zeros();
            s.f[p] = Matrix3::identity();
        }
    };
    for kernel in [KernelKind::Quadratic, KernelKind::Cubic] {
        check_case_with(
            kernel,
            MassLossKind::Log,
            ground(0.4),
            STEPS,
            1e-6,
            onto_ground,
        );
    }
    check_scene_on(
        small_scene(KernelKind::Cubic, ground(0.4)),
        IntegratorKind::Rk4,
        MassLossKind::Log,
        STEPS,
        1e-6,
        onto_ground,
    );
}

/// dL/dg for the gravity effect's parameter.
#[test]
fn gravity_parameter_gradient_matches_fd() {
    let g0 = [0.0, -30.0, 5.0];
    let build = |g: [f64; 3]| {
        small_scene(
            KernelKind::Cubic,
            vec![EffectConfig::Gravity { acceleration: g }],
        )
    };
    let (sim, mut init) = ball(&build(g0), 3.0);
    let mut rng = Lcg(5);
    deform(&mut init, &mut rng);
    let ctrl = controls(init.len(), STEPS, 4, 0.05, &mut rng);
    let loss = shifted_target(&sim, &init, Vector3::new(0.0, 1.0, 0.5), MassLossKind::Log);
    let mut tape = Tape::default();
    let (_, last) = rollout_loss(&sim, &init, &ctrl, STEPS, &loss, Some(&mut tape));
    let grads = sim.backward(&tape, &shared(&ctrl), loss_seed(&sim, &last, &loss));
    for a in 0..3 {
        let fd = fd(|e| {
            let mut g = g0;
            g[a] += e;
            let (s, _) = ball(&build(g), 3.0);
            rollout_loss(&s, &init, &ctrl, STEPS, &loss, None).0
        });
        let an = grads.effect_params[0][a];
        assert!(rel_err(an, fd) < TOL, "dL/dg[{a}]: {an:e} vs {fd:e}");
    }
}

/// The morph's segment objective (log mass loss + arrival term `w sum 1/2 m |v|^2` + the
/// volume cost on every step's state + the path term + a look-ahead window's waypoint) and the
/// gradient the optimizers use, against central differences along random directions of all
/// control layers at once: 12 steps, 3 layers, a moving start state, drag on.
#[test]
fn segment_objective_gradient_matches_finite_differences() {
    let scene = small_scene(KernelKind::Cubic, vec![EffectConfig::drag(0.5)]);
    for integrator in IntegratorKind::ALL {
        let (engine, init) = ball_engine(&scene, 3.2, integrator);
        morph::engine::with_integrator!(&engine, sim => check_segment(sim, init));
    }
}

fn check_segment<I: Integrator>(sim: &I, mut init: State) {
    use morph::segment::{PathPoint, Segment};
    let mut rng = Lcg(2024);
    deform(&mut init, &mut rng);
    let n = init.len();
    let loss = shifted_target(
        sim.model(),
        &init,
        Vector3::new(1.1, 0.4, -0.6),
        MassLossKind::Log,
    );
    // The same shifted target on a grid twice as fine, for the fine mass loss.
    let shifted: Vec<_> = init
        .x
        .iter()
        .map(|x| x + Vector3::new(1.1, 0.4, -0.6))
        .collect();
    let fine_grid = FineMassLoss::refine(&sim.model().grid, 2);
    let fine_target = morph::engine::mpm::transfer::mass_grid(
        &fine_grid,
        FINE_KERNEL,
        &shifted,
        &sim.model().mass,
    )
    .unwrap();
    let fine = FineMassLoss {
        grid: fine_grid,
        loss: MassLoss::new(MassLossKind::Log, fine_target),
        weight: 0.7,
    };
    // Two points on the scheduled path, inside the segment, against part-way targets.
    let path: Vec<PathPoint> = [(3, 0.3), (8, 0.7)]
        .into_iter()
        .map(|(step, part)| PathPoint {
            step,
            loss: shifted_target(
                sim.model(),
                &init,
                part * Vector3::new(1.1, 0.4, -0.6),
                MassLossKind::Log,
            ),
        })
        .collect();
    // A look-ahead window's waypoint: an earlier segment's end inside this one, scored in
    // full against its own target.
    let waypoints = [PathPoint {
        step: 5,
        loss: shifted_target(
            sim.model(),
            &init,
            Vector3::new(0.5, -0.3, 0.2),
            MassLossKind::Log,
        ),
    }];
    // The last control layer before the segment, which the continuity cost holds layer 0 to.
    let anchor: Vec<Matrix3<f64>> = (0..n).map(|_| 0.03 * rng.mat3()).collect();
    // A reach target: the body's box, grown by three spacings toward +x and one toward -y,
    // so those faces pull the particles nearest them.
    let spacing = sim.model().grid.dx / 2.0;
    let (lo, hi) = init.x.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), x| (lo.inf(x), hi.sup(x)),
    );
    let (lo, hi) = (
        lo - Vector3::new(0.0, spacing, 0.0),
        hi + Vector3::new(3.0 * spacing, 0.0, 0.0),
    );
    let mut box_mesh = morph::geometry::assets::cube(2.0, 3);
    for v in &mut box_mesh.vertices {
        *v = lo + (hi - lo).component_mul(&(*v + Vector3::repeat(1.0))) / 2.0;
    }
    let reach = morph::reach::ReachLoss::new(&box_mesh, spacing, 0.02);
    assert!(reach.value(&init.x) > 0.0, "the grown faces pull");
    for (arrival_weight, volume_weight, fine_loss, path_weight, waypoint, smoothing, reach) in [
        (0.0, 0.0, None, 0.0, false, 0.0, None),
        (0.05, 0.0, None, 0.0, false, 0.0, None),
        (0.0, 30.0, None, 0.0, false, 0.0, None),
        (0.0, 0.0, None, 0.8, false, 0.0, None),
        (0.0, 0.0, None, 0.0, true, 0.0, None),
        (0.0, 0.0, None, 0.0, false, 40.0, None),
        (0.0, 0.0, None, 0.0, false, 0.0, Some(&reach)),
        (0.05, 30.0, Some(&fine), 0.8, true, 40.0, Some(&reach)),
    ] {
        let segment = Segment {
            sim,
            loss: &loss,
            fine_loss,
            reach,
            start: &init,
            first_step: 0,
            steps: STEPS,
            stride: STRIDE,
            arrival_weight,
            volume_weight,
            path: if path_weight > 0.0 { &path } else { &[] },
            path_weight,
            waypoints: if waypoint { &waypoints } else { &[] },
            waypoint_weight: 0.4,
            smoothing,
            anchor: (smoothing > 0.0).then_some(&anchor[..]),
            resolution: Default::default(),
            tape_budget: usize::MAX,
        };
        let layers: Vec<Vec<Matrix3<f64>>> = (0..segment.num_layers())
            .map(|_| (0..n).map(|_| 0.03 * rng.mat3()).collect())
            .collect();
        let (value, grad) = segment.objective_and_gradient(&layers).unwrap();
        assert!(value.is_finite() && value > 0.0);
        // Checkpoints and recomputation (here the smallest budget) give bitwise the gradient
        // of the whole tape.
        let recomputed = Segment {
            tape_budget: 0,
            ..segment
        };
        assert!(recomputed.chunk_plan().interval < STEPS);
        assert_eq!(
            recomputed.objective_and_gradient(&layers).unwrap(),
            (value, grad.clone())
        );
        for trial in 0..2 {
            let dir: Vec<Vec<Matrix3<f64>>> = (0..layers.len())
                .map(|_| (0..n).map(|_| rng.mat3()).collect())
                .collect();
            let analytic: f64 = grad
                .iter()
                .flatten()
                .zip(dir.iter().flatten())
                .map(|(g, d)| g.dot(d))
                .sum();
            // The reach cost's nearest particle can change within the usual step (a kink of
            // the minimum distance, O(h) in the difference): a smaller step keeps such
            // switches out of it.
            let step = if reach.is_some() { 1e-6 } else { H };
            let numeric = fd_step(
                |h| {
                    let moved: Vec<Vec<Matrix3<f64>>> = layers
                        .iter()
                        .zip(&dir)
                        .map(|(l, d)| l.iter().zip(d).map(|(a, b)| a + h * b).collect())
                        .collect();
                    segment.objective(&moved).unwrap()
                },
                step,
            );
            let err = rel_err(analytic, numeric);
            assert!(
                err < TOL,
                "arrival {arrival_weight}, volume {volume_weight}, path {path_weight}, fine {}, waypoint {waypoint}, smoothing {smoothing}, reach {}, direction {trial}: {analytic} vs {numeric} ({err:e})",
                fine_loss.is_some(),
                reach.is_some()
            );
        }
    }
}

/// A grid effect that acts differently at every step: `v <- (1 + k w(step)) v` on nodes with
/// mass, `w` a sawtooth in the global step. Its reverse pass is only right if the tape gives
/// it the step the forward pass saw.
#[derive(Debug)]
struct Pulse {
    k: f64,
}

impl Pulse {
    fn w(step: usize) -> f64 {
        0.1 * ((step % 5) as f64 - 2.0)
    }
    /// A smooth function of time in steps (the ODE form reads fractional times).
    fn wt(t: f64) -> f64 {
        0.2 * (1.3 * t).sin()
    }
}

impl morph::engine::effects::Effect for Pulse {
    fn name(&self) -> &'static str {
        "pulse"
    }
    fn acts_on_grid(&self, _: GridForm) -> bool {
        true
    }
    fn num_params(&self) -> usize {
        1
    }
    /// The Euler step scales the node's velocity by a sawtooth in the step; the ODE form its
    /// velocity and acceleration by a smooth function of the time (so the four RK4 stages of
    /// one step see different values).
    fn apply_grid(&self, ctx: &GridContext, _node: usize, m: &mut NodeMotion) {
        let factor = 1.0 + self.k * Self::weight(ctx);
        m.v *= factor;
        m.a *= factor;
    }
    fn reverse_grid(
        &self,
        ctx: &GridContext,
        _node: usize,
        input: &NodeMotion,
        grad: &mut NodeMotion,
        grad_params: &mut [f64],
    ) {
        let w = Self::weight(ctx);
        let factor = 1.0 + self.k * w;
        grad_params[0] += w * (input.v.dot(&grad.v) + input.a.dot(&grad.a));
        grad.v *= factor;
        grad.a *= factor;
    }
}

impl Pulse {
    fn weight(ctx: &GridContext) -> f64 {
        match ctx.form {
            GridForm::Step => Self::w(ctx.step),
            GridForm::Rate => Self::wt(ctx.time / ctx.dt),
        }
    }
}

/// A time-dependent effect, followed by slip walls, in a rollout that starts at global step
/// 7: dL/dk and dL/dx0 against central differences.
#[test]
fn time_dependent_effect_gradient_matches_fd() {
    time_dependent_effect_case(IntegratorKind::Euler);
}

#[test]
fn rk4_time_dependent_effect_gradient_matches_fd() {
    time_dependent_effect_case(IntegratorKind::Rk4);
}

/// A time-dependent effect, followed by slip walls, in a rollout that starts at global step
/// 7: dL/dk and dL/dx0 against central differences, with integrator `kind`.
fn time_dependent_effect_case(kind: IntegratorKind) {
    const FIRST: usize = 7;
    let scene = small_scene(
        KernelKind::Cubic,
        vec![EffectConfig::Walls {
            mode: WallMode::Slip,
            thickness: 3,
        }],
    );
    let (x, vol) =
        morph::engine::scene::ball_particles(&scene.grid, Vector3::new(0.1, -0.2, 0.05), 3.0, 2);
    let build = |k: f64| {
        let mut model = scene.model(vol.clone()).unwrap();
        model.effects.insert(0, Box::new(Pulse { k }));
        Engine::new(model, kind).unwrap()
    };
    let k0 = 0.3;
    let engine = build(k0);
    let mut init = State::at_rest(x.clone());
    let mut rng = Lcg(11);
    deform(&mut init, &mut rng);
    let ctrl = controls(init.len(), STEPS, 4, 0.05, &mut rng);
    let loss = shifted_target(
        engine.model(),
        &init,
        Vector3::new(0.5, 0.0, -0.5),
        MassLossKind::Log,
    );
    fn run<I: Integrator>(
        sim: &I,
        init: &State,
        ctrl: &[Option<Vec<Matrix3<f64>>>],
        loss: &morph::loss::MassLoss,
        tape: Option<&mut I::Tape>,
    ) -> (f64, State) {
        let mut s = init.clone();
        sim.forward(&mut s, &shared(ctrl), FIRST, STEPS, tape)
            .unwrap();
        let m = sim.model().mass_grid(&s.x).unwrap();
        (loss.value_and_grad(&m).0, s)
    }
    let loss_of = |engine: &Engine, init: &State| morph::engine::with_integrator!(engine, sim => run(sim, init, &ctrl, &loss, None).0);
    let grads = morph::engine::with_integrator!(&engine, sim => {
        let mut tape = Default::default();
        let (_, last) = run(sim, &init, &ctrl, &loss, Some(&mut tape));
        sim.backward(&tape, &shared(&ctrl), loss_seed(sim.model(), &last, &loss))
    });
    let fd_k = fd(|e| loss_of(&build(k0 + e), &init));
    let an_k = grads.effect_params[0][0];
    assert!(
        rel_err(an_k, fd_k) < TOL,
        "{kind:?} dL/dk: {an_k:e} vs {fd_k:e}"
    );
    let dir: Vec<Vector3<f64>> = (0..init.len()).map(|_| rng.vec3()).collect();
    let an: f64 = grads
        .initial
        .x
        .iter()
        .zip(&dir)
        .map(|(g, d)| g.dot(d))
        .sum();
    let fd_x = fd_step(
        |e| {
            let mut s = init.clone();
            for (x, d) in s.x.iter_mut().zip(&dir) {
                *x += e * d;
            }
            loss_of(&engine, &s)
        },
        H / 5.0,
    );
    eprintln!(
        "{kind:?} time-dependent effect: dL/dk {an_k:e} vs {fd_k:e}, dL/dx0 {an:e} vs {fd_x:e}"
    );
    assert!(
        rel_err(an, fd_x) < TOL,
        "{kind:?} dL/dx0: {an:e} vs {fd_x:e}"
    );
}

/// RK4 on the ODE form through the same checks as the Euler step: dL/dFc at every control
/// layer and dL/d(x0, v0, F0), with drag, gravity and slip walls (every effect has a rate
/// form).
#[test]
fn rk4_reverse_pass_matches_fd_with_effects() {
    let scene = small_scene(
        KernelKind::Cubic,
        vec![
            EffectConfig::drag(0.5),
            EffectConfig::Gravity {
                acceleration: [0.0, -9.8, 0.0],
            },
            EffectConfig::Walls {
                mode: WallMode::Slip,
                thickness: 3,
            },
        ],
    );
    check_scene_on(
        scene,
        IntegratorKind::Rk4,
        MassLossKind::Log,
        STEPS,
        H,
        |_| {},
    );
}

/// Drag that switches on part-way through the run, eased in over a few steps (the morph's
/// settle drag after the final arrival): the reverse pass sees the same coefficient at each
/// step as the forward pass, with both integrators.
#[test]
fn drag_switched_on_mid_run_reverse_pass_matches_fd() {
    let dt = small_scene(KernelKind::Cubic, Vec::new()).dt;
    for integrator in IntegratorKind::ALL {
        let scene = small_scene(
            KernelKind::Cubic,
            vec![
                EffectConfig::drag(0.5),
                EffectConfig::Drag {
                    coefficient: 30.0,
                    start: 3.0 * dt,
                    ramp: 4.5 * dt,
                },
            ],
        );
        check_scene_on(scene, integrator, MassLossKind::Log, STEPS, H, |_| {});
    }
}

/// The reference paper's additive control (`Fe = F + Fc`, kept for comparison) through the
/// same checks, with both integrators.
#[test]
fn additive_control_reverse_pass_matches_fd() {
    for integrator in IntegratorKind::ALL {
        check_scene_form(
            small_scene(KernelKind::Cubic, vec![EffectConfig::drag(0.5)]),
            integrator,
            ControlForm::Additive,
            MassLossKind::Log,
            STEPS,
            H,
            |_| {},
        );
    }
}

/// The memory plan's bytes per step (`Integrator::tape_bytes_per_step`) are what a real
/// tape holds (`RunTape::bytes`), for both integrators, with a control on every step.
#[test]
fn planned_tape_bytes_match_a_real_tape() {
    use morph::engine::integrator::RunTape;
    let scene = small_scene(KernelKind::Cubic, Vec::new());
    for integrator in IntegratorKind::ALL {
        let (engine, init) = ball_engine(&scene, 3.2, integrator);
        morph::engine::with_integrator!(&engine, sim => {
            let n = init.len();
            let ctrl: Vec<Option<Vec<Matrix3<f64>>>> =
                (0..4).map(|_| Some(vec![Matrix3::zeros(); n])).collect();
            let mut tape = Default::default();
            let mut s = init.clone();
            sim.forward(&mut s, &shared(&ctrl), 0, 4, Some(&mut tape)).unwrap();
            let measured = (tape.bytes() - tape.last().bytes()) as f64 / 4.0;
            let planned = sim.tape_bytes_per_step(n) as f64;
            assert!(
                (planned / measured - 1.0).abs() < 0.02,
                "{integrator:?}: planned {planned} vs measured {measured} bytes a step"
            );
        });
    }
}

/// The effects' contract: every effect a scene can declare, alone, through the whole reverse
/// pass against finite differences, with both integrators (colliders with Coulomb friction),
/// along one random direction per quantity. A new effect adds its row.
#[test]
fn every_effect_alone_matches_fd_with_both_integrators() {
    use morph::engine::scene::ColliderConfig;
    let cube = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/cube.obj");
    let ground = |friction| EffectConfig::Collider {
        shape: ColliderConfig::Plane {
            point: [0.0, -4.6, 0.0],
            normal: [0.15, 1.0, -0.05],
        },
        friction,
    };
    let block = |friction| EffectConfig::Collider {
        shape: ColliderConfig::Mesh {
            path: cube.clone(),
            scale: 2.5,
            translation: [0.3, -6.0, 0.0],
        },
        friction,
    };
    let dt = small_scene(KernelKind::Cubic, Vec::new()).dt;
    // Each row: its name, the effect under Euler and under RK4, and whether it bounds the
    // domain (the ball is then thrown at it; otherwise it drifts slowly, within the grid).
    let rows: Vec<(&str, EffectConfig, EffectConfig, bool)> = vec![
        (
            "drag",
            EffectConfig::drag(0.5),
            EffectConfig::drag(0.5),
            false,
        ),
        (
            "drag switched on",
            EffectConfig::Drag {
                coefficient: 30.0,
                start: 3.0 * dt,
                ramp: 4.5 * dt,
            },
            EffectConfig::Drag {
                coefficient: 30.0,
                start: 3.0 * dt,
                ramp: 4.5 * dt,
            },
            false,
        ),
        (
            "gravity",
            EffectConfig::Gravity {
                acceleration: [0.0, -30.0, 5.0],
            },
            EffectConfig::Gravity {
                acceleration: [0.0, -30.0, 5.0],
            },
            false,
        ),
        (
            "slip walls",
            EffectConfig::Walls {
                mode: WallMode::Slip,
                thickness: 3,
            },
            EffectConfig::Walls {
                mode: WallMode::Slip,
                thickness: 3,
            },
            true,
        ),
        (
            "sticky walls",
            EffectConfig::Walls {
                mode: WallMode::Sticky,
                thickness: 3,
            },
            EffectConfig::Walls {
                mode: WallMode::Sticky,
                thickness: 3,
            },
            true,
        ),
        ("ground", ground(0.4), ground(0.4), true),
        ("mesh collider", block(0.4), block(0.4), true),
    ];
    let moving = |v: Vector3<f64>| {
        move |s: &mut State| {
            for p in 0..s.len() {
                s.v[p] = v;
                s.c[p] = Matrix3::zeros();
                s.f[p] = Matrix3::identity();
            }
        }
    };
    for (name, euler, rk4, bounds) in rows {
        // Thrown down and sideways at a boundary, so it is met within the run.
        let speed = if bounds { 1.0 } else { 0.2 };
        for (integrator, effect) in [(IntegratorKind::Euler, euler), (IntegratorKind::Rk4, rk4)] {
            eprintln!("{name} with {integrator:?}");
            check_scene_once(
                small_scene(KernelKind::Cubic, vec![effect]),
                integrator,
                MassLossKind::Log,
                STEPS,
                1e-6,
                moving(speed * Vector3::new(12.0, -40.0, 3.0)),
            );
        }
    }
}
