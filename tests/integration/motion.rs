//! The motion a viewer sees (issue 27), measured from the written frames: the rms particle
//! speed of every frame from its PLY velocities, progress toward the target from its PLY
//! positions, and the measures (`morph::motion`) from those, against the manifest's
//! own figures and against the goals.

use crate::common;

use common::cli::{manifest, morph, ok, root, scratch_in};
use morph::geometry::load_mesh;
use morph::io::usd::read_points_ply;
use morph::motion::{MotionMeasures, measure};
use morph::quality::Progress;
use nalgebra::Vector3;
use std::path::Path;

fn num(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// The measures recomputed from the frames on disk of the morph in `out` (final target
/// `target`), checked against the manifest's per-frame figures on the way.
fn from_frames(out: &Path, target: &Path) -> (MotionMeasures, serde_json::Value) {
    let m = manifest(out);
    let frames = m["frames"].as_array().unwrap();
    let read =
        |f: &serde_json::Value| read_points_ply(&out.join(f["points"].as_str().unwrap())).unwrap();
    let first = read(&frames[0]);
    // The target as the run placed it, in world units, and the world particle spacing.
    let placement = &m["target"];
    let t: Vec<f64> = placement["translation"]
        .as_array()
        .unwrap()
        .iter()
        .map(num)
        .collect();
    let mesh = load_mesh(target)
        .unwrap()
        .mesh
        .transformed(num(&placement["scale"]), &Vector3::new(t[0], t[1], t[2]));
    let ppc = num(&m["settings"]["body"]["particles_per_cell"]);
    let spacing = num(&m["dx_sim"]) * num(&m["sim_to_world"]["scale"]) / ppc;
    let progress = Progress::new(&mesh, &first.x, spacing);
    let (mut speeds, mut ious) = (Vec::new(), Vec::new());
    for f in frames {
        let p = read(f);
        let n = p.v.len() as f64;
        let s = (p.v.iter().map(|v| v.norm_squared()).sum::<f64>() / n).sqrt();
        let recorded = num(&f["rms_speed"]);
        assert!(
            (s - recorded).abs() <= 1e-5 * recorded.max(1e-3),
            "frame {}: speed {s} vs {recorded}",
            f["index"]
        );
        let iou = progress.iou(&p.x);
        let recorded = num(f["progress_iou"].as_array().unwrap().last().unwrap());
        assert!(
            (iou - recorded).abs() < 0.01,
            "frame {}: progress IoU {iou} vs {recorded}",
            f["index"]
        );
        speeds.push(s);
        ious.push(iou);
    }
    // Measured from the frame the shape change begins on; segment boundaries (the frames on
    // which each segment ends) counted from there.
    let begin = m["settings"]["shot"]["begin"].as_u64().unwrap() as usize;
    let every = num(&m["settings"]["shot"]["frame_every"]);
    let steps = num(&m["settings"]["method"]["steps_per_segment"]);
    let per_segment = steps / every;
    let boundaries: Vec<usize> = (1..)
        .map(|k| 1 + (k as f64 * per_segment).round() as usize)
        .take_while(|&b| b <= frames.len())
        .filter(|&b| b >= begin)
        .map(|b| b + 1 - begin)
        .collect();
    let arrive = m["settings"]["shot"]["at"]
        .as_array()
        .unwrap()
        .last()
        .map(num)
        .unwrap() as usize;
    let measured = measure(
        &speeds[begin - 1..],
        &ious[begin - 1..],
        &boundaries,
        per_segment,
        arrive + 1 - begin,
    );
    (
        MotionMeasures {
            first_frame: begin,
            ..measured
        },
        m,
    )
}

/// The recomputed measures agree with the manifest's.
fn agree(measured: &MotionMeasures, recorded: &MotionMeasures) {
    for (name, a, b) in [
        ("pulse", measured.pulse, recorded.pulse),
        ("dip", measured.dip, recorded.dip),
        ("wobble", measured.wobble, recorded.wobble),
        ("settle", measured.settle, recorded.settle),
        (
            "ease error",
            measured.ease_error.unwrap(),
            recorded.ease_error.unwrap(),
        ),
    ] {
        assert!((a - b).abs() < 0.02, "{name}: frames {a} vs manifest {b}");
    }
    assert_eq!(measured.frozen_frames, recorded.frozen_frames);
    assert_eq!(measured.first_frame, recorded.first_frame);
}

/// Holds the measures to the goals (see GOALS).
fn within_goals(m: &MotionMeasures) {
    assert!(m.pulse <= GOALS.pulse, "{m:?}");
    assert!(m.dip <= GOALS.dip, "{m:?}");
    assert!(m.wobble <= GOALS.wobble, "{m:?}");
    assert!(m.settle <= GOALS.settle, "{m:?}");
    assert!(m.ease_error.unwrap() <= GOALS.ease, "{m:?}");
    assert!(m.frozen_frames <= 3, "{m:?}");
}

/// The README job at resolution 16 (73 frames, 12 segments) with `extra` options, run in
/// scratch folder `name` and measured from its frames.
fn small_readme_job(name: &str, extra: &[&str]) -> (MotionMeasures, serde_json::Value) {
    let out = scratch_in("morph-motion", name);
    let (s, t) = (
        root().join("assets/sphere.obj"),
        root().join("assets/two-lobes.obj"),
    );
    let mut args = vec![
        s.to_str().unwrap(),
        t.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "16",
        "--surface",
        "none",
        "--quiet",
    ];
    args.extend(extra);
    ok(&morph(&args));
    from_frames(&out, &t)
}

/// A small morph (the README job at resolution 16: 73 frames, 12 segments) measured from its
/// frames: the manifest's motion figures agree with the recomputation, and the motion stays
/// within the bounds below.
#[test]
fn motion_measured_from_the_frames_agrees_with_the_manifest_and_stays_in_bounds() {
    let (measured, m) = small_readme_job("small", &[]);
    let recorded: MotionMeasures = serde_json::from_value(m["motion"].clone()).unwrap();
    agree(&measured, &recorded);
    // The bounds (see GOALS); docs/morph.md, "Motion", has what each default morph reaches.
    within_goals(&measured);
}

/// A shot that says it begins later (`--begin 19`) holds still until then, exactly (no
/// controls act on a body at rest), and its motion from there is measured from there and
/// follows its easing curve as a shot beginning on frame 1 does.
#[test]
fn a_shot_that_begins_later_holds_still_until_then_and_eases_from_there() {
    let (measured, m) = small_readme_job("begin", &["--begin", "19"]);
    let frames = m["frames"].as_array().unwrap();
    for f in &frames[..19] {
        assert_eq!(num(&f["rms_speed"]), 0.0, "frame {} moved", f["index"]);
    }
    assert!(num(&frames[19]["rms_speed"]) > 0.0, "{}", frames[19]);
    // The three segments before frame 19 were run, not optimized.
    let evaluations: Vec<u64> = m["segments"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["evaluations"].as_u64().unwrap())
        .collect();
    assert_eq!(&evaluations[..3], &[1, 1, 1], "{evaluations:?}");
    assert!(evaluations[3..].iter().all(|&e| e > 1), "{evaluations:?}");
    let recorded: MotionMeasures = serde_json::from_value(m["motion"].clone()).unwrap();
    assert_eq!(recorded.first_frame, 19);
    assert_eq!(m["keyframes"][0]["motion"]["first_frame"], 19);
    agree(&measured, &recorded);
    // The goals, but for the ease error: a change eased over 40 frames instead of 58 runs
    // ahead of its curve mid-way on this 16-cell body (0.13.0: 0.149 / 0.088 / 0.127 beginning
    // on frames 7 / 13 / 19, where beginning on frame 1 measures 0.084). A schedule that eased
    // from frame 1 all the same measures 0.38 here.
    let ease = measured.ease_error.unwrap();
    assert!(ease <= 0.15, "{measured:?}");
    within_goals(&MotionMeasures {
        ease_error: Some(ease.min(GOALS.ease)),
        ..measured
    });
}

struct Goals {
    pulse: f64,
    dip: f64,
    wobble: f64,
    settle: f64,
    ease: f64,
}

/// What the small morph is held to: the goals (pulse 0.05, dip 0.10, wobble 0.20,
/// settle 0.05, ease error 0.08). 0.10.0's default (the shape in-between re-timed a quarter of
/// the way to its own progress) measures 0.013 / 0.004 / 0.050 / 0.006 / 0.078, 2 frozen
/// frames; 0.9.0's (the cross-fade) 0.024 / -0.002 / 0.068 / 0.006 / 0.131, and 0.2.0's method
/// failed by far (pulse 0.39, dip 0.39, wobble 0.46, settle 0.21). docs/morph.md, "Motion",
/// has what each default morph reaches. The ease error's bound has a margin of 0.01: the
/// optimizer amplifies a result's last bits, and 0.12.0's tiled scatter (which adds the same
/// terms in another order, nothing else) moved this morph's ease error from 0.078 to 0.084,
/// its other measures by less than 0.01.
const GOALS: Goals = Goals {
    pulse: 0.05,
    dip: 0.10,
    wobble: 0.20,
    settle: 0.05,
    ease: 0.09,
};

/// A keyframed morph reports the measures of each keyframe's section, and the whole run's.
#[test]
fn each_keyframe_section_has_its_motion_measures() {
    let out = scratch_in("morph-motion", "keys");
    let a = |n: &str| root().join("assets").join(n).display().to_string();
    let r = morph(&[
        &a("sphere.obj"),
        &a("cube.obj"),
        &a("two-lobes.obj"),
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "12",
        "--preset",
        "draft",
        "--surface",
        "none",
        "--quiet",
    ]);
    ok(&r);
    let m = manifest(&out);
    assert!(m["motion"]["wobble"].is_number(), "{}", m["motion"]);
    let keys = m["keyframes"].as_array().unwrap();
    assert_eq!(keys.len(), 2);
    for k in keys {
        let motion = &k["motion"];
        assert!(
            motion["pulse"].is_number() && motion["settle"].is_number(),
            "{k}"
        );
        assert!(motion["frames"].as_u64().unwrap() >= 2, "{k}");
    }
}
