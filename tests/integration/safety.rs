//! Never lose a user's data, and say clearly what is wrong: the output folder's guards, the
//! lock, interrupt and resume, numbers at the edges of what the formats hold, one error style,
//! topology reports, and `compare` on broken grids. Each test reproduces a case found by
//! trying `morph` as a new user would, in a scratch tree with sentinel files that must
//! survive, through the real binary.

use crate::common;
mod third_probe;
use common::cli::Scratch;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh scratch folder for one test.
fn scratch(name: &str) -> Scratch {
    Scratch::folder("morph-safety", name)
}

fn asset(name: &str) -> String {
    root().join("assets").join(name).display().to_string()
}

fn command(cwd: &Path, args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_morph"));
    c.current_dir(cwd).args(args);
    c
}

fn run(cwd: &Path, args: &[&str]) -> Output {
    command(cwd, args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// One line, `morph: error: ...`, containing every needle.
fn assert_one_line_error(o: &Output, code: i32, needles: &[&str]) {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(code), "{err}");
    let errors: Vec<&str> = err
        .lines()
        .filter(|l| !l.starts_with("morph: warning"))
        .collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(errors[0].starts_with("morph: error: "), "{err}");
    for n in needles {
        assert!(errors[0].contains(n), "{n:?} not in {err}");
    }
}

/// A tiny morph: about a second on 2 cores.
const TINY: &[&str] = &[
    "--preset",
    "draft",
    "--resolution",
    "16",
    "--segments",
    "2",
    "--iterations",
    "2",
    "--quiet",
];

/// A small morph of several seconds, for interrupting: 4 segments x 2 passes.
const SMALL: &[&str] = &[
    "--preset",
    "draft",
    "--resolution",
    "20",
    "--segments",
    "4",
    "--passes",
    "2",
    "--iterations",
    "4",
    "--quiet",
];

fn morph_args<'a>(src: &'a str, tgt: &'a str, out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec![src, tgt, "-o", out];
    v.extend_from_slice(extra);
    v
}

fn sentinel(dir: &Path) -> PathBuf {
    let p = dir.join("precious.txt");
    std::fs::write(&p, "the user's work").unwrap();
    p
}

fn assert_sentinel(p: &Path) {
    assert_eq!(
        std::fs::read_to_string(p).unwrap(),
        "the user's work",
        "{}",
        p.display()
    );
}

/// Every file under `dir`, relative, sorted.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// Frames, surfaces and the mass grid of two outputs are byte for byte the same.
fn assert_same_results(a: &Path, b: &Path) {
    let pick = |d: &Path| -> Vec<PathBuf> {
        files(d)
            .into_iter()
            .filter(|p| {
                p.starts_with("frames")
                    || p.starts_with("meshes")
                    || p.ends_with("final_mass.mgrid")
            })
            .collect()
    };
    let (fa, fb) = (pick(a), pick(b));
    assert_eq!(fa, fb);
    assert!(fa.len() > 3);
    for f in fa {
        assert!(
            std::fs::read(a.join(&f)).unwrap() == std::fs::read(b.join(&f)).unwrap(),
            "{} differs",
            f.display()
        );
    }
}

/// An uninterrupted run into `NAME/ref`; returns the scratch folder `NAME` (the run stays
/// while it is held).
fn reference(name: &str, args: &[&str]) -> Scratch {
    let dir = scratch(name);
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let o = run(&dir, &morph_args(&s, &t, "ref", args));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    dir
}

/// The uninterrupted SMALL run (in `DIR/ref`) that the signal, kill and tidy-up tests compare
/// against, made once for the whole test binary, and how long it took.
fn small_reference() -> &'static (PathBuf, Duration) {
    static SMALL_REF: std::sync::OnceLock<(PathBuf, Duration)> = std::sync::OnceLock::new();
    SMALL_REF.get_or_init(|| {
        let t0 = Instant::now();
        let dir = reference("small-ref", SMALL);
        let took = t0.elapsed();
        let path = dir.to_path_buf();
        // Kept while the binary runs (the next run's scratch folder replaces it).
        std::mem::forget(dir);
        (path, took)
    })
}

/// Case 1: a trailing slash on -o replaces an earlier run in place (nothing written inside
/// it, nothing lost after the run), and makes a new folder when there is none.
#[test]
fn trailing_slash_on_output() {
    let dir = scratch("slash");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let o = run(&dir, &morph_args(&s, &t, "prev/", TINY));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(dir.join("prev/manifest.json").is_file());
    let before = std::fs::read(dir.join("prev/manifest.json")).unwrap();
    let mut args = TINY.to_vec();
    args.extend(["--overwrite", "--seed", "1", "--jitter", "0.1"]);
    let o = run(&dir, &morph_args(&s, &t, "prev/", &args));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let after = std::fs::read(dir.join("prev/manifest.json")).unwrap();
    assert_ne!(before, after, "the new run replaced the old one");
    assert!(!dir.join("prev/.partial").exists() && !dir.join("prev.partial").exists());
    assert!(
        files(&dir)
            .iter()
            .all(|f| !f.to_string_lossy().contains("replaced"))
    );
    let o = run(&dir, &morph_args(&s, &t, "fresh//", TINY));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(dir.join("fresh/frames").is_dir());
}

/// Case 2: `.`, `..`, `/`, the home folder and the working folder's parents are refused
/// before any work; nothing in them is touched.
#[test]
fn output_that_names_a_folder_in_use_is_refused() {
    let dir = scratch("dots");
    let work = dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    let keep = [sentinel(&dir), sentinel(&work)];
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let parent = dir.display().to_string();
    for out in [".", "..", "./", "../", "/", "sub/..", parent.as_str()] {
        let started = Instant::now();
        let o = run(&work, &morph_args(&s, &t, out, &["--overwrite", "--quiet"]));
        assert_one_line_error(&o, 2, &[]);
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "refused before any work"
        );
    }
    // The home folder, given as HOME.
    let o = command(&work, &morph_args(&s, &t, &parent, &["--overwrite"]))
        .env("HOME", &dir)
        .output()
        .unwrap();
    assert_one_line_error(&o, 2, &[]);
    let mut c = command(&dir, &morph_args(&s, &t, "work", &["--overwrite"]));
    let o = c.env("HOME", &work).output().unwrap();
    assert_one_line_error(&o, 2, &["home folder"]);
    for k in &keep {
        assert_sentinel(k);
    }
    assert!(!work.join("..partial").exists() && !dir.join(".partial").exists());
}

/// Case 3: an output folder that contains an input is refused, even with --overwrite and
/// even when it holds an earlier morph output.
#[test]
fn output_that_contains_an_input_is_refused() {
    let dir = scratch("inputs");
    let indir = dir.join("indir");
    std::fs::create_dir_all(&indir).unwrap();
    std::fs::copy(root().join("assets/sphere.obj"), indir.join("src.obj")).unwrap();
    std::fs::write(indir.join("manifest.json"), "{}").unwrap(); // looks like an output
    let t = asset("two-lobes.obj");
    let o = run(
        &dir,
        &morph_args("indir/src.obj", &t, "indir", &["--overwrite"]),
    );
    assert_one_line_error(&o, 2, &["contains the input", "src.obj"]);
    let o = run(
        &dir,
        &morph_args("indir/src.obj", &t, "indir/", &["--overwrite"]),
    );
    assert_one_line_error(&o, 2, &["contains the input"]);
    assert!(indir.join("src.obj").is_file());
    // A folder that is not a morph output is never replaced.
    let other = dir.join("photos");
    std::fs::create_dir_all(&other).unwrap();
    let keep = sentinel(&other);
    let s = asset("sphere.obj");
    let o = run(&dir, &morph_args(&s, &t, "photos", &["--overwrite"]));
    assert_one_line_error(&o, 2, &["not provably a morph output"]);
    assert_sentinel(&keep);
}

