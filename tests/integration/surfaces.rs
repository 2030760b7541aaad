//! The surfaces a morph writes: the source's own surface carried through the morph, and the
//! surface rebuilt from the particles, measured against the source and the target.

use crate::common;
use common::cli::{manifest, morph, ok, scratch_in};

/// Lines of an OBJ file that start with `tag` and a space.
fn lines<'a>(text: &'a str, tag: &str) -> Vec<&'a str> {
    let prefix = format!("{tag} ");
    text.lines().filter(|l| l.starts_with(&prefix)).collect()
}

/// sphere -> spot with the carried surface: every frame has the sphere's vertices, texture
/// coordinates and faces (the same lines: topology and UVs unchanged), frame 1 is the source
/// asset's vertex lines exactly, the body moves it afterwards, and the manifest measures it.
#[test]
fn the_carried_surface_keeps_the_source_topology_and_uvs() {
    let out = scratch_in("surface-tests", "carried");
    ok(&morph(&[
        "assets/sphere.obj",
        "../shared/meshes/spot.obj",
        "-o",
        out.to_str().unwrap(),
        "--preset",
        "draft",
        "--resolution",
        "16",
        "--surface",
        "carried",
        "--quiet",
    ]));
    let source = std::fs::read_to_string("assets/sphere.obj").unwrap();
    let (v0, vt0, f0) = (
        lines(&source, "v"),
        lines(&source, "vt"),
        lines(&source, "f"),
    );
    assert_eq!((v0.len(), vt0.len()), (1986, 2143));
    let m = manifest(&out);
    let frames = m["frames"].as_array().unwrap();
    assert!(
        !out.join("meshes").exists(),
        "--surface carried writes no rebuilt surface"
    );
    let mut moved = 0;
    for (i, f) in frames.iter().enumerate() {
        let path = out.join(f["carried_mesh"].as_str().unwrap());
        let text = std::fs::read_to_string(&path).unwrap();
        let v = lines(&text, "v");
        assert_eq!(v.len(), v0.len(), "{path:?}");
        assert_eq!(lines(&text, "vt"), vt0, "{path:?}: texture coordinates");
        assert_eq!(lines(&text, "f"), f0, "{path:?}: faces");
        if i == 0 {
            assert_eq!(v, v0, "frame 1 is the source asset");
        } else if v != v0 {
            moved += 1;
        }
        let c = &f["carried"];
        let stretch = c["max_stretch"].as_f64().unwrap();
        assert!(stretch.is_finite() && stretch >= 1.0, "{c}");
    }
    assert!(
        moved >= frames.len() / 2,
        "the body moves the surface: {moved} frames"
    );
    let summary = &m["frames_summary"]["carried"];
    assert!(summary["max_stretch"].as_f64().unwrap() > 1.0, "{summary}");
}

/// Each written normal of a carried OBJ and its vertex's normal on the written mesh (area
/// weighted over the faces, fanned): the angle between them, in degrees, per face corner.
fn normal_offsets(text: &str) -> Vec<f64> {
    let parse = |l: &str| -> [f64; 3] {
        let c: Vec<f64> = l
            .split_whitespace()
            .skip(1)
            .take(3)
            .map(|x| x.parse().unwrap())
            .collect();
        [c[0], c[1], c[2]]
    };
    let v: Vec<[f64; 3]> = lines(text, "v").into_iter().map(parse).collect();
    let vn: Vec<[f64; 3]> = lines(text, "vn").into_iter().map(parse).collect();
    // (vertex, normal) per corner, by face.
    let faces: Vec<Vec<(usize, usize)>> = lines(text, "f")
        .into_iter()
        .map(|l| {
            l.split_whitespace()
                .skip(1)
                .map(|c| {
                    let k: Vec<&str> = c.split('/').collect();
                    (
                        k[0].parse::<usize>().unwrap() - 1,
                        k[2].parse::<usize>().unwrap() - 1,
                    )
                })
                .collect()
        })
        .collect();
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut area = vec![[0.0; 3]; v.len()];
    for f in &faces {
        for k in 1..f.len() - 1 {
            let (a, b, c) = (f[0].0, f[k].0, f[k + 1].0);
            let n = cross(sub(v[b], v[a]), sub(v[c], v[a]));
            for i in [a, b, c] {
                area[i] = [area[i][0] + n[0], area[i][1] + n[1], area[i][2] + n[2]];
            }
        }
    }
    faces
        .iter()
        .flatten()
        .filter_map(|&(i, k)| {
            let (g, n) = (area[i], vn[k]);
            let cos = dot(g, n) / (dot(g, g) * dot(n, n)).sqrt();
            cos.is_finite()
                .then(|| cos.clamp(-1.0, 1.0).acos().to_degrees())
        })
        .collect()
}

