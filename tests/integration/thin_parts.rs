//! Issue 64: particles where the shape needs them, and the likeness a report states.

use crate::common;
use common::cli::{Scratch, manifest, morph, scratch_in};
use std::path::Path;

fn scratch(name: &str) -> Scratch {
    scratch_in("thin_parts", name)
}

/// A table as OBJ: a slab on four legs a 27th of its length across.
fn write_table(path: &Path) {
    let boxes = [
        ([-1.6, 1.0, -0.6], [1.6, 1.3, 0.6]),
        ([-1.51, 0.0, -0.51], [-1.39, 1.0, -0.39]),
        ([-1.51, 0.0, 0.39], [-1.39, 1.0, 0.51]),
        ([1.39, 0.0, -0.51], [1.51, 1.0, -0.39]),
        ([1.39, 0.0, 0.39], [1.51, 1.0, 0.51]),
    ];
    let mut text = String::new();
    for (b, (lo, hi)) in boxes.iter().enumerate() {
        for c in 0..8 {
            let p = |a: usize| if c >> a & 1 == 1 { hi[a] } else { lo[a] };
            text += &format!("v {} {} {}\n", p(0), p(1), p(2));
        }
        // Corner c has x = bit 0, y = bit 1, z = bit 2; faces wound outward.
        for [a, b2, c2, d] in [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ] {
            let o = 8 * b + 1;
            text += &format!(
                "f {} {} {}\nf {} {} {}\n",
                a + o,
                b2 + o,
                c2 + o,
                a + o,
                c2 + o,
                d + o
            );
        }
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn a_thin_legged_target_gets_its_particles_and_the_summary_says_so() {
    let dir = scratch("table");
    std::fs::create_dir_all(&*dir).unwrap();
    let table = dir.join("table.obj");
    write_table(&table);
    let out = dir.join("out");
    let args = [
        "assets/sphere.obj",
        table.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--segments",
        "1",
        "--iterations",
        "1",
        "--frame-every",
        "10",
        "--surface",
        "none",
        "--usd",
        "none",
    ];
    let r = morph(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let printed = String::from_utf8_lossy(&r.stdout);
    let line = printed
        .lines()
        .find(|l| l.starts_with("particles: "))
        .unwrap_or_else(|| panic!("no particles line in:\n{printed}"));
    let m = manifest(&out);
    let sizing = &m["sizing"];
    assert_eq!(sizing["per_cell"], 3, "{line}");
    assert!(line.starts_with("particles: 3 per cell"), "{line}");
    assert!(line.contains("table.obj"), "{line}");
    assert_eq!(m["settings"]["body"]["particles_per_cell"], 3);
    // The count the summary names is the run's: within the estimate's few percent.
    let estimated = sizing["particles"].as_f64().unwrap();
    let particles = m["particles"].as_f64().unwrap();
    assert!(
        (particles / estimated - 1.0).abs() < 0.05,
        "{particles} vs {estimated}"
    );
    // A resolution asked for is what the run gets.
    let fixed = dir.join("fixed");
    let mut again = args.to_vec();
    again[3] = fixed.to_str().unwrap();
    again.extend(["--resolution", "16"]);
    let r = morph(&again);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let m = manifest(&fixed);
    assert!(m.get("sizing").is_none());
    assert_eq!(m["settings"]["body"]["particles_per_cell"], 2);
}

#[test]
fn the_reported_likeness_is_that_of_the_written_files() {
    let dir = scratch("liken");
    std::fs::create_dir_all(&*dir).unwrap();
    let out = dir.join("out");
    let r = morph(&[
        "assets/sphere.obj",
        "assets/two-lobes.obj",
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "16",
        "--segments",
        "2",
        "--iterations",
        "4",
        "--frame-every",
        "10",
        "--usd",
        "none",
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stdout).contains("likeness: silhouette IoU"));
    let reported = manifest(&out)["frames_summary"]["surfaces"]["likeness"].clone();
    let r = morph(&["liken", out.to_str().unwrap()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let again: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let values = |v: &serde_json::Value, key: &str| -> Vec<f64> {
        v[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    // The written OBJ rounds coordinates: a pixel's worth on the silhouettes at most.
    for (a, b) in values(&reported, "silhouette_iou")
        .iter()
        .zip(values(&again, "silhouette_iou"))
    {
        assert!((a - b).abs() < 2e-3 && *a > 0.5, "{reported} vs {again}");
    }
    for (a, b) in values(&reported, "tips").iter().zip(values(&again, "tips")) {
        assert!((a - b).abs() < 1e-4, "{reported} vs {again}");
    }
    // The carried surface is likened too, and a folder that is no morph's is refused.
    let r = morph(&["liken", out.to_str().unwrap(), "--surface", "carried"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let r = morph(&["liken", dir.to_str().unwrap()]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.starts_with("morph: error: ") && err.lines().count() == 1,
        "{err}"
    );
}