/// Starts a SMALL morph into `dir/out` and returns once it holds its staging folder's lock.
fn start_holding_the_lock(dir: &Path, s: &str, t: &str) -> Child {
    let child = command(dir, &morph_args(s, t, "out", SMALL))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lock = dir.join("out.partial/.lock");
    let t0 = Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|s| !s.trim().is_empty()) {
        assert!(t0.elapsed() < Duration::from_secs(30));
        std::thread::sleep(Duration::from_millis(5));
    }
    child
}

/// Case 4: a second run on the same -o fails at once naming the running process; the first
/// completes with its own, complete output.
#[test]
fn second_run_on_the_same_output_is_refused() {
    let dir = scratch("lock");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let mut first = start_holding_the_lock(&dir, &s, &t);
    let cube = asset("cube.obj");
    let started = Instant::now();
    let o = run(
        &dir,
        &morph_args(&s, &cube, "out", &["--overwrite", "--quiet"]),
    );
    assert!(started.elapsed() < Duration::from_secs(10), "fails at once");
    let pid = first.id().to_string();
    assert_one_line_error(&o, 1, &["being written by another morph run", &pid]);
    assert!(first.wait().unwrap().success());
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("out/manifest.json")).unwrap()).unwrap();
    assert!(
        m["inputs"][1]["path"]
            .as_str()
            .unwrap()
            .ends_with("two-lobes.obj")
    );
    let frames = m["frames"].as_array().unwrap();
    for f in frames {
        assert!(
            dir.join("out")
                .join(f["points"].as_str().unwrap())
                .is_file()
        );
    }
    assert_eq!(
        files(&dir.join("out/frames")).len(),
        frames.len(),
        "only this run's frames"
    );
}

fn wait_for_checkpoint(dir: &Path, child: &mut Child) {
    let progress = dir.join("out.partial/checkpoint/progress.json");
    let t0 = Instant::now();
    while !progress.is_file() {
        assert!(child.try_wait().unwrap().is_none(), "finished too early");
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Sends `signal` ("INT", "TERM") to a running morph.
fn send(child: &Child, signal: &str) {
    let sent = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
}

/// Starts a SMALL morph into `dir/out`, sends `signal` once its first checkpoint is written,
/// and returns what the process printed and its exit status.
fn interrupted_after_checkpoint(dir: &Path, signal: &str) -> Output {
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let mut child = command(dir, &morph_args(&s, &t, "out", SMALL))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(dir, &mut child);
    send(&child, signal);
    child.wait_with_output().unwrap()
}

/// Case 5: SIGINT and SIGTERM stop cleanly: one line, exit 130 / 143, the checkpoint kept;
/// --resume then finishes with results identical to an uninterrupted run.
#[test]
fn sigint_and_sigterm_stop_cleanly_and_resume() {
    let reference = &small_reference().0;
    for (signal, code) in [("INT", 130), ("TERM", 143)] {
        let dir = scratch(&format!("sig{signal}"));
        let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
        let o = interrupted_after_checkpoint(&dir, signal);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(code), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.contains(&format!("interrupted by SIG{signal}")),
            "{err}"
        );
        assert!(err.contains("--resume"), "{err}");
        assert!(!dir.join("out").exists());
        assert!(dir.join("out.partial/checkpoint/progress.json").is_file());
        // Without --resume the interrupted run is not thrown away.
        let o = run(&dir, &morph_args(&s, &t, "out", SMALL));
        assert_one_line_error(&o, 2, &["--resume"]);
        // Other settings cannot continue it.
        let mut other = SMALL.to_vec();
        other.extend(["--resume", "--seed", "3", "--jitter", "0.2"]);
        let o = run(&dir, &morph_args(&s, &t, "out", &other));
        assert_one_line_error(&o, 1, &["cannot resume", "jitter"]);
        let mut args = SMALL.to_vec();
        args.push("--resume");
        let o = run(&dir, &morph_args(&s, &t, "out", &args));
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert!(!dir.join("out.partial").exists());
        assert!(!dir.join("out/checkpoint").exists());
        assert_same_results(&reference.join("ref"), &dir.join("out"));
        // A finished output resumed again is left as it is.
        let o = run(&dir, &morph_args(&s, &t, "out", &args));
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert_same_results(&reference.join("ref"), &dir.join("out"));
    }
}

/// Case 5: an interruption before any segment completed keeps nothing and says so; either
/// way, what the message says is what is on disk.
#[test]
fn early_sigint_keeps_nothing_and_says_so() {
    let dir = scratch("early-int");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let child = start_holding_the_lock(&dir, &s, &t);
    send(&child, "INT");
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    if err.contains("nothing was kept") {
        assert!(!dir.join("out.partial").exists());
        // A plain re-run is not blocked by leftovers.
        let o = run(&dir, &morph_args(&s, &t, "out", TINY));
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    } else {
        assert!(err.contains("--resume"), "{err}");
        assert!(dir.join("out.partial/checkpoint/progress.json").is_file());
    }
}

/// A farm's "continue if you can, else start over": `--resume --overwrite` with other
/// settings starts afresh instead of refusing, and the result is the new run's.
#[test]
fn resume_with_overwrite_starts_over_when_it_cannot_continue() {
    let dir = scratch("resume-overwrite");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    assert_eq!(
        interrupted_after_checkpoint(&dir, "INT").status.code(),
        Some(130)
    );
    let mut other = TINY.to_vec();
    other.extend(["--resume", "--overwrite", "--seed", "3", "--jitter", "0.2"]);
    let o = run(&dir, &morph_args(&s, &t, "out", &other));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("out/manifest.json")).unwrap()).unwrap();
    assert_eq!(m["settings"]["body"]["jitter"], 0.2);
    assert!(!dir.join("out.partial").exists());
}

/// Case 5 (farm): SIGKILL at a random point, then --resume: frames, surfaces and the mass
/// grid are byte for byte those of an uninterrupted run.
#[test]
fn sigkill_at_a_random_point_then_resume_is_bitwise_identical() {
    // The reference run's own length sets the range of kill times.
    let (reference, full) = small_reference();
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos() as u64;
    for round in 0..3u64 {
        let fraction =
            ((seed.wrapping_mul(2654435761).wrapping_add(round * 977)) % 900) as f64 / 1000.0;
        let at = full.mul_f64(0.05 + fraction);
        let dir = scratch(&format!("kill{round}"));
        let mut child = command(&dir, &morph_args(&s, &t, "out", SMALL))
            .spawn()
            .unwrap();
        std::thread::sleep(at);
        let _ = child.kill(); // SIGKILL
        let _ = child.wait();
        eprintln!(
            "killed after {:.2} s of {:.2} s: checkpoint {}",
            at.as_secs_f64(),
            full.as_secs_f64(),
            dir.join("out.partial/checkpoint/progress.json").is_file()
        );
        let mut args = SMALL.to_vec();
        args.push("--resume");
        let o = run(&dir, &morph_args(&s, &t, "out", &args));
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert_same_results(&reference.join("ref"), &dir.join("out"));
        assert!(!dir.join("out.partial").exists());
    }
}

/// Case 6: -o naming an existing file is refused at once, with or without --overwrite, and
/// nothing is written.
#[test]
fn output_naming_a_file_is_refused_before_the_run() {
    let dir = scratch("file");
    let keep = sentinel(&dir);
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    for extra in [&[][..], &["--overwrite"][..]] {
        let started = Instant::now();
        let o = run(&dir, &morph_args(&s, &t, "precious.txt", extra));
        assert_one_line_error(&o, 2, &["not a folder"]);
        assert!(started.elapsed() < Duration::from_secs(5));
    }
    assert_sentinel(&keep);
    assert_eq!(files(&dir), vec![PathBuf::from("precious.txt")]);
}

