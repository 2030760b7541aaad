//! `morph rope`: bad control settings are clear one-line errors (exit 2), and a short run
//! writes report.json with the three methods, energy.png and PLY frames, where each
//! controller's committed steps replay exactly and MPPI is deterministic across thread counts.

use morph::apps::rope::compare::{RopeSettings, run_rope};
use morph::engine::integrator::{Controlled, Steps};
use morph::engine::mpm::{ControlParams, ControlPlan};
use nalgebra::Vector3;
use std::process::Command;

fn rope(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_morph"))
        .arg("rope")
        .args(args)
        .output()
        .expect("run morph")
}

#[test]
fn bad_control_settings_are_clear_errors() {
    let cases: &[(&[&str], &str)] = &[
        (&["--steps", "-5"], "--steps must be at least 1, got -5"),
        (&["--steps", "0"], "--steps must be at least 1"),
        (
            &["--mppi-horizon", "-10"],
            "--mppi-horizon must be at least 1",
        ),
        (&["--batch", "2000"], "larger than the horizon"),
        (&["--batch", "35"], "multiple of the control interval"),
        (&["--batch", "0"], "--batch must be at least 1"),
        (
            &["--lookahead", "15"],
            "lookahead (15) must be a multiple of the control interval",
        ),
        (&["--lookahead", "-1"], "--lookahead must be at least 0"),
        (
            &["--control-interval", "7"],
            "must be >= 1 and divide the horizon",
        ),
        (
            &["--replan", "200", "--mppi-horizon", "100"],
            "MPPI replans every 200 steps",
        ),
        (
            &["--lr", "NaN"],
            "learning rate must be positive and finite, got NaN",
        ),
        (&["--lr", "-0.1"], "learning rate must be positive"),
        (
            &["--lambda", "inf"],
            "MPPI lambda must be positive and finite",
        ),
        (&["--noise", "0"], "MPPI noise must be positive"),
        (&["--samples", "1"], "--samples must be at least 2"),
        (
            &["--max-tip-acceleration", "nan"],
            "max tip acceleration must be finite",
        ),
        (
            &["--max-clamp-speed", "-1"],
            "max clamp speed must be finite and >= 0",
        ),
        (&["--dt", "inf"], "dt must be positive and finite"),
        (&["--dt", "0.5"], "exceeds the stable bound"),
        (
            &["--low-energy", "2"],
            "low-energy fraction must be in (0, 1)",
        ),
    ];
    for (args, expected) in cases {
        let out = rope(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        let lines: Vec<&str> = err.lines().collect();
        assert_eq!(lines.len(), 1, "{args:?}: not one line: {err}");
        assert!(
            lines[0].starts_with("morph: error: ") && lines[0].contains(expected),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn non_finite_or_misshapen_control_knots_are_refused() {
    let settings = RopeSettings::default();
    let rope = settings.rope.build().unwrap();
    let plan: ControlPlan = rope.engine.model().controls();
    let mut p: ControlParams = plan.zero_params();
    p[0][3] = Vector3::new(f64::NAN, 0.0, 0.0);
    let err = plan.check_params(&p).unwrap_err().to_string();
    assert!(err.contains("knot 3 is not finite"), "{err}");
    let mut s = rope.initial.clone();
    let err = morph::engine::with_integrator!(&rope.engine, sys => sys.run(&mut s, &p, Steps::new(0, 5), None, &mut |_, _| {}))
        .unwrap_err()
        .to_string();
    assert!(err.contains("not finite"), "{err}");
    p[0].pop();
    assert!(
        plan.check_params(&p)
            .unwrap_err()
            .to_string()
            .contains("knots")
    );
}

/// A short scene (0.2 s) so the test stays fast.
fn short() -> RopeSettings {
    let mut s = RopeSettings::default();
    s.rope.steps = 100;
    s.gradient.batch_steps = 50;
    s.gradient.iterations = 2;
    s.mppi.samples = 6;
    s.mppi.horizon_steps = 30;
    s.mppi.replan_steps = 10;
    s.frame_every = 50;
    s
}

#[test]
fn rope_run_writes_report_plot_and_frames() {
    let dir = std::env::temp_dir().join(format!("morph-rope-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = rope(&[
        "-o",
        dir.to_str().unwrap(),
        "--steps",
        "100",
        "--batch",
        "50",
        "--iterations",
        "2",
        "--samples",
        "6",
        "--mppi-horizon",
        "30",
        "--frame-every",
        "50",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.join("report.json")).unwrap();
    let report: serde_json::Value = serde_json::from_str(&text).unwrap();
    for method in ["uncontrolled", "mppi", "gradient"] {
        let m = &report[method];
        let energy = m["energy"].as_array().unwrap();
        assert_eq!(energy.len(), 100, "{method}");
        assert!(energy.iter().all(|e| e.as_f64().unwrap().is_finite()));
        assert_eq!(
            m["last_step_energy"].as_f64().unwrap(),
            energy[99].as_f64().unwrap()
        );
        let tail: f64 = energy[75..]
            .iter()
            .map(|e| e.as_f64().unwrap())
            .sum::<f64>()
            / 25.0;
        assert!((m["final_energy"].as_f64().unwrap() - tail).abs() <= 1e-12 * tail.abs());
        // Compute time: none for the uncontrolled run; for a controller, its total is the
        // time at which its last step was committed, and the commit times never go back.
        let compute = m["compute_s"].as_f64().unwrap();
        if method == "uncontrolled" {
            assert_eq!(compute, 0.0);
        } else {
            let at: Vec<f64> = m["committed_at_s"]
                .as_array()
                .unwrap()
                .iter()
                .map(|t| t.as_f64().unwrap())
                .collect();
            assert_eq!(at.len(), 100, "{method}: a commit time per step");
            assert!(at.windows(2).all(|w| w[0] <= w[1]), "{method}: {at:?}");
            assert!(
                at[0] > 0.0 && compute >= at[99],
                "{method}: {compute} vs {at:?}"
            );
        }
        let frames = m["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 3, "{method}: frames at steps 0, 50, 100");
        for f in frames {
            assert!(dir.join(f.as_str().unwrap()).is_file());
        }
    }
    assert!(report["mppi"]["compute_s"].as_f64().unwrap() > 0.0);
    assert!(dir.join("energy.png").is_file());
    assert!(!std::path::Path::new(&format!("{}.partial", dir.display())).exists());
    // An existing folder is refused without --overwrite.
    let again = rope(&[
        "-o",
        dir.to_str().unwrap(),
        "--steps",
        "100",
        "--batch",
        "50",
    ]);
    assert_eq!(again.status.code(), Some(2));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn controllers_are_deterministic_across_thread_counts() {
    let s = short();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run_rope(&s, |_| {}).unwrap().report)
    };
    let (a, b) = (run(1), run(2));
    for (x, y) in [(&a.mppi, &b.mppi), (&a.gradient, &b.gradient)] {
        assert_eq!(x.energy, y.energy);
        assert_eq!(x.controls, y.controls);
    }
    // Control does something: both controllers end below the uncontrolled rope's cost.
    assert!(a.gradient.cost < a.uncontrolled.cost);
    assert!(a.mppi.cost < a.uncontrolled.cost);
}
