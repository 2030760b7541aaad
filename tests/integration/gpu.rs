//! The GPU device from the command line: a morph and `morph bench` with `--device gpu` on
//! whatever adapter there is (lavapipe in CI), and the one-line error where there is none. The device's agreement
//! with the CPU engine is tested in its crate (`crates/gpu/tests`).

use crate::common::cli::{manifest, morph, ok, scratch_in};
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

/// A small morph (draft, 9 frames, 16 cells) with `extra` options into `out`.
fn small_morph(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "assets/sphere.obj",
        "assets/two-lobes.obj",
        "--preset",
        "draft",
        "--frames",
        "9",
        "--resolution",
        "16",
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    morph(&args)
}

fn files_of(dir: &std::path::Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            match p.is_dir() {
                true => stack.push(p),
                false => out.push(p.strip_prefix(dir).unwrap().display().to_string()),
            }
        }
    }
    out.sort();
    out
}

#[test]
fn a_morph_on_the_device_writes_the_cpu_runs_files_and_its_judge_agrees() {
    let (cpu, gpu) = (scratch_in("gpu", "cpu"), scratch_in("gpu", "gpu"));
    ok(&small_morph(cpu.as_ref(), &[]));
    let r = small_morph(gpu.as_ref(), &["--device", "gpu"]);
    ok(&r);
    let said = String::from_utf8_lossy(&r.stdout);
    assert!(said.lines().any(|l| l.starts_with("device: ")), "{said}");
    assert_eq!(files_of(cpu.as_ref()), files_of(gpu.as_ref()));
    let (mc, mg) = (manifest(cpu.as_ref()), manifest(gpu.as_ref()));
    assert_eq!(mg["settings"]["method"]["device"], "gpu");
    assert_eq!(mc["timings"]["device"], "cpu");
    assert_ne!(mg["timings"]["device"], "cpu");
    for key in ["iou", "fill"] {
        let (c, g) = (
            mc["quality"][key].as_f64().unwrap(),
            mg["quality"][key].as_f64().unwrap(),
        );
        assert!((c - g).abs() < 0.005, "{key}: cpu {c}, gpu {g}");
    }
    assert_eq!(mg["frames_summary"]["frames_inverted"], 0);
    // In f32 the judge stays within 0.01 of f64's.
    let narrow = scratch_in("gpu", "gpu-f32");
    ok(&small_morph(
        narrow.as_ref(),
        &["--device", "gpu", "--precision", "f32"],
    ));
    let mf = manifest(narrow.as_ref());
    assert_eq!(mf["settings"]["method"]["precision"], "f32");
    for key in ["iou", "fill"] {
        let (g, f) = (
            mg["quality"][key].as_f64().unwrap(),
            mf["quality"][key].as_f64().unwrap(),
        );
        assert!((g - f).abs() < 0.01, "{key}: f64 {g}, f32 {f}");
    }
}

#[test]
fn a_morph_without_an_adapter_stops_before_any_output() {
    let out = scratch_in("gpu", "none");
    let r = Command::new(env!("CARGO_BIN_EXE_morph"))
        .current_dir(crate::common::cli::root())
        .args([
            "assets/sphere.obj",
            "assets/two-lobes.obj",
            "--preset",
            "draft",
        ])
        .args(["--device", "gpu", "-o"])
        .arg(out.as_ref() as &std::path::Path)
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
    let p: &std::path::Path = out.as_ref();
    assert!(!p.exists());
    assert!(!p.with_extension("partial").exists());
    let r = small_morph(p, &["--device", "gpu", "--integrator", "rk4"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--device gpu runs the Euler integrator"),
        "{err}"
    );
    let r = small_morph(p, &["--precision", "f32"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("the CPU engine runs in f64"), "{err}");
}
