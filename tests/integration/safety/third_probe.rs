//! The third hostile probe's defects (issue 62), each through the real binary: another run's
//! staging folder, the memory limit with the USD writer, an optimization that cannot work,
//! `compare` and the header's layout, short errors on PLY junk, `inspect` on a mesh that cannot
//! be a source, too many targets, `farm-template --overwrite`, farm progress on resume.

use super::*;

/// A morph of a few seconds with the knobs of the probe (`S` in the issue).
const PROBE: &[&str] = &[
    "--preset",
    "draft",
    "--resolution",
    "16",
    "--segments",
    "2",
    "--iterations",
    "3",
    "--quiet",
];

fn signal(child: &Child, name: &str) {
    send(child, name);
}

/// Waits until the process has taken `signo` (its handler ran), so that a second one is not
/// merged into the first while it is still pending (the kernel keeps one of each).
fn wait_until_taken(child: &Child, signo: i32) {
    let status = format!("/proc/{}/status", child.id());
    let t0 = Instant::now();
    loop {
        let Ok(text) = std::fs::read_to_string(&status) else {
            return;
        };
        let pending = ["ShdPnd:", "SigPnd:"].iter().any(|field| {
            text.lines()
                .find_map(|l| l.strip_prefix(field))
                .and_then(|mask| u64::from_str_radix(mask.trim(), 16).ok())
                .is_some_and(|mask| mask & (1 << (signo - 1)) != 0)
        });
        if !pending {
            return;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "signal {signo} never taken"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn wait_for(path: &Path, what: &str) {
    let t0 = Instant::now();
    while !path.exists() {
        assert!(t0.elapsed() < Duration::from_secs(60), "{what} never came");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Defect 1: run A's staging folder is removed by hand and run B takes the path; A, going
/// on, fails without touching B's folder (and writes nothing into it), and B completes.
#[test]
fn a_failing_run_never_touches_another_runs_staging_folder() {
    let dir = scratch("probe3-staging");
    let keep = sentinel(&dir);
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let a = command(&dir, &morph_args(&s, &t, "c3", SMALL))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let partial = dir.join("c3.partial");
    wait_for(
        &partial.join("checkpoint/progress.json"),
        "A's first checkpoint",
    );
    // A is held still while its folder goes and B takes the path, then let go.
    signal(&a, "STOP");
    std::fs::remove_dir_all(&partial).unwrap();
    let b = command(&dir, &morph_args(&s, &t, "c3", SMALL))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for(&partial.join("run.json"), "B's staging folder");
    signal(&a, "CONT");
    let a = a.wait_with_output().unwrap();
    assert_one_line_error(&a, 1, &["was removed or replaced during the run"]);
    let b = b.wait_with_output().unwrap();
    assert_eq!(b.status.code(), Some(0), "{}", stderr(&b));
    // B's folder is whole and holds only B's frames.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("c3/manifest.json")).unwrap()).unwrap();
    for f in m["files"].as_array().unwrap() {
        assert!(dir.join("c3").join(f.as_str().unwrap()).is_file(), "{f}");
    }
    assert_eq!(
        files(&dir.join("c3/frames")).len(),
        m["frames"].as_array().unwrap().len()
    );
    assert!(!partial.exists());
    assert_sentinel(&keep);
}

/// Runs `morph ARGS` (which writes `OUT`) and returns its output and the peak resident bytes
/// its manifest records (the kernel's high-water mark of morph's own pages: the `ru_maxrss`
/// a parent gets from wait4 counts the parent's pages too, since the child starts as its copy).
fn run_measuring_memory(dir: &Path, args: &[&str], out: &str) -> (Output, u64) {
    let output = run(dir, args);
    let manifest: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join(out).join("manifest.json")).unwrap_or_default(),
    )
    .unwrap_or_default();
    let mb = manifest["timings"]["peak_resident_mb"].as_f64();
    (
        output,
        mb.map_or(u64::MAX, |mb| (mb * (1 << 20) as f64) as u64),
    )
}

/// What the memory test allows above the limit: the allocator's slack over what the plan
/// counts (`ALLOCATOR_SLACK`, 10%) and 16 MB for the binary's own pages.
fn allowance(limit: u64) -> u64 {
    limit / 10 + (16 << 20)
}

/// Defect 2: a run of many frames with USD on stays within --memory-limit, writers included;
/// a limit the USD layer cannot fit in is refused before any work, and --usd none fits it.
#[test]
fn memory_limit_holds_for_a_run_of_many_frames_with_usd() {
    let dir = scratch("probe3-memory");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let shot = [
        "--preset",
        "draft",
        "--resolution",
        "16",
        "--iterations",
        "1",
        "--frames",
        "121",
        "--quiet",
    ];
    let args = |out: &'static str, limit: &'static str, extra: &[&'static str]| {
        let mut v = morph_args(&s, &t, out, &shot);
        v.extend(["--memory-limit", limit]);
        v.extend_from_slice(extra);
        v.into_iter().map(String::from).collect::<Vec<_>>()
    };
    // Refused before work where the USD layer cannot fit: nothing written.
    let low = args("low", "100M", &[]);
    let low: Vec<&str> = low.iter().map(String::as_str).collect();
    let o = run(&dir, &low);
    assert_one_line_error(&o, 2, &["most of it its USD file", "--usd none"]);
    assert!(!dir.join("low").exists() && !dir.join("low.partial").exists());
    // Without the USD the same limit holds the run.
    let none = args("none", "100M", &["--usd", "none"]);
    let none: Vec<&str> = none.iter().map(String::as_str).collect();
    let (o, peak) = run_measuring_memory(&dir, &none, "none");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(peak <= (100 << 20) + allowance(100 << 20), "peak {peak}");
    // With it, a limit the plan accepts holds the whole run.
    let usd = args("usd", "170M", &[]);
    let usd: Vec<&str> = usd.iter().map(String::as_str).collect();
    let (o, peak) = run_measuring_memory(&dir, &usd, "usd");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(dir.join("usd/morph.usdc").is_file());
    assert!(peak <= (170 << 20) + allowance(170 << 20), "peak {peak}");
}

/// Defects 3-5: an optimization that cannot work (a non-finite objective or gradient, a
/// loss that never moves) exits 1 with one line naming what to change, the right way round,
/// and leaves nothing behind.
#[test]
fn an_optimization_that_cannot_work_fails_saying_what_to_change() {
    let dir = scratch("probe3-optimization");
    let keep = sentinel(&dir);
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let cases: &[(&[&str], &[&str])] = &[
        (
            &["--volume-weight", "1e6"],
            &["did not move the body", "lower `volume_weight`"],
        ),
        (
            &["--path-weight", "1e300"],
            &["gradient is not finite", "lower `path_weight`"],
        ),
        (
            &["--fine-weight", "1e300"],
            &["gradient is not finite", "lower `fine_weight`"],
        ),
        (
            &["--control-smoothing", "1e300"],
            &["did not move the body", "lower `control_smoothing`"],
        ),
        (
            &["--learning-rate", "1e-300"],
            &["did not move the body", "larger `learning_rate`"],
        ),
    ];
    for (extra, needles) in cases {
        let mut args = morph_args(&s, &t, "o", PROBE);
        args.extend_from_slice(extra);
        let o = run(&dir, &args);
        assert_one_line_error(&o, 1, needles);
        assert!(!stderr(&o).contains("smaller `learning_rate`") || extra[0] != "--learning-rate");
        assert!(
            !dir.join("o").exists() && !dir.join("o.partial").exists(),
            "{extra:?}"
        );
    }
    // A healthy run of the same shot passes.
    let o = run(&dir, &morph_args(&s, &t, "o", PROBE));
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_sentinel(&keep);
}

/// A mass grid file: `header` (JSON) over `values`.
fn write_grid(path: &Path, header: &str, values: &[f64]) {
    let mut bytes = b"MORPHMG1".to_vec();
    bytes.extend((header.len() as u32).to_le_bytes());
    bytes.extend(header.as_bytes());
    for v in values {
        bytes.extend(v.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

fn grid_header(order: &str, units: &str) -> String {
    format!(
        r#"{{"dims":[2,3,4],"origin":[0,0,0],"dx":1,"dtype":"f64le","order":"{order}","units":"{units}","mass_units":"simulation"}}"#
    )
}

/// Defect 6: `compare` reads the layout the header declares (x- or z-slowest) and refuses an
/// order or units it cannot read.
#[test]
fn compare_reads_the_headers_order_and_refuses_what_it_cannot() {
    let dir = scratch("probe3-compare");
    let (nx, ny, nz) = (2, 3, 4);
    let mass = |i: usize, j: usize, k: usize| (100 * i + 10 * j + k) as f64;
    let mut x_slowest = Vec::new();
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                x_slowest.push(mass(i, j, k));
            }
        }
    }
    let mut z_slowest = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                z_slowest.push(mass(i, j, k));
            }
        }
    }
    let (a, b, c) = (
        dir.join("a.mgrid"),
        dir.join("b.mgrid"),
        dir.join("c.mgrid"),
    );
    write_grid(&a, &grid_header("x-slowest", "world"), &x_slowest);
    write_grid(&b, &grid_header("z-slowest", "world"), &z_slowest);
    // The same masses in two layouts: equal.
    let o = run(&dir, &["compare", "a.mgrid", "b.mgrid"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    // The z-slowest bytes declared x-slowest are other masses: different.
    write_grid(&c, &grid_header("x-slowest", "world"), &z_slowest);
    let o = run(&dir, &["compare", "a.mgrid", "c.mgrid"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    for (order, units, needle) in [
        ("banana", "world", "unsupported order 'banana'"),
        (
            "x-slowest",
            "millimetres",
            "unsupported units 'millimetres'",
        ),
    ] {
        write_grid(&c, &grid_header(order, units), &x_slowest);
        let o = run(&dir, &["compare", "a.mgrid", "c.mgrid"]);
        assert_one_line_error(&o, 2, &[needle]);
    }
}

/// Defect 7: a PLY header line of megabytes and a file of NULs named .ply give a short,
/// one-line error.
#[test]
fn ply_junk_gives_a_short_error() {
    let dir = scratch("probe3-ply");
    let long = dir.join("long.ply");
    let mut text = b"ply\nformat ascii 1.0\nelement vertex ".to_vec();
    text.extend(std::iter::repeat_n(b'9', 5 << 20));
    text.extend(b"\nproperty float x\nend_header\n");
    std::fs::write(&long, text).unwrap();
    let nul = dir.join("nul.ply");
    std::fs::write(&nul, vec![0u8; 8 << 20]).unwrap();
    for (file, needle) in [
        (&long, "header line 3 is"),
        (&nul, "does not start with the line 'ply'"),
    ] {
        let o = run(&dir, &["inspect", &file.display().to_string()]);
        assert_one_line_error(&o, 1, &[needle]);
        assert!(o.stderr.len() < 400, "{} bytes", o.stderr.len());
    }
}

/// An axis-aligned box `size` from the origin, as an OBJ.
fn write_box(path: &Path, size: [f64; 3]) {
    let (v, f) = cube([0.0; 3]);
    let v: Vec<[f64; 3]> = v
        .iter()
        .map(|p| [p[0] * size[0], p[1] * size[1], p[2] * size[2]])
        .collect();
    write_obj(path, &v, &f);
}

/// Defect 8: `inspect` warns of a mesh no particle fits in (it cannot be a source), and gives
/// a closed mesh's exact volume.
#[test]
fn inspect_warns_of_a_mesh_that_cannot_be_a_source() {
    let dir = scratch("probe3-inspect");
    for (name, size) in [
        ("needle.obj", [1.0, 1e-6, 1e-6]),
        ("slab.obj", [1.0, 1.0, 0.01]),
    ] {
        let path = dir.join(name);
        write_box(&path, size);
        let (report, err) = inspect(&dir, &path);
        assert_eq!(report["particles"], 0);
        let exact = size[0] * size[1] * size[2];
        let volume = report["volume"].as_f64().unwrap();
        assert!((volume / exact - 1.0).abs() < 1e-6, "{volume} vs {exact}");
        let warnings = report["warnings"].as_array().unwrap();
        assert!(
            warnings
                .iter()
                .any(|w| w.as_str().unwrap().contains("no particle fits inside")),
            "{warnings:?}"
        );
        assert!(err.contains("morph: warning:") && err.contains("cannot be a morph's source"));
    }
    // A mesh that can be a source has no such warning, and its volume is exact too.
    let path = dir.join("cube.obj");
    write_box(&path, [1.0, 2.0, 3.0]);
    let (report, _) = inspect(&dir, &path);
    assert!(report["particles"].as_u64().unwrap() > 0);
    assert!((report["volume"].as_f64().unwrap() - 6.0).abs() < 1e-9);
    assert!(
        report["warnings"].as_array().unwrap().is_empty(),
        "{report}"
    );
}

/// Defect 9: more targets than the shot has keyframes for are refused before any mesh is
/// read, without naming an --at that was never given.
#[test]
fn too_many_targets_are_refused_before_loading() {
    let dir = scratch("probe3-targets");
    let s = asset("sphere.obj");
    let cube = asset("cube.obj");
    let mut args = vec![s.as_str()];
    args.extend(std::iter::repeat_n(cube.as_str(), 12));
    args.extend(["-o", "x", "--frames", "13"]);
    let o = run(&dir, &args);
    assert_one_line_error(
        &o,
        2,
        &["12 target meshes need a keyframe each", "room for"],
    );
    assert!(!stderr(&o).contains("--at:"));
    // Meshes that do not exist show the check comes before any is read.
    let mut args = vec![s.as_str()];
    args.extend(std::iter::repeat_n("missing.obj", 1000));
    args.extend(["-o", "x", "--frames", "13"]);
    let o = run(&dir, &args);
    assert_one_line_error(&o, 2, &["1000 target meshes"]);
    assert!(!dir.join("x").exists() && !dir.join("x.partial").exists());
}

/// Defect 10: `farm-template`'s --overwrite counts after the meshes too.
#[test]
fn farm_template_overwrite_after_the_meshes() {
    let dir = scratch("probe3-farm");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    std::fs::write(dir.join("job.json"), "old").unwrap();
    let args = [
        "farm-template",
        "openjd",
        "--template",
        "job.json",
        &s,
        &t,
        "--overwrite",
    ];
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let job = std::fs::read_to_string(dir.join("job.json")).unwrap();
    assert!(job.contains("jobtemplate-2023-09"), "{job}");
    // Without it, still refused.
    let o = run(&dir, &args[..args.len() - 1]);
    assert_one_line_error(&o, 2, &["exists; pass --overwrite"]);
}

/// Defect 11: a resumed run's farm progress starts where the interrupted one was, never at 0.
#[test]
fn farm_progress_never_goes_back_on_resume() {
    let dir = scratch("probe3-progress");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let mut args = morph_args(&s, &t, "out", SMALL);
    args.extend(["--progress", "openjd"]);
    let mut child = command(&dir, &args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(&dir, &mut child);
    signal(&child, "TERM");
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(143), "{}", stderr(&o));
    args.push("--resume");
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let shown: Vec<f64> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| l.strip_prefix("openjd_progress: "))
        .map(|p| p.parse().unwrap())
        .collect();
    assert!(shown[0] > 0.0, "{shown:?}");
    assert!(shown.windows(2).all(|w| w[0] <= w[1]), "{shown:?}");
    assert_eq!(shown.last(), Some(&100.0));
}

/// Defect 12a: a second Ctrl-C while stopping exits at once with its line (and, with --json,
/// its `interrupted` event); the checkpoint written before is kept whole and a resume finishes.
#[test]
fn a_second_interrupt_says_so_and_keeps_the_checkpoint() {
    let dir = scratch("probe3-second-signal");
    let (s, t) = (asset("sphere.obj"), asset("two-lobes.obj"));
    let mut args = morph_args(&s, &t, "out", SMALL);
    args.push("--json");
    let mut child = command(&dir, &args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_checkpoint(&dir, &mut child);
    signal(&child, "INT");
    wait_until_taken(&child, libc::SIGINT);
    signal(&child, "INT");
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    let err = stderr(&o);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let last: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(last["event"], "interrupted", "{stdout}");
    assert_eq!(last["exit_code"], 130);
    // The second signal comes while the first is stopping the run (at its next evaluation).
    assert!(
        err.contains("morph: interrupted again by SIGINT while stopping"),
        "{err}"
    );
    assert!(
        last["message"]
            .as_str()
            .unwrap()
            .contains("interrupted again")
    );
    args.retain(|a| *a != "--json");
    args.push("--resume");
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}

/// Defect 12b: --quiet holds back every warning, the --threads one too.
#[test]
fn quiet_prints_no_warning() {
    let dir = scratch("probe3-quiet");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let mut args = morph_args(&s, &t, "o", TINY);
    args.extend(["--threads", "64"]);
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(stderr(&o), "", "nothing under --quiet");
    args.retain(|a| *a != "--quiet");
    args.push("--overwrite");
    let o = run(&dir, &args);
    assert!(
        stderr(&o).contains("morph: warning: --threads 64"),
        "{}",
        stderr(&o)
    );
}

/// Defect 12c: an output folder whose staging folder cannot be made is a bad output folder,
/// exit 2 as the table says, before any work.
#[test]
fn an_output_folder_that_cannot_be_made_exits_2() {
    let dir = scratch("probe3-unwritable");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    // /proc refuses new folders even to root (a chmod'ed folder does not).
    let o = run(&dir, &morph_args(&s, &t, "/proc/morph-probe-out", TINY));
    assert_one_line_error(
        &o,
        2,
        &["cannot create folder '/proc/morph-probe-out.partial'"],
    );
}

/// Defect 12e: a JSON scene file naming a key twice is refused, naming it (TOML's parser
/// refuses it itself).
#[test]
fn a_scene_key_given_twice_is_refused() {
    let dir = scratch("probe3-duplicate-keys");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let json = format!(r#"{{"source": "{s}", "targets": ["{t}"], "frames": 30, "frames": 40}}"#);
    std::fs::write(dir.join("scene.json"), json).unwrap();
    let o = run(&dir, &["--scene", "scene.json", "-o", "x"]);
    assert_one_line_error(&o, 2, &["the key `frames` is given twice"]);
    let toml = format!("source = \"{s}\"\ntargets = [\"{t}\"]\nframes = 30\nframes = 40\n");
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    let o = run(&dir, &["--scene", "scene.toml", "-o", "x"]);
    assert_one_line_error(&o, 2, &["duplicate key"]);
    assert!(!dir.join("x").exists() && !dir.join("x.partial").exists());
}

/// Defect 12f: a collider (or the ground) that holds part of the body at frame 1 is warned
/// about, in the summary and the manifest.
#[test]
fn a_collider_overlapping_the_body_is_warned_about() {
    let dir = scratch("probe3-collider");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    // A box through the sphere's side (the unit sphere at the origin).
    let (v, f) = cube([0.0; 3]);
    let v: Vec<[f64; 3]> = v
        .iter()
        .map(|p| [0.6 + p[0], p[1] - 0.5, p[2] - 0.5])
        .collect();
    write_obj(&dir.join("rock.obj"), &v, &f);
    let scene = format!(
        "source = \"{s}\"\ntargets = [\"{t}\"]\n[[colliders]]\nmesh = \"rock.obj\"\n[ground]\nheight = -0.9\n"
    );
    std::fs::write(dir.join("scene.toml"), scene).unwrap();
    let mut args = vec!["--scene", "scene.toml", "-o", "x"];
    args.extend_from_slice(&TINY[..TINY.len() - 1]);
    let o = run(&dir, &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("collider rock.obj overlaps the body at frame 1"),
        "{err}"
    );
    assert!(
        err.contains("the ground at height -0.9 cuts the body at frame 1"),
        "{err}"
    );
    let m = common::cli::manifest(&dir.join("x"));
    let warnings = m["warnings"].to_string();
    assert!(warnings.contains("overlaps the body"), "{warnings}");
}

/// Defect 12g: a run of hours says so, with its estimate, before its first step.
#[test]
fn a_long_run_says_how_long_before_it_starts() {
    let dir = scratch("probe3-long");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    let args = morph_args(
        &s,
        &t,
        "o",
        &[
            "--frames",
            "60001",
            "--usd",
            "none",
            "--preset",
            "draft",
            "--resolution",
            "16",
        ],
    );
    let mut child = command(&dir, &args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let err = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = std::io::BufRead::read_line(&mut std::io::BufReader::new(err), &mut line);
        let _ = tx.send(line);
    });
    // The warning comes with the setup, before the first step; a run that says nothing is
    // stopped after a while.
    let line = rx.recv_timeout(Duration::from_secs(60)).unwrap_or_default();
    signal(&child, "INT");
    let _ = child.wait();
    assert!(
        line.starts_with("morph: warning: this run is long: about "),
        "{line}"
    );
    assert!(
        line.contains("hours") && line.contains("60001 frames"),
        "{line}"
    );
}

/// Defect 12d: a memory refusal gives one figure for one morph, the run's or its USD file's,
/// whichever is larger: given that figure, the same command runs.
#[test]
fn a_memory_refusal_names_the_figure_that_runs() {
    let dir = scratch("probe3-memory-figure");
    let (s, t) = (asset("sphere.obj"), asset("cube.obj"));
    for extra in [&["--usd", "none"][..], &[][..]] {
        let mut args = morph_args(&s, &t, "o", PROBE);
        args.extend_from_slice(extra);
        let mut low = args.clone();
        low.extend(["--memory-limit", "10M"]);
        let o = run(&dir, &low);
        assert_one_line_error(&o, 2, &["this morph needs at least"]);
        let err = stderr(&o);
        let figure = err
            .split("below the ")
            .nth(1)
            .and_then(|r| r.split(" this morph").next())
            .unwrap()
            .replace(' ', "")
            .replace("MB", "M")
            .replace("GB", "G");
        let mut enough = args.clone();
        enough.extend(["--memory-limit", &figure]);
        let o = run(&dir, &enough);
        assert_eq!(o.status.code(), Some(0), "{figure}: {}", stderr(&o));
        std::fs::remove_dir_all(dir.join("o")).unwrap();
    }
}
