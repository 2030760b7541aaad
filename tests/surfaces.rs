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
