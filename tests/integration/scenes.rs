//! Shots: keyframed targets, scene files (unknown keys, the resolved scene that reruns a
//! morph bit for bit) and the example scenes in `examples/`, each run at low resolution.

use std::path::Path;

use crate::common;
use common::cli::{Scratch, manifest, morph, ok, root, scratch_in};

fn scratch(name: &str) -> Scratch {
    scratch_in("scene-tests", name)
}

fn fill(q: &serde_json::Value) -> f64 {
    q["fill"].as_f64().unwrap()
}

/// Low resolution and effort, so a shot runs in seconds.
const QUICK: &[&str] = &["--preset", "draft", "--resolution", "16", "--quiet"];

/// Each target is there at its keyframe and not long before: halfway from the previous
/// keyframe the judge against it is lower than at its frame; the last target's fill at its
/// frame is within 10% of the final frame's. Returns each keyframe's fill.
fn check_keyframes(out: &Path, frames: &[u64]) -> Vec<f64> {
    let m = manifest(out);
    let keys = m["keyframes"].as_array().unwrap();
    assert_eq!(keys.len(), frames.len());
    let last = fill(&m["quality"]);
    let mut fills = Vec::new();
    for (k, want) in keys.iter().zip(frames) {
        assert_eq!(k["frame"].as_u64(), Some(*want));
        let (at, half) = (fill(&k["quality"]), fill(&k["halfway_quality"]));
        assert!(half < at, "keyframe {want}: halfway fill {half} vs {at}");
        fills.push(at);
    }
    let at_last = *fills.last().unwrap();
    assert!(
        at_last >= 0.9 * last,
        "last keyframe: fill {at_last} vs final {last}"
    );
    fills
}

#[test]
fn keyframes_reach_each_target_at_its_frame() {
    let out = scratch("keys");
    let o = out.to_str().unwrap();
    let mut args = vec![
        "assets/sphere.obj",
        "assets/two-lobes.obj",
        "assets/cube.obj",
        "--at",
        "25,55",
        "--frames",
        "73",
        "--no-surfaces",
        "-o",
        o,
    ];
    args.extend(QUICK);
    ok(&morph(&args));
    let fills = check_keyframes(&out, &[25, 55]);
    assert_eq!(manifest(&out)["inputs"].as_array().unwrap().len(), 3);
    // The first target is reached at its frame as well as a morph to it alone (--arrive 25)
    // reaches it there: within 10%.
    let alone = scratch("keys-alone");
    let mut args = vec![
        "assets/sphere.obj",
        "assets/two-lobes.obj",
        "--arrive",
        "25",
        "--frames",
        "73",
        "--no-surfaces",
        "-o",
        alone.to_str().unwrap(),
    ];
    args.extend(QUICK);
    ok(&morph(&args));
    let reference = fill(&manifest(&alone)["keyframes"][0]["quality"]);
    assert!(
        fills[0] >= 0.9 * reference,
        "two lobes at frame 25: {} vs {reference} alone",
        fills[0]
    );
}