/// A source with its own normals (`vn`: suzanne's) has them written turned with the carried
/// mesh: on every frame each keeps the angle it makes with its vertex's normal on the mesh, as
/// in the source (0.13.0 turned them by the particles' mean `F`, which a plastic flow leaves
/// near a rotation: 15.7 degrees off on frame 1, 20.6 on the last, on this morph).
#[test]
fn a_source_s_own_normals_follow_the_carried_mesh() {
    let out = scratch_in("surface-tests", "carried-normals");
    ok(&morph(&[
        "../shared/meshes/suzanne.obj",
        "assets/sphere.obj",
        "-o",
        out.to_str().unwrap(),
        "--preset",
        "draft",
        "--resolution",
        "16",
        "--surface",
        "carried",
        "--usd",
        "none",
        "--quiet",
    ]));
    let m = manifest(&out);
    let frames = m["frames"].as_array().unwrap();
    let read = |f: &serde_json::Value| {
        std::fs::read_to_string(out.join(f["carried_mesh"].as_str().unwrap())).unwrap()
    };
    let first = normal_offsets(&read(&frames[0]));
    assert!(first.len() > 1900, "{} corners", first.len());
    let last = normal_offsets(&read(frames.last().unwrap()));
    assert_eq!(first.len(), last.len());
    let worst = first
        .iter()
        .zip(&last)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 0.5,
        "a written normal turned {worst} degrees against its mesh"
    );
}

