//! Bad states and settings give typed errors naming the step and particle, never a panic.

use crate::common;

use common::*;
use morph::engine::mpm::{KernelKind, SimError};
use morph::engine::scene::SceneConfig;
use nalgebra::{Matrix3, Vector3};

#[test]
fn particle_outside_grid_at_start() {
    let (sim, mut s) = ball(&small_scene(KernelKind::Cubic, vec![]), 3.0);
    s.x[17] = Vector3::new(7.9, 0.0, 0.0); // the cubic stencil needs 2 nodes beyond
    let err = sim.forward(&mut s, &[], 0, 5, None).unwrap_err();
    assert!(
        matches!(
            err,
            SimError::OutsideGrid {
                step: 0,
                particle: 17,
                ..
            }
        ),
        "{err:?}"
    );
    assert!(err.to_string().contains("particle 17"), "{err}");
}

#[test]
fn particle_leaving_the_grid_later() {
    let (sim, mut s) = ball(&small_scene(KernelKind::Quadratic, vec![]), 2.0);
    for v in s.v.iter_mut() {
        *v = Vector3::new(60.0, 0.0, 0.0);
    }
    let err = sim.forward(&mut s, &[], 0, 200, None).unwrap_err();
    match err {
        SimError::OutsideGrid { step, .. } => assert!(step > 10, "left at step {step}"),
        e => panic!("expected OutsideGrid, got {e:?}"),
    }
}

#[test]
fn nan_in_the_state_or_controls() {
    let (sim, s0) = ball(&small_scene(KernelKind::Cubic, vec![]), 3.0);
    let mut s = s0.clone();
    s.v[5][1] = f64::NAN;
    let err = sim.forward(&mut s, &[], 3, 5, None).unwrap_err();
    assert_eq!(
        err,
        SimError::NonFinite {
            step: 3,
            particle: 5,
            field: "velocity"
        }
    );
    let mut s = s0.clone();
    s.x[9][2] = f64::INFINITY;
    let err = sim.forward(&mut s, &[], 0, 5, None).unwrap_err();
    assert_eq!(
        err,
        SimError::NonFinite {
            step: 0,
            particle: 9,
            field: "position"
        }
    );
    let mut s = s0.clone();
    let mut fc = vec![Matrix3::zeros(); s.len()];
    fc[12][(0, 0)] = f64::NAN;
    let err = sim
        .forward(&mut s, &[None, Some(fc.into())], 0, 5, None)
        .unwrap_err();
    assert_eq!(
        err,
        SimError::NonFinite {
            step: 1,
            particle: 12,
            field: "control Fc"
        }
    );
}

#[test]
fn unstable_time_step_is_refused() {
    let mut scene = small_scene(KernelKind::Cubic, vec![]);
    scene.dt = 0.05; // wave speed sqrt(136111 / 40) = 58.3 cells/s: limit dx / c = 0.0171
    let (_, vol) = morph::engine::scene::ball_particles(&scene.grid, Vector3::zeros(), 3.0, 2);
    let err = scene.build(vol).unwrap_err();
    match err {
        SimError::UnstableTimeStep { dt, limit, .. } => {
            assert_eq!(dt, 0.05);
            assert!((limit - 1.0 / (136111.0f64 / 40.0).sqrt()).abs() < 1e-4);
        }
        e => panic!("expected UnstableTimeStep, got {e:?}"),
    }
    // The reference dt is within the bound.
    let (_, vol) = morph::engine::scene::ball_particles(
        &SceneConfig::reference().grid,
        Vector3::zeros(),
        3.0,
        2,
    );
    assert!(SceneConfig::reference().build(vol).is_ok());
}

#[test]
fn runaway_velocity_exceeds_cfl() {
    let (sim, mut s) = ball(&small_scene(KernelKind::Cubic, vec![]), 3.0);
    s.v[3] = Vector3::new(0.0, 500.0, 0.0);
    let err = sim.forward(&mut s, &[], 0, 5, None).unwrap_err();
    assert!(
        matches!(
            err,
            SimError::CflExceeded {
                step: 0,
                particle: 3,
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn absurd_scene_settings() {
    let mut scene = small_scene(KernelKind::Cubic, vec![]);
    let (_, vol) = morph::engine::scene::ball_particles(&scene.grid, Vector3::zeros(), 3.0, 2);
    scene.dt = -1.0;
    assert!(matches!(
        scene.build(vol.clone()),
        Err(SimError::InvalidScene(_))
    ));
    scene.dt = 1.0 / 120.0;
    scene.material.density = f64::NAN;
    assert!(matches!(
        scene.build(vol.clone()),
        Err(SimError::InvalidScene(_))
    ));
    scene.material.density = 40.0;
    // A drag that switches on at a negative time or eases in over a non-finite ramp.
    for (start, ramp) in [(-1.0, 0.0), (0.0, f64::NAN)] {
        scene.effects = vec![morph::engine::scene::EffectConfig::Drag {
            coefficient: 1.0,
            start,
            ramp,
        }];
        assert!(matches!(
            scene.build(vol.clone()),
            Err(SimError::InvalidScene(_))
        ));
    }
    scene.effects = vec![];
    scene.grid.dx = 0.0;
    assert!(matches!(scene.build(vol), Err(SimError::InvalidScene(_))));
}