/// A scene file with a key the settings do not have fails with one line that names the key,
/// the file and the line; nothing is written.
#[test]
fn a_scene_with_an_unknown_key_fails_with_one_line() {
    let dir = scratch("unknown-key");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("shot.toml");
    std::fs::write(
        &scene,
        "source = \"sphere.obj\"\ntargets = [\"cube.obj\"]\nfps = 24.0\n\n[ground]\nheight = -2.0\nfricton = 0.3\n",
    )
    .unwrap();
    let out = dir.join("out");
    let r = morph(&[
        "--scene",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("morph: error: scene file '"), "{err}");
    assert!(
        err.contains("shot.toml': line 7: unknown key `world.ground.fricton`"),
        "{err}"
    );
    assert!(!out.exists());
}

/// `morph --scene OUT/scene.toml` reruns a morph bit for bit: a scene with gravity, a ground
/// with friction, an initial velocity and a softer material, given partly on the command
/// line (which overrides the file).
#[test]
fn the_resolved_scene_reproduces_the_mass_grid_bitwise() {
    let dir = scratch("resolved");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("shot.toml");
    let assets = root().join("assets");
    std::fs::write(
        &scene,
        format!(
            "source = \"{}\"\ntargets = [\"{}\"]\nframes = 25\ngravity = [0.0, -9.81, 0.0]\ninitial_velocity = [1.0, 0.0, 0.0]\ntarget_fit = \"on-ground\"\nresolution = 24\n[ground]\nheight = -1.6\nfriction = 0.3\n[material]\nyoungs_modulus = 5.0e4\n",
            assets.join("sphere.obj").display(),
            assets.join("cube.obj").display()
        ),
    )
    .unwrap();
    let (first, second) = (dir.join("first"), dir.join("second"));
    let mut args = vec![
        "--scene",
        scene.to_str().unwrap(),
        "-o",
        first.to_str().unwrap(),
        "--no-surfaces",
    ];
    args.extend(QUICK);
    ok(&morph(&args));
    let m = manifest(&first);
    assert_eq!(
        m["settings"]["body"]["resolution"].as_u64(),
        Some(16),
        "the command line overrides"
    );
    assert_eq!(m["frames"].as_array().unwrap().len(), 25);
    let resolved = first.join("scene.toml");
    ok(&morph(&[
        "--scene",
        resolved.to_str().unwrap(),
        "-o",
        second.to_str().unwrap(),
        "--quiet",
    ]));
    let a = std::fs::read(first.join("final_mass.mgrid")).unwrap();
    let b = std::fs::read(second.join("final_mass.mgrid")).unwrap();
    assert!(a == b, "the resolved scene's run differs");
}

/// Each example in `examples/` runs at low resolution, and does what its file says.
#[test]
fn the_examples_run() {
    let examples = root().join("examples");
    let mut names: Vec<String> = std::fs::read_dir(&examples)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "fall-onto-floor.toml",
            "stiff-material.toml",
            "three-keyframes.toml"
        ]
    );
    for name in &names {
        let out = scratch(name.trim_end_matches(".toml"));
        let scene = examples.join(name);
        let mut args = vec![
            "--scene",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--no-surfaces",
        ];
        args.extend(QUICK);
        ok(&morph(&args));
        let m = manifest(&out);
        let summary = &m["frames_summary"];
        assert_eq!(summary["frames_inverted"].as_u64(), Some(0), "{name}");
        match name.as_str() {
            "three-keyframes.toml" => _ = check_keyframes(&out, &[25, 55]),
            "fall-onto-floor.toml" => {
                check_keyframes(&out, &[60]);
                // The drop and the landing are left to physics: the four segments before the
                // change begins (frame 25) run without controls, not optimized, and the body
                // moves in them.
                assert_eq!(m["settings"]["shot"]["begin"], 25);
                assert_eq!(m["motion"]["first_frame"], 25);
                let segments = m["segments"].as_array().unwrap();
                let evaluations: Vec<u64> = segments
                    .iter()
                    .map(|s| s["evaluations"].as_u64().unwrap())
                    .collect();
                assert_eq!(&evaluations[..4], &[1, 1, 1, 1], "{evaluations:?}");
                assert!(evaluations[4..].iter().all(|&e| e > 1), "{evaluations:?}");
                assert!(m["frames"][8]["rms_speed"].as_f64().unwrap() > 0.1);
                // The body lands and stays on the ground: on the last frame no particle is
                // more than a particle spacing below it, and the lowest is within two cells.
                let ground = m["settings"]["world"]["effects"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .find(|e| e["shape"]["kind"] == "plane")
                    .map(|e| e["shape"]["point"][1].as_f64().unwrap())
                    .expect("the scene's ground in the world's effects");
                let (lowest, spacing) = lowest_point(&out, &m);
                assert!(lowest > ground - spacing, "lowest {lowest}");
                assert!(
                    lowest < ground + 4.0 * spacing,
                    "lowest {lowest}: not on the ground"
                );
            }
            "stiff-material.toml" => {
                let d = &m["settings"]["body"]["material"];
                let (e, _) = morph::engine::material::young_poisson_from_lame(
                    d["mu"].as_f64().unwrap(),
                    d["lambda"].as_f64().unwrap(),
                );
                assert!((e - 1.0e6).abs() < 1.0, "E {e}");
            }
            _ => unreachable!(),
        }
    }
}