/// `morph assets` does not replace a user's file of the same name unless asked.
#[test]
fn assets_do_not_replace_files_unasked() {
    let dir = scratch("assets");
    std::fs::write(dir.join("sphere.obj"), "the user's work").unwrap();
    let o = run(&dir, &["assets", "-o", "."]);
    assert_one_line_error(&o, 1, &["sphere.obj", "--overwrite"]);
    assert_sentinel(&dir.join("sphere.obj"));
    assert_eq!(files(&dir).len(), 1, "nothing half-written");
    let o = run(&dir, &["assets", "-o", ".", "--overwrite"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(files(&dir).len(), 4);
}

/// Writes `assets/sphere.obj` scaled by `scale` about the origin.
fn scaled_sphere(dir: &Path, name: &str, scale: f64) -> String {
    let text = std::fs::read_to_string(root().join("assets/sphere.obj")).unwrap();
    let out: Vec<String> = text
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(rest) => {
                let c: Vec<f64> = rest
                    .split_whitespace()
                    .map(|x| x.parse().unwrap())
                    .collect();
                format!("v {:e} {:e} {:e}", c[0] * scale, c[1] * scale, c[2] * scale)
            }
            None => l.to_string(),
        })
        .collect();
    let p = dir.join(name);
    std::fs::write(&p, out.join("\n")).unwrap();
    p.display().to_string()
}

/// Cases 7 and 8: a source the float32 frames cannot hold is refused before the run, naming
/// it; extreme targets are fine (they are rescaled in f64); inspect agrees with the run.
#[test]
fn extreme_units_are_refused_or_handled_and_the_right_mesh_is_named() {
    let dir = scratch("units");
    let t = asset("two-lobes.obj");
    for (scale, name, needle) in [
        (
            1e39,
            "big39.obj",
            "beyond what the 32-bit float frames can hold",
        ),
        (
            1e-45,
            "tiny45.obj",
            "below what 32-bit float frames resolve",
        ),
        (
            1e300,
            "big300.obj",
            "beyond what the 32-bit float frames can hold",
        ),
        (
            1e-300,
            "tiny300.obj",
            "below what 32-bit float frames resolve",
        ),
    ] {
        let mesh = scaled_sphere(&dir, name, scale);
        let o = run(&dir, &morph_args(&mesh, &t, "out", TINY));
        assert_one_line_error(&o, 1, &[name, needle]);
        assert!(!stderr(&o).contains("--resolution") && !stderr(&o).contains("two-lobes"));
        assert!(!dir.join("out").exists() && !dir.join("out.partial").exists());
        // inspect: exit 0, a plain report, and the same verdict as a warning.
        let o = run(&dir, &["inspect", &mesh]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert!(report["particles"].as_u64().unwrap() > 1000, "{report}");
        assert!(stderr(&o).contains(needle), "{}", stderr(&o));
        if !(1e-100..=1e100).contains(&scale) {
            assert!(report["volume"].is_null());
            assert!(stderr(&o).contains("beyond 64-bit floats"));
        }
    }
    // As a target, an extreme mesh is scaled to the source's volume in f64: it just works,
    // and every written value is finite.
    let s = asset("sphere.obj");
    let big = scaled_sphere(&dir, "target300.obj", 1e300);
    let o = run(&dir, &morph_args(&s, &big, "ok", TINY));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("ok/manifest.json")).unwrap()).unwrap();
    assert!(m["target"]["scale"].as_f64().unwrap() > 0.0);
    let obj = std::fs::read_to_string(dir.join("ok/meshes/frame_0001.obj")).unwrap();
    assert!(!obj.contains("inf") && !obj.contains("NaN"));
}

/// Case 9: one error style everywhere: parse errors are one line, every bad option exits 2
/// in every subcommand, --json ends with an error event, --help shows ranges and defaults.
#[test]
fn one_error_style() {
    let dir = scratch("style");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let bad: Vec<Vec<&str>> = vec![
        vec!["inspect", &s, "--resolution", "0"],
        vec!["inspect", &s, "--resolution", "many"],
        vec![&s, &t, "--resolution", "0"],
        vec![&s, &t, "--bogus"],
        vec![&s],
        vec![&s, &t, "--preset", "huge"],
        vec!["compare", "a.mgrid", "b.mgrid", "--rtol", "-1"],
        vec!["bench", "--steps", "0"],
        vec!["bench", "stages", "--repeats", "0"],
        vec!["bench-geometry", "--resolutions", "4"],
        vec!["rope", "--steps", "-5"],
        vec!["assets", "--nope"],
        vec!["--threads", "0", &s, &t],
    ];
    for args in &bad {
        let o = run(&dir, args);
        assert_one_line_error(&o, 2, &[]);
    }
    // --json: the stream ends with an error event.
    for args in [
        vec![s.as_str(), &t, "--json", "--resolution", "0"],
        vec![s.as_str(), &t, "--json", "--no-such-option"],
        vec![s.as_str(), "missing.obj", "--json", "-o", "x"],
    ] {
        let o = run(&dir, &args);
        let out = String::from_utf8_lossy(&o.stdout);
        let last: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
        assert_eq!(last["event"], "error", "{out}");
        assert_eq!(last["exit_code"].as_i64(), o.status.code().map(i64::from));
        assert!(last["message"].as_str().unwrap().len() > 5);
    }
    let help = String::from_utf8(run(&dir, &["--help"]).stdout).unwrap();
    for needle in ["range 8-256", "default 32", "130", "143", "--resume"] {
        assert!(help.contains(needle), "{needle}");
    }
    let help = String::from_utf8(run(&dir, &["inspect", "--help"]).stdout).unwrap();
    assert!(help.contains("range 8-256"));
}

fn write_obj(path: &Path, vertices: &[[f64; 3]], faces: &[[usize; 3]]) {
    let mut s = String::new();
    for v in vertices {
        s += &format!("v {} {} {}\n", v[0], v[1], v[2]);
    }
    for f in faces {
        s += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}

fn cube(o: [f64; 3]) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let v = (0..8)
        .map(|i| {
            [
                o[0] + (i >> 2 & 1) as f64,
                o[1] + (i >> 1 & 1) as f64,
                o[2] + (i & 1) as f64,
            ]
        })
        .collect();
    let f = vec![
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],
    ];
    (v, f)
}