/// The rebuilt surfaces come out clean with either method: one shell (the body; no void
/// walls, no islands), closed, and no triangle under the stated smallest angle; the manifest
/// has the surfaces before cleaning too (the narrow lattice kernel leaves voids to drop).
#[test]
fn rebuilt_surfaces_have_one_shell_and_no_slivers() {
    // The README job at draft, resolution 20, rebuilt surface only, on `threads` ("0": all),
    // in 13 frames: a shorter shot deforms the body as much, and the lattice kernel still
    // leaves void shells on its last frames.
    let run = |name: &str, method: &str, threads: &str| {
        let out = scratch_in("surface-tests", name);
        ok(&morph(
            &[
                "assets/sphere.obj",
                "assets/two-lobes.obj",
                "-o",
                out.to_str().unwrap(),
                "--preset",
                "draft",
                "--resolution",
                "20",
                "--frames",
                "13",
                "--surface",
                "rebuilt",
                "--rebuilt-method",
                method,
                "--quiet",
            ]
            .into_iter()
            .chain(
                (threads != "0")
                    .then_some(["--threads", threads])
                    .into_iter()
                    .flatten(),
            )
            .collect::<Vec<_>>(),
        ));
        out
    };
    for method in ["sharp", "deformed", "lattice", "splashsurf"] {
        let out = run(&format!("rebuilt-{method}"), method, "0");
        let m = manifest(&out);
        let mut voids_before = 0;
        for f in m["frames"].as_array().unwrap() {
            let r = &f["rebuilt"];
            let after = &r["after"];
            assert_eq!(after["void_shells"].as_u64(), Some(0), "{method}: {r}");
            // splashsurf parts the body where its particles part (2 shells on some frames
            // here) and its fine marching cubes leave slivers our cleaning does not all
            // remove (0.12 degrees): these bounds are the default's (docs/geometry.md).
            if method != "splashsurf" {
                assert_eq!(after["shells"].as_u64(), Some(1), "{method}: {r}");
                assert!(
                    after["min_angle_deg"].as_f64().unwrap() >= 0.25,
                    "{method}: {r}"
                );
            }
            assert_eq!(after["zero_area"].as_u64(), Some(0), "{method}: {r}");
            voids_before += r["before"]["void_shells"].as_u64().unwrap();
            let mesh = morph::geometry::load_mesh(&out.join(f["mesh"].as_str().unwrap()))
                .unwrap()
                .mesh;
            assert!(mesh.topology().is_closed(), "{method}: {}", f["mesh"]);
            // The sharp, deformed and splashsurf surfaces keep the particles' volume (the
            // body's times their mean J) within 0.5%; the narrow kernel's stays within 4%.
            let e = f["surface_volume_error"].as_f64().unwrap();
            let against_particles = (1.0 + e) / f["mean_j"].as_f64().unwrap() - 1.0;
            let bound = if method == "lattice" { 0.04 } else { 0.005 };
            assert!(
                against_particles.abs() <= bound,
                "{method}: volume off the particles' by {against_particles}"
            );
        }
        if method == "lattice" {
            assert!(
                voids_before > 0,
                "the narrow kernel leaves void shells for cleaning to drop"
            );
        }
        if method == "splashsurf" {
            // splashsurf works in parallel subdomains: the same files on one thread.
            let one = run("rebuilt-splashsurf-1", method, "1");
            for f in m["frames"].as_array().unwrap() {
                let name = f["mesh"].as_str().unwrap();
                assert!(
                    std::fs::read(out.join(name)).unwrap()
                        == std::fs::read(one.join(name)).unwrap(),
                    "{name} differs between 1 thread and all"
                );
            }
        }
    }
}

/// The particle spacing of a run, world units.
fn world_spacing(m: &serde_json::Value) -> f64 {
    let per_cell = m["settings"]["body"]["particles_per_cell"]
        .as_f64()
        .unwrap();
    m["dx_sim"].as_f64().unwrap() / per_cell * m["sim_to_world"]["scale"].as_f64().unwrap()
}

/// Frame 1 is the body at rest: its rebuilt surface is true to the source (issue 28's goals:
/// mean normal deviation <= 3 degrees, <= 1% of the area beyond 20, mean distance <= 0.15
/// spacings). The default `sharp` surface meets them on the sphere and on fandisk (flat faces,
/// sharp edges: 1.86 degrees, 0.99% beyond 20, the share at its bar); `deformed`, whose kernels round every edge,
/// meets them on the sphere only (fandisk 12.3 degrees, 26%), and the old narrow kernel on
/// neither (what the measure must tell apart). The manifest's figures agree with a
/// recomputation from the written files.
#[test]
fn a_body_at_rest_is_rebuilt_true_to_its_mesh() {
    use morph::geometry::fidelity::{Reference, mesh_fidelity};
    let goals = (3.0, 0.01, 0.15);
    let fandisk = "../shared/meshes/fandisk.obj";
    for (source, method, within) in [
        ("assets/sphere.obj", "sharp", true),
        ("assets/sphere.obj", "deformed", true),
        ("assets/sphere.obj", "lattice", false),
        (fandisk, "sharp", true),
        (fandisk, "deformed", false),
    ] {
        let bounds = goals;
        let name = format!("rest-{method}-{}", source.rsplit('/').next().unwrap());
        let out = scratch_in("surface-tests", &name);
        ok(&morph(&[
            source,
            "assets/cube.obj",
            "-o",
            out.to_str().unwrap(),
            "--frames",
            "2",
            "--iterations",
            "1",
            "--surface",
            "rebuilt",
            "--rebuilt-method",
            method,
            "--quiet",
        ]));
        let m = manifest(&out);
        let f = &m["frames_summary"]["surfaces"]["rebuilt_first"];
        let (normal, off, mean) = (
            f["mean_normal_deg"].as_f64().unwrap(),
            f["off_share"].as_f64().unwrap(),
            f["mean_distance"].as_f64().unwrap(),
        );
        let meets = normal <= bounds.0 && off <= bounds.1 && mean <= bounds.2;
        assert_eq!(meets, within, "{source} {method}: {f}");
        // Recomputed from the written frame and the source file.
        let rebuilt = morph::geometry::load_mesh(&out.join("meshes/frame_0001.obj")).unwrap();
        let reference = morph::geometry::load_mesh(std::path::Path::new(source)).unwrap();
        let again = mesh_fidelity(
            &rebuilt.mesh,
            &Reference::new(&reference.mesh).unwrap(),
            world_spacing(&m),
        );
        for (ours, theirs) in [
            (again.mean_normal_deg, normal),
            (again.mean_distance, mean),
            (again.max_distance, f["max_distance"].as_f64().unwrap()),
        ] {
            assert!(
                (ours - theirs).abs() <= 0.02 * theirs.abs() + 1e-3,
                "{source} {method}: recomputed {again:?}, manifest {f}"
            );
        }
        assert!((again.off_share - off).abs() <= 0.002, "{again:?} vs {f}");
    }
}