/// The lowest particle of the last frame (world y) and the particle spacing (world units).
fn lowest_point(out: &Path, m: &serde_json::Value) -> (f64, f64) {
    let frames = m["frames"].as_array().unwrap();
    let last = frames.last().unwrap()["points"].as_str().unwrap();
    let bytes = std::fs::read(out.join(last)).unwrap();
    let end = b"end_header\n";
    let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let floats: Vec<f32> = bytes[at..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let lowest = floats
        .chunks_exact(8)
        .map(|p| p[1] as f64)
        .fold(f64::INFINITY, f64::min);
    let scale = m["sim_to_world"]["scale"].as_f64().unwrap();
    let dx = m["dx_sim"].as_f64().unwrap();
    let per_cell = m["settings"]["body"]["particles_per_cell"]
        .as_f64()
        .unwrap();
    (lowest, scale * dx / per_cell)
}

/// Bad scene values fail with one line and write nothing: a value of the wrong type names its
/// key; a collider mesh that is not closed (the teapot) or is missing names the mesh.
#[test]
fn bad_scene_values_fail_with_one_line() {
    let dir = scratch("bad-values");
    std::fs::create_dir_all(&dir).unwrap();
    let assets = root().join("assets");
    let head = format!(
        "source = \"{}\"\ntargets = [\"{}\"]\npreset = \"draft\"\nresolution = 16\n",
        assets.join("sphere.obj").display(),
        assets.join("cube.obj").display()
    );
    let teapot = root().join("../shared/meshes/teapot.obj");
    for (name, body, code, says) in [
        (
            "type",
            "frames = \"many\"\n".to_string(),
            2,
            "in `shot.frames`",
        ),
        (
            "open-collider",
            format!("[[colliders]]\nmesh = \"{}\"\n", teapot.display()),
            1,
            "is not closed",
        ),
        (
            "missing-collider",
            "[[colliders]]\nmesh = \"no-such-mesh.obj\"\n".to_string(),
            1,
            "no-such-mesh.obj",
        ),
    ] {
        let scene = dir.join(format!("{name}.toml"));
        std::fs::write(&scene, format!("{head}{body}")).unwrap();
        let out = dir.join(format!("{name}-out"));
        let r = morph(&[
            "--scene",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(code), "{name}: {err}");
        assert_eq!(err.lines().count(), 1, "{name}: {err}");
        assert!(
            err.starts_with("morph: error: ") && err.contains(says),
            "{name}: {err}"
        );
        assert!(!out.exists(), "{name}: nothing is written");
        assert!(!dir.join(format!("{name}-out.partial")).exists(), "{name}");
    }
}

/// `--set KEY=VALUE` sets a knob as the scene file's key and the option of earlier versions
/// do: the same settings and the same bits; `OUT/scene.toml` holds it; a bad key or value is
/// one line, exit 2, and no folder.
#[test]
fn a_knob_set_on_the_command_line_is_the_scene_files_and_the_old_options() {
    let dir = scratch("set");
    std::fs::create_dir_all(&dir).unwrap();
    let (a, b) = (
        root().join("assets/sphere.obj"),
        root().join("assets/cube.obj"),
    );
    let run = |name: &str, extra: &[&str]| {
        let out = dir.join(name);
        let mut args = vec![
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ];
        args.extend(QUICK);
        args.extend(["--surface", "none", "--usd", "none"]);
        args.extend(extra);
        (morph(&args), out)
    };
    let (r, set) = run(
        "set",
        &[
            "--set",
            "segments=2",
            "--set",
            "iterations=2",
            "--set",
            "method.path-weight=0.5",
            "--set",
            "optimizer=line-search",
        ],
    );
    ok(&r);
    let (r, old) = run(
        "old",
        &[
            "--segments",
            "2",
            "--iterations=2",
            "--path-weight",
            "0.5",
            "--optimizer",
            "line-search",
        ],
    );
    ok(&r);
    let scene = dir.join("knobs.toml");
    std::fs::write(
        &scene,
        "segments = 2\n[method]\npath_weight = 0.5\n[method.optimizer]\nkind = \"line-search\"\niterations = 2\n",
    )
    .unwrap();
    let (r, file) = run("file", &["--scene", scene.to_str().unwrap()]);
    ok(&r);
    let settings = |out: &Path| manifest(out)["settings"].clone();
    assert_eq!(settings(&set), settings(&old));
    assert_eq!(settings(&set), settings(&file));
    let s = settings(&set);
    assert_eq!(s["method"]["optimizer"]["iterations"], 2);
    assert_eq!(s["method"]["optimizer"]["kind"], "line-search");
    assert_eq!(s["method"]["path_weight"], 0.5);
    let mgrid = |out: &Path| std::fs::read(out.join("final_mass.mgrid")).unwrap();
    assert_eq!(mgrid(&set), mgrid(&old));
    let resolved: toml::Table = std::fs::read_to_string(set.join("scene.toml"))
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(resolved["method"]["path_weight"].as_float(), Some(0.5));
    for (pair, says) in [
        ("bogus=1", "unknown key `bogus`"),
        ("iterations=x", "method.optimizer.iterations"),
    ] {
        let (r, out) = run("bad", &["--set", pair]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.starts_with("morph: error: --set") && err.contains(says),
            "{err}"
        );
        assert!(!out.exists());
    }
    let help = morph(&["help", "method"]);
    ok(&help);
    let text = String::from_utf8_lossy(&help.stdout);
    for key in [
        "path_weight",
        "optimizer.iterations",
        "lookahead",
        "rebuilt_method",
    ] {
        assert!(text.contains(key), "`morph help method` lacks {key}");
    }
}

/// `morph --help`: at most 30 options under at most 6 headings (counted in `-h`, one line an
/// option).
#[test]
fn the_help_lists_at_most_30_options_under_6_headings() {
    let r = morph(&["-h"]);
    ok(&r);
    let text = String::from_utf8_lossy(&r.stdout);
    let options = (text.lines())
        .filter(|l| l.starts_with("  -") || l.starts_with("      --"))
        .count();
    let headings: Vec<&str> = (text.lines())
        .filter(|l| l.ends_with(':') && !l.starts_with(' '))
        .filter(|l| !["Usage:", "Commands:", "Arguments:"].contains(l))
        .collect();
    assert!((20..=30).contains(&options), "{options} options");
    assert!(headings.len() <= 6, "{headings:?}");
}
