//! The fast hard cases (`morph::apps::bench::hard_cases`): each stays finite, inside the grid,
//! with 0 < J <= J_MAX and a bounded speed on every frame, or is refused with one line.
//! The long ones run with `morph bench-hard-cases --long` (docs/engine.md).

use morph::apps::bench::hard_cases::{Case, Outcome, cases, run_case};
use std::path::Path;

fn case(name: &str) -> Case {
    let meshes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
    cases(&meshes)
        .expect("the shared meshes load")
        .into_iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no case {name}"))
}

/// Runs a case and checks it did what it should; returns its outcome for further checks.
fn check(name: &str) -> Outcome {
    let c = case(name);
    assert!(!c.long, "{name} is a long case");
    let outcome = run_case(&c);
    eprintln!("{}", serde_json::to_string(&outcome).unwrap());
    if let Err(e) = outcome.check(&c.expect) {
        panic!("{e}");
    }
    outcome
}

#[test]
fn stiff_materials_substep_instead_of_failing() {
    let base = morph::apps::bench::hard_cases::quick();
    let step = morph::MORPH_STEP;
    let mut bounds = Vec::new();
    for name in ["stiff-x100", "stiff-x10000"] {
        let m = check(name).measured.unwrap();
        // The fewest substeps that keep each within half the elastic bound.
        assert!(m.substeps > 1, "{name}");
        assert!(
            (m.dt * m.substeps as f64 - step).abs() < 1e-15,
            "{name}: {m:?}"
        );
        assert!(m.dt <= 0.5 * m.stable_dt, "{name}: {m:?}");
        assert!(
            step / (m.substeps - 1) as f64 > 0.5 * m.stable_dt,
            "{name}: {m:?}"
        );
        // The shot keeps its length: 6 steps of 1/120 s, a frame every 5 (24 fps).
        assert_eq!(m.frames, 6 / base.timing().frame_every + 1, "{name}");
        bounds.push(m.stable_dt);
    }
    // The bound falls with the square root of the stiffness.
    assert!((bounds[0] / bounds[1] - 10.0).abs() < 1e-9, "{bounds:?}");
}

#[test]
fn a_time_step_above_the_bound_is_refused_with_the_bound() {
    let e = check("dt-above-bound").error.unwrap();
    assert!(
        e.contains("`dt` 0.01") && e.contains("s of this material"),
        "{e}"
    );
}

#[test]
fn thin_features_bunny_ears_and_a_rod() {
    for name in ["bunny-ears-24", "bunny-ears-32", "thin-rod"] {
        check(name);
    }
}

#[test]
fn far_apart_shapes_are_refused_with_the_distance() {
    let e = check("far-apart-as-given").error.unwrap();
    assert!(e.contains("10.0000 units"), "{e}");
}

#[test]
fn a_plate_thinner_than_two_cells() {
    check("plate-thinner-than-two-cells");
}

#[test]
fn tiny_and_huge_units_morph_alike() {
    let tiny = check("units-1e-4").measured.unwrap();
    let huge = check("units-1e4").measured.unwrap();
    // The simulation runs on the domain's scale, whatever the mesh units: the same morph.
    let rel = (tiny.final_loss - huge.final_loss).abs() / huge.final_loss;
    assert!(rel < 1e-6, "{} vs {}", tiny.final_loss, huge.final_loss);
    assert_eq!(tiny.particles, huge.particles);
}

#[test]
fn topology_changes() {
    for name in [
        "sphere-to-torus",
        "two-lobes-to-sphere",
        "sphere-to-two-blobs",
    ] {
        let m = check(name).measured.unwrap();
        assert!(m.final_loss < m.initial_loss, "{name}: {m:?}");
    }
}

#[test]
fn source_equal_to_target_does_not_move() {
    let m = check("source-equals-target").measured.unwrap();
    assert_eq!(m.initial_loss, 0.0);
    assert_eq!(m.final_loss, 0.0);
    assert_eq!(m.max_displacement_cells, 0.0);
    assert_eq!((m.min_j, m.max_j), (1.0, 1.0));
}

#[test]
fn a_learning_rate_100x_the_default_stays_finite() {
    let m = check("learning-rate-x100").measured.unwrap();
    // The first steps were too large: each was undone (recorded as such) and halved until one
    // lowered the objective, so the run still gets somewhere.
    assert!(m.rejected_steps > 0, "{m:?}");
    assert!(m.final_loss < m.initial_loss, "{m:?}");
}

#[test]
fn a_40_segment_chain_keeps_its_energy_bounded() {
    let m = check("chain-40-segments").measured.unwrap();
    assert_eq!(m.grad_norms.len(), 40);
    // The body settles: the last frame holds a fraction of the peak energy, and a body that
    // has arrived is not warned about.
    assert!(m.last_over_peak_energy < 0.5, "{m:?}");
    assert!(m.warnings.is_empty(), "{m:?}");
}

#[test]
fn a_300_step_segment_keeps_a_finite_gradient() {
    let m = check("segment-300-steps").measured.unwrap();
    let (first, last) = m.grad_norms[0];
    assert!(
        first.is_finite() && first > 0.0 && last.is_finite(),
        "{m:?}"
    );
}
