//! Meshes in, surfaces out: loading, validation errors, voxelized volumes of the real test
//! meshes, placement, surface extraction and the built-in assets.

use crate::common;
use common::cli::Scratch;
use morph::engine::mpm::{GridSpec, KernelKind};
use morph::geometry::{
    Jitter, MeshError, MorphGeometry, PlacementOptions, Solid, TargetFit, TriMesh, assets,
    extract_surface, load_mesh, particles_in,
};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

fn shared_meshes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes")
}

fn scratch(name: &str) -> Scratch {
    Scratch::empty("geometry-tests", name)
}

/// The inside volumes listed in `../shared/meshes/README.md` ("| file | volume |" table).
fn reference_volumes() -> Vec<(String, f64)> {
    let readme = std::fs::read_to_string(shared_meshes().join("README.md")).unwrap();
    let table = readme
        .split("| file | volume |")
        .nth(1)
        .expect("volume table in the meshes README");
    table
        .lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (cells.len() >= 3)
                .then(|| Some((cells[1].to_string(), cells[2].parse::<f64>().ok()?)))
                .flatten()
        })
        .collect()
}

/// Particle volume in the mesh's own units when the mesh is placed alone as a morph source.
fn particle_volume(path: &Path, resolution: usize) -> f64 {
    let geo = MorphGeometry::prepare(
        path,
        path,
        &PlacementOptions {
            resolution,
            ..Default::default()
        },
        2,
        None,
    )
    .unwrap();
    geo.source.positions.len() as f64 * geo.source.volume / geo.placement.world_to_sim.scale.powi(3)
}

/// Done-when 1: every shared mesh, open ones included, at resolution 64 (the shape spans
/// 44 cells, 88 particles across): particle volume within 3% of the listed inside volume.
#[test]
fn particle_volume_of_every_shared_mesh_within_3_percent() {
    let reference = reference_volumes();
    assert_eq!(reference.len(), 8, "{reference:?}");
    for (file, expected) in reference {
        let got = particle_volume(&shared_meshes().join(&file), 64);
        let err = got / expected - 1.0;
        eprintln!("{file}: {got:.6} vs {expected} ({:+.2}%)", 100.0 * err);
        assert!(err.abs() < 0.03, "{file}: {got} vs {expected}");
    }
}

/// Topology facts from the meshes README: triangle counts after triangulating polygons,
/// boundary edges of the open meshes (after welding), closedness of the others.
#[test]
fn loader_reproduces_the_listed_topology() {
    let facts = [
        ("bob.obj", 10688, Some(0)),
        ("spot.obj", 5856, Some(0)),
        ("cow.obj", 5804, Some(0)),
        ("fandisk.obj", 12946, Some(0)),
        ("rocker-arm.obj", 20088, Some(0)),
        ("stanford-bunny.obj", 69451, Some(223)),
        ("suzanne.obj", 968, None),
        // The README counts 1036 boundary edges on the file as stored; 876 of them are seams
        // between coincident vertices of the teapot's patches, which loading welds.
        ("teapot.obj", 6320, Some(160)),
    ];
    for (file, triangles, boundary) in facts {
        let loaded = load_mesh(&shared_meshes().join(file)).unwrap();
        assert_eq!(loaded.mesh.triangles.len(), triangles, "{file}");
        let topo = loaded.mesh.topology();
        match boundary {
            Some(0) => assert!(topo.is_closed(), "{file}: {topo:?}"),
            Some(b) => assert_eq!(topo.boundary_edges, b, "{file}"),
            None => assert!(!topo.is_closed(), "{file}"),
        }
    }
}

#[test]
fn missing_material_library_is_a_warning() {
    let loaded = load_mesh(&shared_meshes().join("bob.obj")).unwrap();
    assert!(
        loaded.warnings.iter().any(|w| w.contains("bob_tri.mtl")),
        "{:?}",
        loaded.warnings
    );
}

fn cube_ply_ascii() -> String {
    let cube = assets::cube(2.0, 1);
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n",
        cube.vertices.len()
    );
    for v in &cube.vertices {
        s += &format!("{} {} {}\n", v.x, v.y, v.z);
    }
    // The cube's triangles come in pairs (q0, q1, q2), (q0, q2, q3): write them as quads.
    for pair in cube.triangles.chunks(2) {
        let (a, b) = (pair[0], pair[1]);
        s += &format!("4 {} {} {} {}\n", a[0], a[1], a[2], b[2]);
    }
    s
}