/// The carried surface must not fold where the body compresses (sphere -> fandisk): no
/// frame's fold share above the source's own (plus one face in a thousand). 0.3.0's binding
/// (each particle's own `F` within 2.5 spacings) folded 0.25% of the faces on this run.
/// Nor may the rebuilt (`sharp`) surface crease mid-shot: no frame's crease share more than
/// 0.05% above frame 1's. Before its snapping faded with the planes' strain, it creased
/// 0.15% of its faces on frame 4 of this run (the body at rest, frame 1: none).
#[test]
fn the_surfaces_do_not_fold_or_crease_under_compression() {
    let out = scratch_in("surface-tests", "fold");
    let run = morph(&[
        "assets/sphere.obj",
        "../shared/meshes/fandisk.obj",
        "-o",
        out.to_str().unwrap(),
        "--preset",
        "draft",
        "--surface",
        "both",
        "--usd",
        "none",
    ]);
    ok(&run);
    let m = manifest(&out);
    let s = &m["frames_summary"]["surfaces"];
    let (source, most) = (
        s["source_fold_share"].as_f64().unwrap(),
        s["max_carried_fold_share"].as_f64().unwrap(),
    );
    assert!(
        most <= source + 1e-3,
        "fold share {most} against the source's {source}"
    );
    let (first, creased) = (
        s["rebuilt_first_crease_share"].as_f64().unwrap(),
        s["max_rebuilt_crease_share"].as_f64().unwrap(),
    );
    assert!(
        creased <= first + 5e-4,
        "crease share {creased} against frame 1's {first}"
    );
    // The summaries are the largest of the frames', and each frame's crease share is the
    // written mesh's.
    let frames = m["frames"].as_array().unwrap();
    let largest = |key: &str, figure: &str| {
        frames
            .iter()
            .map(|f| f[key][figure].as_f64().unwrap())
            .fold(0.0, f64::max)
    };
    assert_eq!(largest("carried", "fold_share"), most);
    assert_eq!(largest("rebuilt", "crease_share"), creased);
    // The summary says the same.
    let stdout = String::from_utf8_lossy(&run.stdout);
    let line = lines(&stdout, "surfaces:");
    let said = format!("rebuilt creases at most {:.2}%", 100.0 * creased);
    assert!(line.len() == 1 && line[0].contains(&said), "{stdout}");
    for (k, f) in frames.iter().enumerate().step_by(4) {
        let path = out.join(format!("meshes/frame_{:04}.obj", k + 1));
        let mesh = morph::geometry::load_mesh(&path).unwrap().mesh;
        let again = morph::geometry::fidelity::crease_share(&mesh);
        let ours = f["rebuilt"]["crease_share"].as_f64().unwrap();
        assert!((again - ours).abs() <= 2e-4, "{path:?}: {again} vs {ours}");
    }
}