fn inspect(dir: &Path, mesh: &Path) -> (serde_json::Value, String) {
    let o = run(dir, &["inspect", &mesh.display().to_string()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    (serde_json::from_slice(&o.stdout).unwrap(), stderr(&o))
}

/// A unit cube at the origin and another at `second`, as one OBJ.
fn write_two_cubes(path: &Path, second: [f64; 3]) {
    let (mut v, mut f) = cube([0.0; 3]);
    let (v2, f2) = cube(second);
    f.extend(f2.iter().map(|t| t.map(|i| i + 8)));
    v.extend(v2);
    write_obj(path, &v, &f);
}

/// Case 10: multi-part meshes report each part's genus (never -1), four faces on one edge
/// give a warning, an unwelded closed mesh is welded and reported closed.
#[test]
fn topology_reports() {
    let dir = scratch("topology");
    // Two separate cubes.
    let two = dir.join("two.obj");
    write_two_cubes(&two, [3.0, 0.0, 0.0]);
    let (r, err) = inspect(&dir, &two);
    assert!(r["genus"].is_null() && r["closed"] == true, "{r}");
    let parts = r["parts"].as_array().unwrap();
    assert_eq!(parts.len(), 2);
    for p in parts {
        assert_eq!(p["genus"], 0);
        assert_eq!(p["euler_characteristic"], 2);
    }
    assert!(!err.contains("warning"), "{err}");
    // Two cubes sharing one edge: four faces on it.
    let bowtie = dir.join("bowtie.obj");
    write_two_cubes(&bowtie, [1.0, 1.0, 0.0]);
    let (r, err) = inspect(&dir, &bowtie);
    assert_eq!(r["non_manifold_edges"], 1, "{r}");
    assert!(err.contains("1 non-manifold edges"), "{err}");
    // The same cube with every face carrying its own three corners.
    let (v, f) = cube([0.0; 3]);
    let mut uv = Vec::new();
    let mut uf = Vec::new();
    for t in &f {
        uf.push([uv.len(), uv.len() + 1, uv.len() + 2]);
        uv.extend(t.map(|i| v[i]));
    }
    let unwelded = dir.join("unwelded.obj");
    write_obj(&unwelded, &uv, &uf);
    let (r, err) = inspect(&dir, &unwelded);
    assert_eq!(r["closed"], true, "{r}");
    assert_eq!(r["genus"], 0);
    assert_eq!(r["welded_vertices"], 36 - 8);
    assert!(!err.contains("open"), "{err}");
}

/// Case 11: compare names the node of a non-finite value; frame names sort past 9999.
#[test]
fn compare_reports_non_finite_and_frame_names_sort() {
    use morph::io::massgrid::MassGrid;
    let dir = scratch("compare");
    let values: Vec<f64> = (0..24).map(|i| i as f64).collect();
    let good = MassGrid::new([2, 3, 4], [0.0; 3], 1.0, values.clone());
    good.write(&dir.join("good.mgrid")).unwrap();
    // A grid with NaN at node (1, 2, 3) = index 23, written by hand (the writer refuses it).
    let mut bytes = std::fs::read(dir.join("good.mgrid")).unwrap();
    let n = bytes.len();
    bytes[n - 8..].copy_from_slice(&f64::NAN.to_le_bytes());
    std::fs::write(dir.join("nan.mgrid"), &bytes).unwrap();
    assert!(
        MassGrid::new([2, 3, 4], [0.0; 3], 1.0, vec![f64::NAN; 24])
            .write(&dir.join("refused.mgrid"))
            .is_err()
    );
    let o = run(&dir, &["compare", "nan.mgrid", "good.mgrid"]);
    assert_eq!(o.status.code(), Some(1));
    let c: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(c["within_tolerance"], false);
    assert_eq!(c["non_finite"]["node"], serde_json::json!([1, 2, 3]));
    assert_eq!(c["non_finite"]["a"], "NaN");
    assert!(stderr(&o).contains("[1, 2, 3]"));

    // 10,001 frames: names padded to 5 digits, so they sort in frame order.
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let args = [
        "--resolution",
        "8",
        "--particles-per-cell",
        "1",
        "--segments",
        "1",
        "--steps",
        "10000",
        "--control-stride",
        "10000",
        "--iterations",
        "1",
        "--frame-every",
        "1",
        "--no-surfaces",
        "--quiet",
    ];
    let o = run(&dir, &morph_args(&s, &t, "long", &args));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let names: Vec<String> = files(&dir.join("long/frames"))
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    assert_eq!(names.len(), 10_001);
    assert_eq!(names[0], "frame_00001.ply");
    assert_eq!(names[9_999], "frame_10000.ply");
    assert_eq!(names[10_000], "frame_10001.ply");
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("long/manifest.json")).unwrap()).unwrap();
    let listed: Vec<&str> = m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["points"].as_str().unwrap())
        .collect();
    let mut sorted = listed.clone();
    sorted.sort();
    assert_eq!(listed, sorted);
}

/// Sphere -> two-lobes with `shot` into `NAME/out`, interrupted by SIGINT after its first
/// checkpoint and resumed: asserts the results are bitwise an uninterrupted run's, and
/// returns the manifest.
fn interrupt_resume_and_compare(name: &str, shot: &[&str]) -> serde_json::Value {
    let reference = reference(&format!("{name}-ref"), shot);
    let dir = scratch(name);
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let mut child = command(&dir, &morph_args(&s, &t, "out", shot))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(&dir, &mut child);
    send(&child, "INT");
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    let mut args = shot.to_vec();
    args.push("--resume");
    let o = run(&dir, &morph_args(&s, &t, "out", &args));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_same_results(&reference.join("ref"), &dir.join("out"));
    serde_json::from_slice(&std::fs::read(dir.join("out/manifest.json")).unwrap()).unwrap()
}

/// `--frames` with a last segment shorter than the others (and with fewer control layers):
/// interrupted after a checkpoint, `--resume` finishes bitwise like an uninterrupted run.
#[test]
fn resume_with_a_shorter_last_segment_is_bitwise_identical() {
    // 41 frames, a frame every 3 steps: 120 steps = 4 segments of 28 and one of 8 (1 layer).
    const SHOT: &[&str] = &[
        "--preset",
        "draft",
        "--resolution",
        "16",
        "--frames",
        "41",
        "--frame-every",
        "3",
        "--steps",
        "28",
        "--passes",
        "2",
        "--iterations",
        "4",
        "--quiet",
    ];
    let m = interrupt_resume_and_compare("short-last", SHOT);
    assert_eq!(m["frames"].as_array().unwrap().len(), 41);
    assert_eq!(m["settings"]["method"]["segments"].as_u64(), Some(5));
}

/// A look-ahead (`--lookahead 1`): each checkpoint holds the controls the window left for
/// the next segment, so a resumed run starts that segment where the uninterrupted one did
/// and finishes bitwise like it (two passes, and a last segment shorter than the others,
/// which no window reaches past). The controls' continuity is on too: a resumed segment's
/// first layer is held to the last layer kept before it, which the checkpoint must give back,
/// and a window's new segment starts from half that layer (`--carry-controls`).
#[test]
fn resume_with_lookahead_is_bitwise_identical() {
    const SHOT: &[&str] = &[
        "--preset",
        "draft",
        "--resolution",
        "16",
        "--frames",
        "41",
        "--frame-every",
        "3",
        "--steps",
        "30",
        "--passes",
        "2",
        "--iterations",
        "4",
        "--lookahead",
        "1",
        "--control-smoothing",
        "30000",
        "--waypoint-weight",
        "0.1",
        "--carry-controls",
        "0.5",
        "--quiet",
    ];
    let m = interrupt_resume_and_compare("lookahead-resume", SHOT);
    assert_eq!(m["settings"]["method"]["lookahead"].as_u64(), Some(1));
    assert_eq!(m["frames"].as_array().unwrap().len(), 41);
    // One pass: interrupted in the last pass, where a finished segment's controls are kept
    // only as long as the next segment's continuity needs them.
    let one_pass: Vec<&str> = SHOT
        .iter()
        .map(|a| if *a == "2" { "1" } else { *a })
        .collect();
    let m = interrupt_resume_and_compare("lookahead-resume-one-pass", &one_pass);
    assert_eq!(m["settings"]["method"]["passes"].as_u64(), Some(1));
}

/// Coarse-to-fine (`--levels 2`): interrupted after a checkpoint of the finest level, the
/// resumed run solves the coarse level again and finishes bitwise like an uninterrupted run.
#[test]
fn resume_with_levels_is_bitwise_identical() {
    const SHOT: &[&str] = &[
        "--preset",
        "draft",
        "--resolution",
        "20",
        "--levels",
        "2",
        "--frames",
        "25",
        "--iterations",
        "4",
        "--quiet",
    ];
    let m = interrupt_resume_and_compare("levels-resume", SHOT);
    assert_eq!(m["levels"].as_array().unwrap().len(), 1);
    assert_eq!(m["segments"].as_array().unwrap().len(), 4);
}

// ---------------------------------------------------------------------------------------
// Never lose data, part two: one test per case found by the second round of hostile use.
// ---------------------------------------------------------------------------------------

/// A TINY morph of the built-in sphere into the cube, into `dir/out`.
fn tiny_output(dir: &Path, out: &str) -> PathBuf {
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let o = run(dir, &morph_args(&s, &t, out, TINY));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    dir.join(out)
}