#[test]
fn ply_quads_ascii_and_binary_load_like_obj() {
    let ascii = scratch("cube_ascii.ply");
    std::fs::write(&ascii, cube_ply_ascii()).unwrap();
    let mesh = load_mesh(&ascii).unwrap().mesh;
    assert_eq!(mesh.triangles.len(), 12);
    assert!(mesh.topology().is_closed());
    assert!((mesh.signed_volume() - 8.0).abs() < 1e-9);

    // Binary little-endian with double coordinates and int indices.
    let cube = assets::cube(2.0, 2);
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        cube.vertices.len(),
        cube.triangles.len()
    )
    .into_bytes();
    for v in &cube.vertices {
        for c in v.iter() {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &cube.triangles {
        bytes.push(3);
        for i in t {
            bytes.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    let binary = scratch("cube_binary.ply");
    std::fs::write(&binary, bytes).unwrap();
    let loaded = load_mesh(&binary).unwrap().mesh;
    assert_eq!(loaded, cube);
}

#[test]
fn inward_faces_are_flipped_with_a_warning() {
    let mut sphere = assets::uv_sphere(1.0, 16, 32, |_, _| 1.0);
    for t in &mut sphere.triangles {
        t.swap(1, 2);
    }
    // Half the faces wrong: inconsistent orientation.
    let path = scratch("inside_out.obj");
    sphere.write_obj(&path).unwrap();
    let loaded = load_mesh(&path).unwrap();
    assert!(loaded.warnings.iter().any(|w| w.contains("flipped")));
    assert!(loaded.mesh.signed_volume() > 4.0);

    let mut mixed = assets::uv_sphere(1.0, 16, 32, |_, _| 1.0);
    for t in mixed.triangles.iter_mut().step_by(3) {
        t.swap(1, 2);
    }
    mixed.write_obj(&path).unwrap();
    let loaded = load_mesh(&path).unwrap();
    assert_eq!(loaded.mesh.topology().misoriented_edges, 0);
    assert!(loaded.mesh.signed_volume() > 4.0);
}

/// Done-when 2: each bad input gives its own clear, one-line error naming the file.
#[test]
fn bad_inputs_are_clear_errors() {
    let write = |name: &str, bytes: &[u8]| {
        let p = scratch(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let cases: Vec<(Scratch, &str)> = vec![
        (scratch("does_not_exist.obj"), "cannot read mesh"),
        (write("empty.obj", b""), "is an empty file"),
        (
            write("garbage.obj", &[0xff, 0xfe, 0x00, 0x9c, 0x80, 0x10, 0xc3, 0x28]),
            "not a valid OBJ file: line 1 is not text",
        ),
        (write("garbage.ply", b"ply\nformat what 9\n\x00\xff"), "not a valid PLY file"),
        (write("text.obj", b"hello\nworld\n"), "no faces"),
        (
            write(
                "nan.obj",
                b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 NaN\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n",
            ),
            "vertex 4 has a non-finite coordinate",
        ),
        (
            write(
                "flat.obj",
                b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 0.5 0\nf 1 2 5\nf 2 3 5\nf 3 4 5\nf 4 1 5\n",
            ),
            "flat (zero thickness along z)",
        ),
        (
            write("triangle.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 1\nf 1 2 3\n"),
            "only 1 triangle(s), which cannot enclose a volume",
        ),
        (
            write("index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"),
            "not a valid OBJ file",
        ),
        (write("mesh.stl", b"solid x\nendsolid x\n"), "unknown format"),
    ];
    for (path, expected) in cases {
        let err = load_mesh(&path).expect_err(&path.display().to_string());
        let msg = err.to_string();
        assert!(msg.contains(expected), "{}: {msg}", path.display());
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(!msg.contains('\n'), "{msg}");
    }
}

/// An open sheet (a bent square, no volume) loads but has no inside: a clear error.
#[test]
fn open_sheet_has_no_inside() {
    let mut sheet = TriMesh::default();
    let n = 8;
    for i in 0..=n {
        for j in 0..=n {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            sheet
                .vertices
                .push(Vector3::new(x, y, 0.3 * (x * 3.0).sin()));
        }
    }
    for i in 0..n {
        for j in 0..n {
            let id = |a: usize, b: usize| (a * (n + 1) + b) as u32;
            sheet
                .triangles
                .push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            sheet
                .triangles
                .push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let path = scratch("sheet.obj");
    sheet.write_obj(&path).unwrap();
    let mesh = load_mesh(&path).unwrap().mesh;
    let err = Solid::measure(&mesh, &path).unwrap_err();
    assert!(matches!(err, MeshError::NoInside { .. }), "{err}");
}

/// The binary prints bad input as one line on stderr and exits 1.
#[test]
fn cli_reports_bad_mesh_in_one_line() {
    let path = scratch("cli_nan.obj");
    std::fs::write(
        &path,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv inf 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n",
    )
    .unwrap();
    for (args, code) in [
        (vec!["inspect".into(), path.display().to_string()], 1),
        (vec!["inspect".into(), "/no/such/file.obj".into()], 1),
        (
            vec![
                "inspect".into(),
                shared_meshes().join("cow.obj").display().to_string(),
                "--resolution".into(),
                "3".into(),
            ],
            2, // a bad option, as in every subcommand
        ),
    ] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_morph"))
            .args(&args)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(code), "{args:?}");
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(stderr.starts_with("morph: error: "), "{stderr}");
    }
}

/// Placement: target scaled to the source's volume with centroids on top of each other,
/// everything inside the grid with padding, transform recorded and invertible.
#[test]
fn target_is_scaled_to_source_volume_and_centred() {
    let src = shared_meshes().join("spot.obj");
    let tgt = shared_meshes().join("fandisk.obj"); // other units, far from the origin
    let geo = MorphGeometry::prepare(&src, &tgt, &PlacementOptions::default(), 2, None).unwrap();
    let (ns, nt) = (geo.source.positions.len(), geo.target.positions.len());
    assert!((nt as f64 / ns as f64 - 1.0).abs() < 0.03, "{ns} vs {nt}");
    let centroid = |x: &[Vector3<f64>]| x.iter().sum::<Vector3<f64>>() / x.len() as f64;
    let gap = (centroid(&geo.source.positions) - centroid(&geo.target.positions)).norm();
    assert!(gap < 0.25 * geo.placement.grid.dx, "{gap}");
    // The recorded transform maps the target's own centroid onto the source's.
    let t = geo.placement.target_to_world;
    let mapped = t.apply(&Vector3::from(geo.target_solid.centroid));
    let back = (mapped - Vector3::from(geo.source_solid.centroid)).norm();
    assert!(back < 1e-9 * geo.source_solid.volume.cbrt(), "{back}");
    let expected_scale = (geo.source_solid.volume / geo.target_solid.volume).cbrt();
    assert!((t.scale - expected_scale).abs() < 1e-12);
    // Every particle at least 3 cells from the walls, longest side = resolution.
    let g = &geo.placement.grid;
    assert_eq!(*g.cells.iter().max().unwrap(), 32);
    for x in geo.source.positions.iter().chain(&geo.target.positions) {
        for a in 0..3 {
            let cells_from_low = (x[a] - g.origin[a]) / g.dx;
            assert!(cells_from_low > 3.0 && cells_from_low < g.cells[a] as f64 - 3.0);
        }
    }
    // Target masses: same total as the source, on the grid.
    let m = geo.target_masses(KernelKind::Cubic, 40.0).unwrap();
    let total: f64 = m.iter().sum();
    let source_mass = 40.0 * geo.source.volume * ns as f64;
    assert!((total / source_mass - 1.0).abs() < 1e-12);

    let as_given = MorphGeometry::prepare(
        &src,
        &src,
        &PlacementOptions {
            target_fit: TargetFit::AsGiven,
            ..Default::default()
        },
        2,
        None,
    )
    .unwrap();
    assert_eq!(as_given.placement.target_to_world.scale, 1.0);
    assert_eq!(as_given.source.positions, as_given.target.positions);
}

#[test]
fn bad_placement_options_are_errors() {
    let src = shared_meshes().join("spot.obj");
    for (opts, per_cell, jitter, expected) in [
        (
            PlacementOptions {
                resolution: 4,
                ..Default::default()
            },
            2,
            None,
            "--resolution",
        ),
        (
            PlacementOptions {
                padding: f64::NAN,
                ..Default::default()
            },
            2,
            None,
            "padding",
        ),
        (PlacementOptions::default(), 0, None, "particles per cell"),
        (
            PlacementOptions::default(),
            2,
            Some(Jitter {
                amount: 3.0,
                seed: 1,
            }),
            "jitter",
        ),
    ] {
        let err = MorphGeometry::prepare(&src, &src, &opts, per_cell, jitter).unwrap_err();
        assert!(err.to_string().contains(expected), "{err}");
    }
}

#[test]
fn jitter_is_seeded_and_keeps_the_count() {
    let sphere = assets::uv_sphere(6.0, 24, 48, |_, _| 1.0);
    let grid = GridSpec::centred_cube(16, 1.0);
    let plain = particles_in(&sphere, &grid, 2, None);
    let j = |seed| particles_in(&sphere, &grid, 2, Some(Jitter { amount: 0.5, seed }));
    let (a, b, c) = (j(7), j(7), j(8));
    assert_eq!(a.positions, b.positions);
    assert_ne!(a.positions, c.positions);
    assert_eq!(a.positions.len(), plain.positions.len());
    let max_shift = a
        .positions
        .iter()
        .zip(&plain.positions)
        .map(|(p, q)| (p - q).abs().max())
        .fold(0.0, f64::max);
    assert!(
        max_shift > 0.0 && max_shift <= 0.25 * 0.5 + 1e-12,
        "{max_shift}"
    );
}

/// Done-when 4: a particle ball gives a closed surface within 5% of the particle volume,
/// also when the particles are jittered, and the same bits for any thread count.
#[test]
fn surface_of_particle_ball_is_closed_with_matching_volume() {
    let sphere = assets::uv_sphere(8.0, 48, 96, |_, _| 1.0);
    let grid = GridSpec::centred_cube(24, 1.0);
    for jitter in [
        None,
        Some(Jitter {
            amount: 0.6,
            seed: 3,
        }),
    ] {
        let p = particles_in(&sphere, &grid, 2, jitter);
        let volumes = vec![p.volume; p.positions.len()];
        let mesh = extract_surface(&p.positions, &volumes, 0.5).unwrap();
        let topo = mesh.topology();
        assert!(topo.is_closed(), "{topo:?}");
        assert_eq!(topo.misoriented_edges, 0);
        let particle_volume = p.volume * p.positions.len() as f64;
        let ratio = mesh.signed_volume() / particle_volume;
        assert!((ratio - 1.0).abs() < 0.05, "{jitter:?}: {ratio}");
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| extract_surface(&p.positions, &volumes, 0.5).unwrap())
        };
        assert_eq!(on(1), on(2));
    }
}

/// A stretched body (volumes scaled by J) still gives one closed surface.
#[test]
fn surface_of_deformed_particles_stays_closed() {
    let torus = assets::torus(6.0, 2.5, 48, 24);
    let grid = GridSpec::centred_cube(24, 1.0);
    let p = particles_in(&torus, &grid, 2, None);
    let stretch = Vector3::new(1.3, 1.0, 0.8);
    let x: Vec<Vector3<f64>> = p
        .positions
        .iter()
        .map(|x| x.component_mul(&stretch))
        .collect();
    let j = stretch.product();
    let volumes = vec![p.volume * j; x.len()];
    let mesh = extract_surface(&x, &volumes, 0.5).unwrap();
    assert!(mesh.topology().is_closed());
    let ratio = mesh.signed_volume() / (p.volume * j * x.len() as f64);
    assert!((ratio - 1.0).abs() < 0.08, "{ratio}");
    // Genus 1 survives: chi = V - E + F = 0.
    let chi =
        mesh.vertices.len() as i64 - mesh.topology().edges as i64 + mesh.triangles.len() as i64;
    assert_eq!(chi, 0);
}

/// Done-when 5: `morph assets` regenerates exactly the committed files.
#[test]
fn committed_assets_match_the_generator() {
    let dir = scratch("assets");
    let _ = std::fs::remove_dir_all(&dir); // a fresh folder: assets never replace files unasked
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_morph"))
        .args(["assets", "-o"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success());
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    for name in ["sphere.obj", "torus.obj", "cube.obj", "two-lobes.obj"] {
        let fresh = std::fs::read(dir.join(name)).unwrap();
        let kept = std::fs::read(committed.join(name))
            .unwrap_or_else(|e| panic!("assets/{name}: {e}; run `morph assets`"));
        assert!(
            fresh == kept,
            "assets/{name} is stale: run `cargo run --release -- assets`"
        );
        let mesh = load_mesh(&committed.join(name)).unwrap();
        assert!(mesh.mesh.topology().is_closed(), "{name}");
        assert!(mesh.warnings.is_empty(), "{name}: {:?}", mesh.warnings);
    }
}
