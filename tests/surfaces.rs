//! The surfaces a morph writes: the source's own surface carried through the morph.

mod common;
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

/// The rebuilt surfaces come out clean: one shell (the body; no void walls, no islands),
/// closed, and no triangle under the stated smallest angle; the manifest has the surfaces
/// before cleaning too, which had voids.
#[test]
fn rebuilt_surfaces_have_one_shell_and_no_slivers() {
    let out = scratch_in("surface-tests", "rebuilt");
    ok(&morph(&[
        "assets/sphere.obj",
        "assets/two-lobes.obj",
        "-o",
        out.to_str().unwrap(),
        "--preset",
        "draft",
        "--resolution",
        "20",
        "--surface",
        "rebuilt",
        "--quiet",
    ]));
    let m = manifest(&out);
    let mut voids_before = 0;
    for f in m["frames"].as_array().unwrap() {
        let r = &f["rebuilt"];
        let after = &r["after"];
        assert_eq!(after["shells"].as_u64(), Some(1), "{r}");
        assert_eq!(after["void_shells"].as_u64(), Some(0), "{r}");
        assert!(after["min_angle_deg"].as_f64().unwrap() >= 0.25, "{r}");
        assert_eq!(after["zero_area"].as_u64(), Some(0), "{r}");
        voids_before += r["before"]["void_shells"].as_u64().unwrap();
        let mesh = morph::geometry::load_mesh(&out.join(f["mesh"].as_str().unwrap()))
            .unwrap()
            .mesh;
        assert!(mesh.topology().is_closed(), "{}", f["mesh"]);
    }
    assert!(
        voids_before > 0,
        "the extraction leaves void shells for cleaning to drop"
    );
}
