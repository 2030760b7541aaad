//! `morph study` on a tiny grid: the three files, their columns, finite figures, a readable
//! plot, a continued study that skips what it measured, and a refused foreign folder.

use crate::common;
use common::cli::Scratch;
use std::path::PathBuf;
use std::process::Command;

fn scratch(name: &str) -> Scratch {
    Scratch::empty("morph-study-tests", name)
}

/// `morph study` of sphere -> two-lobes into `out` with `grid` (the axes) and `extra`.
fn study_with(out: &PathBuf, grid: &[&str], extra: &[&str]) -> std::process::Output {
    let root = env!("CARGO_MANIFEST_DIR");
    Command::new(env!("CARGO_BIN_EXE_morph"))
        .args([
            "study",
            &format!("{root}/assets/sphere.obj"),
            &format!("{root}/assets/two-lobes.obj"),
        ])
        .arg("-o")
        .arg(out)
        .args(grid)
        .args(extra)
        .output()
        .expect("run morph study")
}

/// The tiny grid: resolutions 10 and 12, one segment of one iteration.
fn study(out: &PathBuf, extra: &[&str]) -> std::process::Output {
    let grid = ["--quick", "--resolutions", "10,12", "--iterations", "1"];
    study_with(
        out,
        &grid,
        &[&["--segments", "1", "--kernels", "quadratic"], extra].concat(),
    )
}