/// Case 1: --overwrite replaces only a folder that morph provably made: a manifest that is
/// morph's and nothing in the folder it does not list. A `{}` manifest beside a thesis, a
/// morph output with a file added, and a rope folder with a bare report.json are refused with
/// the first foreign file named, and nothing is deleted.
#[test]
fn overwrite_replaces_only_a_folder_morph_provably_made() {
    let dir = scratch("provably-ours");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    std::fs::create_dir_all(dir.join("p")).unwrap();
    let thesis = sentinel(&dir.join("p"));
    std::fs::write(dir.join("p/manifest.json"), "{}").unwrap();
    let mut args = morph_args(&s, &t, "p", TINY);
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert_one_line_error(
        &o,
        2,
        &["'p' is not provably a morph output", "manifest.json"],
    );
    assert_sentinel(&thesis);

    let out = tiny_output(&dir, "out");
    let added = out.join("frames/notes.txt");
    std::fs::write(&added, "the user's work").unwrap();
    let mut args = morph_args(&s, &t, "out", TINY);
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert_one_line_error(&o, 2, &["'frames/notes.txt'", "does not list"]);
    assert_sentinel(&added);
    // Without the foreign file the same command replaces it.
    std::fs::remove_file(&added).unwrap();
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));

    // The rope's folder: a report.json that is not one morph wrote.
    std::fs::create_dir_all(dir.join("rope")).unwrap();
    let kept = sentinel(&dir.join("rope"));
    std::fs::write(dir.join("rope/report.json"), "{}").unwrap();
    let o = run(&dir, &["rope", "-o", "rope", "--overwrite"]);
    assert_one_line_error(&o, 2, &["not provably a morph output"]);
    assert_sentinel(&kept);
}

/// Copies the built-in sphere and two lobes into `dir` (inputs a test may damage).
fn local_inputs(dir: &Path) -> (String, String) {
    for name in ["sphere.obj", "two-lobes.obj"] {
        std::fs::copy(root().join("assets").join(name), dir.join(name)).unwrap();
    }
    ("sphere.obj".into(), "two-lobes.obj".into())
}

/// Runs morph with `args` in `dir` (writing `dir/out`), sends `signal` once its first
/// checkpoint is written, and returns what it printed.
fn stop_after_checkpoint(dir: &Path, args: &[&str], signal: &str) -> Output {
    let mut child = command(dir, args).stderr(Stdio::piped()).spawn().unwrap();
    wait_for_checkpoint(dir, &mut child);
    send(&child, signal);
    child.wait_with_output().unwrap()
}

/// Starts a SMALL morph of `s` into `t` in `dir/out` and stops it with SIGINT once its first
/// checkpoint is written.
fn interrupt_small(dir: &Path, s: &str, t: &str) {
    let o = stop_after_checkpoint(dir, &morph_args(s, t, "out", SMALL), "INT");
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
}

/// A SMALL morph of local copies of the inputs interrupted in `dir/out` after its first
/// checkpoint: the source, the target, the checkpoint folder and its state file's name.
fn interrupted_with_checkpoint(dir: &Path) -> (String, String, PathBuf, PathBuf) {
    let (s, t) = local_inputs(dir);
    interrupt_small(dir, &s, &t);
    let ck = dir.join("out.partial/checkpoint");
    let state = files(&ck)
        .into_iter()
        .find(|f| f.to_string_lossy().starts_with("state_"))
        .unwrap();
    (s, t, ck, state)
}

/// Case 2: --overwrite (and the farm's --resume --overwrite) clears an interrupted run only
/// once the new inputs have loaded: a source truncated by a sync in progress fails the run
/// and the checkpoint is still there, byte for byte; the repaired source then resumes.
#[test]
fn overwrite_keeps_an_interrupted_run_until_the_inputs_load() {
    let dir = scratch("keep-partial");
    let (s, t) = local_inputs(&dir);
    interrupt_small(&dir, &s, &t);
    let ck = dir.join("out.partial/checkpoint");
    let before = files(&ck);
    let progress = std::fs::read(ck.join("progress.json")).unwrap();
    let whole = std::fs::read(dir.join(&s)).unwrap();
    std::fs::write(dir.join(&s), "").unwrap();
    for flags in [&["--resume", "--overwrite"][..], &["--overwrite"][..]] {
        let mut args = morph_args(&s, &t, "out", SMALL);
        args.extend_from_slice(flags);
        let o = run(&dir, &args);
        assert_one_line_error(&o, 1, &["sphere.obj"]);
        assert_eq!(files(&ck), before, "{flags:?}");
        assert_eq!(std::fs::read(ck.join("progress.json")).unwrap(), progress);
    }
    std::fs::write(dir.join(&s), whole).unwrap();
    let mut args = morph_args(&s, &t, "out", SMALL);
    args.push("--resume");
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).is_empty() || o.stdout.is_empty());
}

/// Case 3: a scene file is an input like the meshes: one kept inside the output folder makes
/// --overwrite refuse, and it survives.
#[test]
fn a_scene_file_inside_the_output_is_protected() {
    let dir = scratch("scene-inside");
    let out = tiny_output(&dir, "out");
    let scene = out.join("shot.toml");
    std::fs::write(
        &scene,
        format!(
            "source = \"{}\"\ntargets = [\"{}\"]\nresolution = 16\nsegments = 2\n",
            asset("sphere.obj"),
            asset("cube.obj")
        ),
    )
    .unwrap();
    let text = std::fs::read_to_string(&scene).unwrap();
    let o = run(
        &dir,
        &[
            "--scene",
            "out/shot.toml",
            "-o",
            "out",
            "--overwrite",
            "--quiet",
        ],
    );
    assert_one_line_error(&o, 2, &["contains the input", "shot.toml"]);
    assert_eq!(std::fs::read_to_string(&scene).unwrap(), text);
}

/// Case 4: -o naming a mount point is refused before any work, saying why and what to give
/// instead; nothing is written beside it. With a real empty tmpfs when this machine lets a
/// test mount one (a user namespace), and always on /proc.
#[test]
fn output_on_a_mount_point_is_refused_before_any_work() {
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let dir = scratch("mount");
    let o = run(&dir, &morph_args(&s, &t, "/proc", TINY));
    assert_one_line_error(&o, 2, &["'/proc' is a mount point", "-o /proc/morph-out"]);
    assert!(!Path::new("/proc.partial").exists());
    let mnt = dir.join("volume");
    std::fs::create_dir_all(&mnt).unwrap();
    let script = format!(
        "mount -t tmpfs none '{m}' && exec '{bin}' '{s}' '{t}' -o '{m}' --preset draft --resolution 16 --segments 2 --iterations 2 --quiet",
        m = mnt.display(),
        bin = env!("CARGO_BIN_EXE_morph"),
    );
    match Command::new("unshare")
        .args(["-Urm", "sh", "-c", &script])
        .output()
    {
        Ok(o)
            if !String::from_utf8_lossy(&o.stderr).contains("unshare:")
                && !String::from_utf8_lossy(&o.stderr).contains("mount:") =>
        {
            assert_one_line_error(&o, 2, &["is a mount point", "give a folder inside it"]);
            assert!(
                !dir.join("volume.partial").exists(),
                "nothing written beside it"
            );
        }
        _ => eprintln!("no user namespaces here: the empty tmpfs case is skipped (/proc checked)"),
    }
}