/// The `v` lines of an OBJ file, as written.
fn obj_vertices(path: &std::path::Path) -> Vec<nalgebra::Vector3<f64>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let c: Vec<f64> = l
                .split_whitespace()
                .take(3)
                .map(|v| v.parse().unwrap())
                .collect();
            nalgebra::Vector3::new(c[0], c[1], c[2])
        })
        .collect()
}

/// `--surface all`: the last target's own mesh carried backward. Its last frame is the target as
/// the run placed it (to f32's rounding of the file's numbers), every frame keeps its
/// topology, its folds on the frames it is seen in (weight above zero) are no more than the
/// target's own, and its weights rise from 0 to 1 in the manifest and the USD file.
#[test]
fn the_target_carried_backward_ends_on_the_placed_target() {
    use morph::geometry::fidelity::{edge_neighbours, fold_share};
    let scratch = scratch_in("surfaces", "target-carried");
    let out: &std::path::Path = scratch.as_ref();
    let target = common::cli::root().join("assets/two-lobes.obj");
    ok(&morph(&[
        "assets/sphere.obj",
        target.to_str().unwrap(),
        "--preset",
        "draft",
        "--frames",
        "13",
        "--resolution",
        "20",
        "--surface",
        "all",
        "--usd",
        "usda",
        "-o",
        out.to_str().unwrap(),
    ]));
    let m = manifest(out);
    let frames = m["frames"].as_array().unwrap();
    let weights: Vec<f64> = frames
        .iter()
        .map(|f| f["target_weight"].as_f64().unwrap())
        .collect();
    assert_eq!(weights[0], 0.0);
    assert_eq!(*weights.last().unwrap(), 1.0);
    assert!(weights.windows(2).all(|w| w[1] >= w[0]), "{weights:?}");
    // The last frame: the target file's vertices, placed.
    let place = &m["target"];
    let scale = place["scale"].as_f64().unwrap();
    let t: Vec<f64> = place["translation"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let translation = nalgebra::Vector3::new(t[0], t[1], t[2]);
    let placed: Vec<_> = obj_vertices(&target)
        .iter()
        .map(|v| scale * v + translation)
        .collect();
    let last = out.join(frames.last().unwrap()["target_carried"].as_str().unwrap());
    let written = obj_vertices(&last);
    assert_eq!(written.len(), placed.len());
    let size = placed.iter().fold(0.0f64, |s, v| s.max(v.norm()));
    let worst = written
        .iter()
        .zip(&placed)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(
        worst <= 1e-5 * size,
        "last frame {worst} from the placed target (size {size})"
    );
    // Folds: no more than the target's own where the target's mesh is seen.
    let folds = |path: &std::path::Path| {
        let mesh = morph::geometry::load_mesh(path).unwrap().mesh;
        let tris: Vec<[usize; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| i as usize))
            .collect();
        (
            fold_share(&mesh.vertices, &tris, &edge_neighbours(&tris)),
            tris.len(),
        )
    };
    let (own, faces) = folds(&target);
    for (f, w) in frames.iter().zip(&weights) {
        let (share, n) = folds(&out.join(f["target_carried"].as_str().unwrap()));
        assert_eq!(n, faces, "the topology holds");
        let reported = f["target_carried_fold_share"]
            .as_f64()
            .expect("the manifest's");
        if *w > 0.0 {
            assert!(reported <= own + 1e-12, "frame {}: {reported}", f["index"]);
            assert!(
                share <= own + 1e-12,
                "frame {}: folds {share} against the target's {own}",
                f["index"]
            );
        }
    }
    // The USD file: the target's mesh, and the weights on both carried meshes.
    let usda = std::fs::read_to_string(out.join("morph.usda")).unwrap();
    assert!(usda.contains("def Mesh \"target_carried\""));
    assert_eq!(usda.matches("float primvars:weight.timeSamples").count(), 2);
}