#[test]
fn a_tiny_study_writes_its_files_and_continues() {
    let out = scratch("tiny");
    let r = study(&out, &[]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));

    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header, morph::apps::study::CSV_COLUMNS);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 2, "one row per configuration");
    let text_columns = ["id", "preset", "kernel", "integrator", "pareto", "error"];
    // Empty where they do not apply: no budget was asked for; a run whose shape barely
    // changes has no ease error.
    let may_be_empty = ["particle_budget", "ease_error"];
    for row in &rows {
        assert_eq!(row.len(), header.len());
        assert_eq!(row[header.len() - 1], "", "no configuration failed");
        for (col, value) in header.iter().zip(row) {
            if text_columns.contains(col) || (may_be_empty.contains(col) && value.is_empty()) {
                continue;
            }
            // CPU seconds and peak memory are measured on Linux, where the tests run.
            let v: f64 = value
                .parse()
                .unwrap_or_else(|_| panic!("column {col} is not a number: '{value}'"));
            assert!(v.is_finite(), "column {col} is {v}");
        }
    }
    assert!(
        rows.iter().any(|r| r[header.len() - 2] == "true"),
        "a Pareto front"
    );

    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("study.json")).unwrap()).unwrap();
    assert_eq!(json["rows"].as_array().unwrap().len(), 2);
    assert_eq!(
        json["inputs"].as_array().unwrap().len(),
        2,
        "the meshes are recorded"
    );
    let png = image::open(out.join("study.png")).expect("a readable PNG");
    assert!(png.width() > 100 && png.height() > 100);

    // Run again: both configurations are kept, none re-run; one more resolution adds one.
    let again = study(&out, &[]);
    assert!(again.status.success());
    let said = String::from_utf8_lossy(&again.stdout);
    assert_eq!(said.matches("measured earlier, kept").count(), 2, "{said}");
    let more = study(&out, &["--resolutions", "10,12,14"]);
    assert!(more.status.success());
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 3);
    // A particle budget and a reach weight are axes too: a budget picks the resolution (the
    // row says which), a weight is a configuration of its own, and the motion is measured.
    let axes = study(&out, &["--particles", "600", "--reach-weights", "0,10"]);
    assert!(
        axes.status.success(),
        "{}",
        String::from_utf8_lossy(&axes.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("study.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    let ids: Vec<&str> = rows.iter().map(|r| r["id"].as_str().unwrap()).collect();
    assert_eq!(rows.len(), 3 + 4, "{ids:?}");
    for id in [
        "draft-r10-ppc2-quadratic-euler-it1-p1-s1-rw10",
        "draft-r12-ppc2-quadratic-euler-it1-p1-s1-rw10",
        "draft-n600-ppc2-quadratic-euler-it1-p1-s1",
        "draft-n600-ppc2-quadratic-euler-it1-p1-s1-rw10",
    ] {
        assert!(ids.contains(&id), "{id} in {ids:?}");
    }
    let budget = rows
        .iter()
        .find(|r| r["id"] == "draft-n600-ppc2-quadratic-euler-it1-p1-s1")
        .unwrap();
    let particles = budget["particles"].as_f64().unwrap();
    assert!((300.0..=1200.0).contains(&particles), "{budget}");
    assert!(budget["resolution"].as_u64().unwrap() > 0, "{budget}");
    for r in rows {
        let pulse = r["motion"]["pulse"].as_f64();
        assert!(pulse.is_some_and(f64::is_finite), "motion measured: {r}");
    }
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();

    // The same folder for other meshes: refused, its rows do not apply (they were kept as
    // "measured earlier" and the study exited 0).
    let root = env!("CARGO_MANIFEST_DIR");
    let other = Command::new(env!("CARGO_BIN_EXE_morph"))
        .args([
            "study",
            &format!("{root}/assets/sphere.obj"),
            &format!("{root}/assets/cube.obj"),
        ])
        .arg("-o")
        .arg(&out)
        .args(["--quick", "--resolutions", "10,12"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&other.stderr);
    assert_eq!(other.status.code(), Some(2), "{err}");
    assert!(
        err.starts_with("morph: error: ") && err.contains("a study of another target mesh"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(out.join("study.csv")).unwrap(), csv);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_study_refuses_a_folder_it_did_not_make() {
    let out = scratch("foreign");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), "mine").unwrap();
    let r = study(&out, &[]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.starts_with("morph: error: ") && err.contains("not empty"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("keep.txt")).unwrap(),
        "mine"
    );
    // A study.json of morph 0.2.0 (a bare list of rows, no meshes): refused, kept.
    let old = scratch("old-study");
    std::fs::create_dir_all(&old).unwrap();
    std::fs::write(old.join("study.json"), "[]").unwrap();
    let r = study(&old, &[]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("not a study this morph can continue"), "{err}");
    assert_eq!(
        std::fs::read_to_string(old.join("study.json")).unwrap(),
        "[]"
    );
    let bad = study(&scratch("bad"), &["--segments", "0"]);
    assert_eq!(bad.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&out);
}

/// The new axes' bad values are refused with one line and exit 2, before anything is written.
#[test]
fn bad_budgets_and_reach_weights_are_refused() {
    for (name, extra) in [
        ("neg-reach", ["--reach-weights", "-1"]),
        ("nan-reach", ["--reach-weights", "nan"]),
        ("zero-budget", ["--particles", "0"]),
    ] {
        let out = scratch(name);
        let _ = std::fs::remove_dir_all(&out);
        let r = study(&out, &extra);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.starts_with("morph: error: ") && err.trim_end().lines().count() == 1,
            "{name}: {err}"
        );
        assert!(!out.join("study.json").exists(), "{name}: nothing written");
    }
}

/// Each configuration's peak memory is its own: a small run measured after a large one does
/// not report the memory the large one freed (glibc keeps it unless it is handed back).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn a_small_configuration_after_a_large_one_reports_its_own_peak() {
    let out = scratch("peaks");
    let _ = std::fs::remove_dir_all(&out);
    // The large grid first: configurations run in the order asked.
    let grid = ["--quick", "--resolutions", "40,10", "--iterations", "1"];
    let r = study_with(&out, &grid, &["--segments", "1", "--kernels", "quadratic"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("study.json")).unwrap()).unwrap();
    let peak = |id: &str| {
        let rows = json["rows"].as_array().unwrap();
        let row = rows.iter().find(|r| r["id"] == id).unwrap();
        row["peak_mb"].as_f64().unwrap()
    };
    let (large, small) = (
        peak("draft-r40-ppc2-quadratic-euler-it1-p1-s1"),
        peak("draft-r10-ppc2-quadratic-euler-it1-p1-s1"),
    );
    // Measured: 687 MB and 27 MB (584 MB for the small one before the memory was handed back).
    assert!(
        small < 0.25 * large,
        "56 particles peaked at {small} MB after 24,432 at {large} MB"
    );
    let _ = std::fs::remove_dir_all(&out);
}