/// Runs `args` in `dir`, killing it after 20 s (a blocked read would otherwise hang).
fn run_bounded(dir: &Path, args: &[&str]) -> Output {
    let mut child = command(dir, args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            panic!("morph {args:?} did not finish in 20 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Case 5: every read has a bound: a device, a link to one, a FIFO and a checkpoint file
/// replaced by a link to /dev/zero are refused at once with one line, never read forever.
#[test]
fn reads_are_bounded_devices_and_fifos_refused() {
    let dir = scratch("bounded-reads");
    let o = run_bounded(&dir, &["inspect", "/dev/zero"]);
    assert_one_line_error(&o, 1, &["/dev/zero", "a device, not a regular file"]);
    std::os::unix::fs::symlink("/dev/zero", dir.join("zero.obj")).unwrap();
    let o = run_bounded(&dir, &["inspect", "zero.obj"]);
    assert_one_line_error(&o, 1, &["zero.obj", "a device"]);
    let fifo = dir.join("pipe.obj");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a plain libc call on a valid C string.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let o = run_bounded(&dir, &["inspect", "pipe.obj"]);
    assert_one_line_error(&o, 1, &["pipe.obj", "a FIFO"]);
    let o = run_bounded(&dir, &morph_args("pipe.obj", &asset("cube.obj"), "o", TINY));
    assert_one_line_error(&o, 1, &["pipe.obj", "a FIFO"]);
    let out = tiny_output(&dir, "grid");
    let mgrid = out.join("final_mass.mgrid");
    let o = run_bounded(&dir, &["compare", mgrid.to_str().unwrap(), "/dev/zero"]);
    assert_one_line_error(&o, 2, &["/dev/zero", "a device"]);

    // A checkpoint file replaced by a link to /dev/zero.
    let (s, t, ck, state) = interrupted_with_checkpoint(&dir);
    std::fs::remove_file(ck.join(&state)).unwrap();
    std::os::unix::fs::symlink("/dev/zero", ck.join(&state)).unwrap();
    let mut args = morph_args(&s, &t, "out", SMALL);
    args.push("--resume");
    let o = run_bounded(&dir, &args);
    assert_one_line_error(&o, 1, &[&state.to_string_lossy(), "a device"]);
}

/// Case 6: frame counts are checked before anything is sized by them: 2^64 - 1, 2^32 + 1
/// and 10^9 frames, on the command line or in a scene, are refused at once, in one line.
#[test]
fn huge_frame_counts_are_refused_before_allocation() {
    let dir = scratch("frames-limit");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    for n in ["18446744073709551615", "4294967297", "1000000000"] {
        let mut args = morph_args(&s, &t, "o", &["--preset", "draft", "--quiet"]);
        args.extend(["--frames", n]);
        let t0 = Instant::now();
        let o = run_bounded(&dir, &args);
        assert_one_line_error(&o, 2, &["--frames must be between 2 and 100000"]);
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "{n}: {:?}",
            t0.elapsed()
        );
    }
    std::fs::write(
        dir.join("shot.toml"),
        format!("source = \"{s}\"\ntargets = [\"{t}\"]\nframes = 4294967297\n"),
    )
    .unwrap();
    let o = run_bounded(&dir, &["--scene", "shot.toml", "-o", "o", "--quiet"]);
    assert_one_line_error(&o, 2, &["frames must be between 2 and 100000"]);
    assert!(!dir.join("o").exists() && !dir.join("o.partial").exists());
}

/// Case 7: the rope's counts have an upper bound, refused before the run.
#[test]
fn rope_counts_have_an_upper_bound() {
    let dir = scratch("rope-limits");
    for (flag, value) in [("--steps", "1000000000"), ("--samples", "1000000000")] {
        let o = run_bounded(&dir, &["rope", "-o", "r", flag, value]);
        assert_one_line_error(&o, 2, &[flag, "must be at most 100000"]);
    }
    assert!(!dir.join("r").exists());
}

/// Case 8: the memory plan: a limit above the machine's memory is refused; a limit far below
/// what a fine grid needs is refused before setup, at once; the verdict on a limit is the
/// same on every run (it is computed from the inputs, not the resident size).
#[test]
fn memory_plan_is_deterministic_and_checked_before_setup() {
    let dir = scratch("memory-plan");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let mut args = morph_args(&s, &t, "o", TINY);
    args.extend(["--memory-limit", "1T"]);
    let o = run_bounded(&dir, &args);
    assert_one_line_error(&o, 2, &["--memory-limit 1024.0 GB is more than the"]);
    let mut args = morph_args(&s, &t, "o", &[]);
    args.extend(["--resolution", "256", "--memory-limit", "1G", "--quiet"]);
    let t0 = Instant::now();
    let o = run_bounded(&dir, &args);
    assert_one_line_error(&o, 2, &["this morph needs at least"]);
    assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());
    // A limit near what the morph needs: three runs, one verdict, word for word.
    let mut verdicts = Vec::new();
    for _ in 0..3 {
        let mut args = morph_args(&s, &t, "near", TINY);
        args.extend(["--memory-limit", "40M"]);
        let o = run(&dir, &args);
        verdicts.push((o.status.code(), stderr(&o)));
        let _ = std::fs::remove_dir_all(dir.join("near"));
    }
    assert!(verdicts.iter().all(|v| v == &verdicts[0]), "{verdicts:?}");
}

/// Case 9: more threads than cores run on the cores, with a warning (1000 workers on 2 cores
/// made a 4 s run take 269 s); the result is the same.
#[test]
fn threads_beyond_the_cores_are_lowered_with_a_warning() {
    let dir = scratch("threads");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    // Without --quiet, which holds every warning back (third_probe.rs).
    let mut args = morph_args(&s, &t, "many", &TINY[..TINY.len() - 1]);
    args.extend(["--threads", "1000"]);
    let o = run_bounded(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--threads 1000 is more than this machine's"),
        "{}",
        stderr(&o)
    );
    let one = tiny_output(&dir, "one");
    assert_eq!(
        std::fs::read(one.join("final_mass.mgrid")).unwrap(),
        std::fs::read(dir.join("many/final_mass.mgrid")).unwrap()
    );
}

/// The particles a run's setup event reports.
fn particles_of(dir: &Path, extra: &[&str]) -> usize {
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let _ = std::fs::remove_dir_all(dir.join("o"));
    let mut args = morph_args(&s, &t, "o", &["--preset", "draft", "--segments", "1"]);
    args.extend(["--iterations", "1", "--no-surfaces", "--json"]);
    args.extend_from_slice(extra);
    let o = run(dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let first = String::from_utf8_lossy(&o.stdout)
        .lines()
        .next()
        .unwrap()
        .to_string();
    let e: serde_json::Value = serde_json::from_str(&first).unwrap();
    e["particles"].as_u64().unwrap() as usize
}

/// Case 10: --particles meets its budget in order: more asked, never fewer got, each within
/// the step one resolution makes (700, 1000 and 2000 gave 17,256, 7,208 and 4,224).
#[test]
fn particle_budget_is_met_in_order() {
    let dir = scratch("budget");
    let counts: Vec<usize> = [700, 1000, 2000, 5000]
        .iter()
        .map(|b| particles_of(&dir, &["--particles", &b.to_string()]))
        .collect();
    for (b, c) in [700, 1000, 2000, 5000].iter().zip(&counts) {
        let off = (*c as f64 / *b as f64 - 1.0).abs();
        assert!(off < 0.3, "budget {b}: {c} particles");
    }
    assert!(counts.windows(2).all(|w| w[0] < w[1]), "{counts:?}");
}

/// Case 12: checkpoints are sealed: a flipped bit in a state file, or progress.json edited
/// back to `segments_done: 0`, is refused by name on --resume (it exited 0 with a different
/// result). A checkpoint of another run is refused in `tests/integration/fuzz.rs`.
#[test]
fn damaged_checkpoints_are_refused_by_name() {
    let dir = scratch("sealed");
    let (s, t, ck, state) = interrupted_with_checkpoint(&dir);
    let mut resume = morph_args(&s, &t, "out", SMALL);
    resume.push("--resume");
    let bytes = std::fs::read(ck.join(&state)).unwrap();
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 0x10;
    std::fs::write(ck.join(&state), &flipped).unwrap();
    let o = run(&dir, &resume);
    assert_one_line_error(&o, 1, &[&state.to_string_lossy(), "damaged", "--overwrite"]);
    std::fs::write(ck.join(&state), &bytes).unwrap();
    let text = std::fs::read_to_string(ck.join("progress.json")).unwrap();
    let edited = text.replace("\"segments_done\":1", "\"segments_done\":0");
    assert_ne!(edited, text, "progress.json holds segments_done 1: {text}");
    std::fs::write(ck.join("progress.json"), &edited).unwrap();
    let o = run(&dir, &resume);
    assert_one_line_error(&o, 1, &["progress.json", "damaged"]);
    std::fs::write(ck.join("progress.json"), &text).unwrap();
    let o = run(&dir, &resume);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}

/// Case 13: physics no control can move is refused up front, naming what to change: a drag
/// of 1e308 (NaN gradients and exit 0) or 1e6, a material of Young's modulus 1e-30, a
/// density of 1e30.
#[test]
fn absurd_physics_is_refused_with_the_setting_to_change() {
    let dir = scratch("absurd");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    for (drag, needle) in [("1e308", "drag 1.000e308"), ("1e6", "drag 1.000e6")] {
        std::fs::write(
            dir.join("shot.toml"),
            format!("source = \"{s}\"\ntargets = [\"{t}\"]\ndrag = {drag}\n"),
        )
        .unwrap();
        let mut args = vec!["--scene", "shot.toml", "-o", "o"];
        args.extend_from_slice(TINY);
        let o = run(&dir, &args);
        assert_one_line_error(&o, 2, &[needle, "nothing can move", "at most"]);
    }
    for flags in [["--youngs-modulus", "1e-30"], ["--density", "1e30"]] {
        let mut args = morph_args(&s, &t, "o", TINY);
        args.extend(flags);
        let o = run(&dir, &args);
        assert_one_line_error(
            &o,
            2,
            &[
                "too soft for its density",
                "raise --youngs-modulus or lower --density",
            ],
        );
    }
    assert!(!dir.join("o").exists());
}

/// Case 14: OBJ polylines (`l`) and points (`p`) are not faces: a closed cube with a polyline
/// is closed, with no non-manifold edge.
#[test]
fn obj_polylines_are_not_faces() {
    let dir = scratch("polylines");
    let (v, f) = cube([0.0; 3]);
    write_obj(&dir.join("cube.obj"), &v, &f);
    let mut text = std::fs::read_to_string(dir.join("cube.obj")).unwrap();
    text.push_str("l 1 2 4 3 1\np 1 2 3\n");
    std::fs::write(dir.join("cube.obj"), text).unwrap();
    let (report, warnings) = inspect(&dir, &dir.join("cube.obj"));
    assert_eq!(report["closed"], true, "{report}");
    assert_eq!(report["non_manifold_edges"], 0, "{report}");
    assert_eq!(report["triangles"], 12, "{report}");
    assert!(warnings.is_empty(), "{warnings}");
}

/// Case 15: `v x y z w` is read as (x, y, z) / w everywhere: the carried surface's frames
/// are written without w, at the particles' size (Blender ignores w).
#[test]
fn homogeneous_vertices_are_carried_at_the_right_size() {
    let dir = scratch("vertex-w");
    let sphere = std::fs::read_to_string(root().join("assets/sphere.obj")).unwrap();
    let doubled: String = sphere
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(rest) => {
                let c: Vec<f64> = rest
                    .split_whitespace()
                    .map(|x| x.parse().unwrap())
                    .collect();
                format!("v {} {} {} 2\n", 2.0 * c[0], 2.0 * c[1], 2.0 * c[2])
            }
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(dir.join("w.obj"), doubled).unwrap();
    let o = run(&dir, &morph_args("w.obj", &asset("cube.obj"), "out", TINY));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let extent = |text: &str| -> f64 {
        text.lines()
            .filter_map(|l| l.strip_prefix("v "))
            .map(|r| {
                let c: Vec<f64> = r.split_whitespace().map(|x| x.parse().unwrap()).collect();
                assert_eq!(c.len(), 3, "a vertex line with w: v {r}");
                c[0].abs().max(c[1].abs()).max(c[2].abs())
            })
            .fold(0.0, f64::max)
    };
    let first = std::fs::read_to_string(dir.join("out/carried/frame_0001.obj")).unwrap();
    let original = extent(&sphere);
    assert!(
        (extent(&first) - original).abs() < 1e-4 * original,
        "{} vs {original}",
        extent(&first)
    );
}

/// Case 16: a frame spacing longer than the shot (only the rest shape would be written), a
/// frame rate past 1000 fps, and --resume on a finished folder that lost a file are refused
/// or remade, never reported as done.
#[test]
fn shots_without_motion_and_incomplete_folders_are_not_done() {
    let dir = scratch("no-frames");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    for flags in [&["--fps", "0.001"][..], &["--frame-every", "1000000"][..]] {
        let mut args = morph_args(&s, &t, "o", TINY);
        args.extend_from_slice(flags);
        let o = run(&dir, &args);
        assert_one_line_error(&o, 2, &["only the rest shape would be written"]);
    }
    let mut args = morph_args(&s, &t, "o", TINY);
    args.extend(["--dt", "1e-12"]);
    let o = run(&dir, &args);
    assert_one_line_error(&o, 2, &["frames per second, more than 1000"]);
    let out = tiny_output(&dir, "done");
    std::fs::remove_file(out.join("frames/frame_0002.ply")).unwrap();
    let mut args = morph_args(&s, &t, "done", TINY);
    args.push("--resume");
    let o = run(&dir, &args);
    assert_one_line_error(
        &o,
        2,
        &["'frames/frame_0002.ply'", "missing", "--overwrite"],
    );
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(out.join("frames/frame_0002.ply").is_file());
}

/// The unclear or late errors, each now one line that says what and where, in time.
#[test]
fn unclear_errors_are_clear_and_early() {
    let dir = scratch("clear-errors");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    // A 246-character -o with --overwrite: refused before the run, not after it.
    let long = "x".repeat(246);
    let mut args = morph_args(&s, &t, &long, TINY);
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert_one_line_error(&o, 2, &["is 246 bytes long", "at most 234"]);
    // Too many targets, and an --at that does not match them: said before any mesh loads.
    let many: Vec<String> = (0..1001).map(|_| t.clone()).collect();
    let mut args: Vec<&str> = vec![&s];
    args.extend(many.iter().map(String::as_str));
    args.extend(["-o", "o", "--quiet"]);
    let o = run_bounded(&dir, &args);
    assert_one_line_error(&o, 2, &["1001 target meshes given", "1 to 1000"]);
    let two = asset("two-lobes.obj");
    let o = run(&dir, &[&s, &t, &two, "-o", "o", "--at", "5", "--quiet"]);
    assert_one_line_error(&o, 2, &["--at gives 1 frame(s) for 2 target(s)"]);
    // A JSON scene with a byte-order mark reads.
    std::fs::write(
        dir.join("bom.json"),
        format!("\u{feff}{{\"source\": \"{s}\", \"targets\": [\"{t}\"], \"resolution\": 16, \"segments\": 2}}"),
    )
    .unwrap();
    let o = run(
        &dir,
        &[
            "--scene",
            "bom.json",
            "-o",
            "bom",
            "--iterations",
            "2",
            "--quiet",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    // The rope's stable step in numbers that can be read.
    let o = run(&dir, &["rope", "-o", "r", "--youngs-modulus", "1e30"]);
    let err = stderr(&o);
    assert!(!err.contains("0.000000"), "{err}");
    assert!(err.contains("e-"), "{err}");
    // PLY triangle strips (Stanford's scans) are triangles: a cube of six strips is closed.
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut strip: Vec<i32> = Vec::new();
    for q in quads {
        if !strip.is_empty() {
            strip.push(-1);
        }
        strip.extend([q[0], q[1], q[3], q[2]]);
    }
    let mut ply = String::from(
        "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n",
    );
    for i in 0..8 {
        ply.push_str(&format!("{} {} {}\n", i & 1, (i >> 1) & 1, (i >> 2) & 1));
    }
    let list: Vec<String> = strip.iter().map(|i| i.to_string()).collect();
    ply.push_str(&format!("{} {}\n", strip.len(), list.join(" ")));
    std::fs::write(dir.join("strips.ply"), ply).unwrap();
    let (report, _) = inspect(&dir, &dir.join("strips.ply"));
    assert_eq!(report["triangles"], 12, "{report}");
    assert_eq!(report["closed"], true, "{report}");
}

/// SIGHUP (a closed terminal) and a closed stdout (SIGPIPE: the log reader went away) stop a
/// run like SIGINT: one line saying so, the checkpoint kept, exit 129 / 141.
#[test]
fn sighup_and_a_closed_stdout_stop_with_a_message() {
    let dir = scratch("hup");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let o = stop_after_checkpoint(&dir, &morph_args(&s, &t, "out", SMALL), "HUP");
    assert_eq!(o.status.code(), Some(129), "{}", stderr(&o));
    assert!(stderr(&o).contains("SIGHUP"), "{}", stderr(&o));
    assert!(dir.join("out.partial/checkpoint/progress.json").is_file());

    let dir = scratch("pipe");
    let mut args = morph_args(&s, &t, "out", SMALL);
    args.retain(|a| *a != "--quiet");
    args.push("--json");
    let mut child = command(&dir, &args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(&dir, &mut child);
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(141), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("SIGPIPE (stdout was closed)"),
        "{}",
        stderr(&o)
    );
    assert!(dir.join("out.partial/checkpoint/progress.json").is_file());
}

/// A replacing run killed while deleting the old folder leaves `.OUT.replaced-PID`: the next
/// run that replaces OUT removes it when its process is gone and it is still provably
/// morph's; one holding a user's file is left alone.
#[test]
fn leftovers_of_a_killed_replacement_are_removed_when_provably_ours() {
    let dir = scratch("leftovers");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let out = tiny_output(&dir, "out");
    let copy = |to: &str| {
        let status = Command::new("cp")
            .arg("-r")
            .arg(&out)
            .arg(dir.join(to))
            .status()
            .unwrap();
        assert!(status.success());
    };
    copy(".out.replaced-999999999");
    std::fs::remove_file(dir.join(".out.replaced-999999999/frames/frame_0001.ply")).unwrap();
    copy(".out.replaced-999999998");
    let theirs = sentinel(&dir.join(".out.replaced-999999998"));
    let mut args = morph_args(&s, &t, "out", TINY);
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(!dir.join(".out.replaced-999999999").exists());
    assert_sentinel(&theirs);
}

/// A disk that fills up after the first checkpoint: the error says the completed segments are
/// kept and that --resume continues (it said only what could not be written). Run on a full
/// tmpfs in a user namespace, when this machine lets a test mount one.
#[test]
fn disk_full_says_the_checkpoint_is_kept() {
    let dir = scratch("disk-full");
    let mnt = dir.join("volume");
    std::fs::create_dir_all(&mnt).unwrap();
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let script = format!(
        "mount -t tmpfs -o size=48m none '{m}' || exit 99
cd '{m}'
'{bin}' '{s}' '{t}' -o out {small} 2> '{d}/err.txt' &
pid=$!
while [ ! -f out.partial/checkpoint/progress.json ]; do sleep 0.02; done
dd if=/dev/zero of=fill bs=1M count=64 2>/dev/null
wait $pid
echo \"code $?\"
cat '{d}/err.txt'
ls out.partial/checkpoint/progress.json",
        m = mnt.display(),
        d = dir.display(),
        bin = env!("CARGO_BIN_EXE_morph"),
        small = SMALL.join(" "),
    );
    let o = Command::new("unshare")
        .args(["-Urm", "sh", "-c", &script])
        .output();
    let Some(o) = o
        .ok()
        .filter(|o| o.status.code() != Some(99) && o.status.success())
    else {
        eprintln!("no user namespaces here: the full-disk case is skipped");
        return;
    };
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("code 1"), "{said}");
    let errors: Vec<&str> = said
        .lines()
        .filter(|l| l.starts_with("morph: error:"))
        .collect();
    assert_eq!(errors.len(), 1, "{said}");
    assert!(errors[0].contains("No space left on device"), "{said}");
    assert!(
        errors[0].contains("the completed segments are kept in 'out.partial'")
            && errors[0].contains("--resume"),
        "{said}"
    );
    assert!(
        said.contains("out.partial/checkpoint/progress.json"),
        "{said}"
    );
}

/// An output of morph 0.2.0 or earlier (its manifest lists no files) is refused by
/// --overwrite with a message that says why, and kept.
#[test]
fn outputs_of_earlier_versions_are_refused_saying_why() {
    let dir = scratch("old-version");
    let out = tiny_output(&dir, "out");
    let path = out.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    m.as_object_mut().unwrap().remove("files");
    m["version"] = "0.2.0".into();
    std::fs::write(&path, serde_json::to_vec(&m).unwrap()).unwrap();
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let mut args = morph_args(&s, &t, "out", TINY);
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert_one_line_error(
        &o,
        2,
        &[
            "written by morph 0.2.0, which did not list",
            "delete it yourself",
        ],
    );
    assert!(out.join("frames/frame_0001.ply").is_file());
}

/// Case 5 (farm): killed after the manifest is written, while the finished run removes its
/// checkpoint or before the folder is moved into place: --resume computes nothing again and
/// puts the complete folder in place, without the checkpoint's leftovers. (A kill in the
/// middle of that removal once left a checkpoint naming files already deleted.)
#[test]
fn killed_while_a_finished_run_tidies_up_then_resume_moves_it_into_place() {
    let reference = &small_reference().0;
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    for cut in [
        "before the checkpoint is removed",
        "halfway through removing it",
    ] {
        let dir = scratch(&format!("tidy-{}", cut.len()));
        assert_eq!(
            interrupted_after_checkpoint(&dir, "INT").status.code(),
            Some(130)
        );
        // The staging folder as the finished run leaves it: every file and the manifest.
        let staging = dir.join("out.partial");
        for f in files(&reference.join("ref")) {
            let to = staging.join(&f);
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            std::fs::copy(reference.join("ref").join(&f), &to).unwrap();
        }
        let checkpoint = staging.join("checkpoint");
        if cut.starts_with("halfway") {
            std::fs::remove_file(checkpoint.join("progress.json")).unwrap();
            for f in files(&checkpoint).iter().step_by(2) {
                std::fs::remove_file(checkpoint.join(f)).unwrap();
            }
        }
        let mut args = SMALL.to_vec();
        args.push("--resume");
        let o = run(&dir, &morph_args(&s, &t, "out", &args));
        let said = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
        assert_eq!(o.status.code(), Some(0), "{cut}: {said}");
        // Nothing was computed again: the manifest (with its timings) is the finished run's.
        assert!(
            std::fs::read(dir.join("out/manifest.json")).unwrap()
                == std::fs::read(reference.join("ref/manifest.json")).unwrap(),
            "{cut}"
        );
        assert_same_results(&reference.join("ref"), &dir.join("out"));
        assert!(!dir.join("out/checkpoint").exists(), "{cut}");
        assert!(!staging.exists(), "{cut}");
        assert_eq!(
            files(&dir.join("out")),
            files(&reference.join("ref")),
            "{cut}"
        );
    }
}

/// On the GPU device (lavapipe in CI): interrupted after a checkpoint, `--resume` finishes
/// bitwise like an uninterrupted run, the device giving the same bits every time.
#[test]
fn resume_on_the_gpu_device_is_bitwise_identical() {
    const SHOT: &[&str] = &[
        "--preset",
        "draft",
        "--resolution",
        "16",
        "--frames",
        "25",
        "--frame-every",
        "3",
        "--steps",
        "24",
        "--iterations",
        "3",
        "--device",
        "gpu",
        "--quiet",
    ];
    let m = interrupt_resume_and_compare("gpu-resume", SHOT);
    assert_ne!(m["timings"]["device"], "cpu");
    assert_eq!(m["settings"]["method"]["segments"].as_u64(), Some(3));
}
