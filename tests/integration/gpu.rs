//! The GPU device from the command line: `morph bench --device gpu` on whatever adapter there
//! is (lavapipe in CI), and the one-line error where there is none. The device's agreement
//! with the CPU engine is tested in its crate (`crates/gpu/tests`).

use crate::common::cli::{morph, ok};
use std::process::Command;

#[test]
fn bench_on_the_device_prints_the_cpu_bench_lines() {
    let r = morph(&[
        "bench",
        "--device",
        "gpu",
        "--kernels",
        "cubic",
        "--steps",
        "3",
        "--repeats",
        "1",
    ]);
    ok(&r);
    let out = String::from_utf8_lossy(&r.stdout);
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let benches: Vec<&str> = lines.iter().map(|l| l["bench"].as_str().unwrap()).collect();
    assert_eq!(benches, ["forward", "forward_reverse"]);
    for l in &lines {
        assert_eq!(l["device"], "gpu");
        assert!(l["adapter"].as_str().is_some_and(|a| !a.is_empty()));
        assert!(l["particle_steps_per_s"].as_f64().unwrap() > 0.0);
        assert_eq!(l["particles"], 17256);
    }
}

#[test]
fn no_adapter_is_one_error_line() {
    let r = Command::new(env!("CARGO_BIN_EXE_morph"))
        .args([
            "bench",
            "--device",
            "gpu",
            "--kernels",
            "cubic",
            "--steps",
            "1",
        ])
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("morph: error: no GPU adapter found"),
        "{err}"
    );
    assert!(err.contains("--device cpu"), "{err}");
    assert!(r.stdout.is_empty());
}

#[test]
fn the_device_runs_the_euler_integrator_only() {
    let r = morph(&["bench", "--device", "gpu", "--integrators", "rk4"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert_eq!(
        err.trim(),
        "morph: error: --device gpu runs the Euler integrator only"
    );
}
