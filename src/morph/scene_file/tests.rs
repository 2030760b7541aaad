//! The scene file's tests: keys, parts, the resolved scene, every knob through `--set`.
use super::*;

#[test]
fn unknown_keys_are_named_with_their_line() {
    let text = "preset = \"draft\"\nresolution = 16\n\n[ground]\nheight = 0.0\nfrction = 0.3\n";
    let e = SceneFile::parse(text, Path::new("shot.toml"), None).unwrap_err();
    assert!(
        e.contains("line 6") && e.contains("`world.ground.frction`") && e.contains("shot.toml"),
        "{e}"
    );
    let e = SceneFile::parse("gravty = [0, -9.8, 0]\n", Path::new("s.toml"), None).unwrap_err();
    assert!(e.contains("line 1") && e.contains("`gravty`"), "{e}");
    let e = SceneFile::parse(
        "{\n  \"resolution\": 16,\n  \"fpz\": 24\n}",
        Path::new("s.json"),
        None,
    )
    .unwrap_err();
    assert!(e.contains("line 3") && e.contains("`fpz`"), "{e}");
    // In a list of tables, the item's index; Young's modulus is a key the file reads.
    let text = "[[colliders]]\nmesh = \"a.obj\"\n[[colliders]]\nmesh = \"b.obj\"\nfriction = 0.2\nsticky = true\n[material]\nyoungs_modulus = 1e5\npoisson_ratio = 0.3\n";
    let e = SceneFile::parse(text, Path::new("s.toml"), None).unwrap_err();
    assert!(
        e.contains("line 6") && e.contains("`world.colliders.1.sticky`"),
        "{e}"
    );
    // A value of the wrong type is reported as such, not as an unknown key.
    let e = SceneFile::parse("resolution = \"big\"\n", Path::new("s.toml"), None).unwrap_err();
    assert!(
        !e.contains("unknown key") && e.contains("resolution"),
        "{e}"
    );
}

#[test]
fn a_key_may_be_given_flat_or_under_its_part_but_not_both() {
    let parse = |text: &str| SceneFile::parse(text, Path::new("s.toml"), None);
    let flat = parse("frames = 49\nresolution = 20\n[optimizer]\niterations = 3\n").unwrap();
    let nested =
        parse("[shot]\nframes = 49\n[body]\nresolution = 20\n[method.optimizer]\niterations = 3\n")
            .unwrap();
    assert_eq!(flat.settings, nested.settings);
    assert_eq!(nested.settings.shot.frames, Some(49));
    let e = parse("frames = 49\n[shot]\nframes = 50\n").unwrap_err();
    assert!(e.contains("`frames` is given twice"), "{e}");
    let e = parse("shot = 3\n").unwrap_err();
    assert!(e.contains("`shot` must be a table"), "{e}");
    let e = parse("[shot]\nresolution = 20\n").unwrap_err();
    assert!(e.contains("unknown key `shot.resolution`"), "{e}");
}

#[test]
fn the_world_is_the_engines_effect_list_in_the_files_units() {
    use crate::engine::scene::{ColliderConfig, EffectConfig};
    let text = "[[world.effects]]\ntype = \"gravity\"\nacceleration = [0.0, -9.81, 0.0]\n\n[[world.effects]]\ntype = \"collider\"\nshape = { kind = \"mesh\", path = \"rock.obj\", scale = 2.0 }\n\n[[world.effects]]\ntype = \"walls\"\nmode = \"slip\"\nthickness = 3\n";
    let s = SceneFile::parse(text, Path::new("/shots/a/shot.toml"), None)
        .unwrap()
        .settings;
    assert!(s.validate().is_ok());
    assert_eq!(
        s.world.effects.len(),
        3,
        "the file's list replaces the preset's"
    );
    assert_eq!(s.world.drag(), 0.0);
    match &s.world.effects[1] {
        EffectConfig::Collider {
            shape: ColliderConfig::Mesh { path, scale, .. },
            friction,
        } => {
            assert_eq!(path, Path::new("/shots/a/rock.obj"), "relative to the file");
            assert_eq!((*scale, *friction), (2.0, 0.5));
        }
        other => panic!("{other:?}"),
    }
    // Without its walls the list is refused.
    let e = SceneFile::parse(
        "[[world.effects]]\ntype = \"drag\"\ncoefficient = 1.0\n",
        Path::new("s.toml"),
        None,
    )
    .unwrap()
    .settings
    .validate()
    .unwrap_err();
    assert!(e.contains("it needs one"), "{e}");
}

#[test]
fn a_file_changes_only_the_keys_it_gives_over_its_preset() {
    let text = "preset = \"draft\"\nresolution = 20\n[material]\ndensity = 80.0\n[optimizer]\niterations = 3\n";
    let s = SceneFile::parse(text, Path::new("a/shot.toml"), None)
        .unwrap()
        .settings;
    let mut want = MorphSettings::preset(Preset::Draft);
    want.body.resolution = 20;
    want.body.material.density = 80.0;
    want.method.optimizer.iterations = 3;
    assert_eq!(s, want);
}

#[test]
fn a_resolution_replaces_the_presets_particle_budget() {
    let parse = |text: &str| {
        SceneFile::parse(text, Path::new("shot.toml"), None)
            .unwrap()
            .settings
    };
    assert!(
        MorphSettings::preset(Preset::Final)
            .body
            .particles
            .is_some()
    );
    let s = parse("preset = \"final\"\nresolution = 40\n");
    assert_eq!((s.body.resolution, s.body.particles), (40, None));
    let s = parse("preset = \"final\"\nresolution = 40\nparticles = 9000\n");
    assert_eq!(s.body.particles, Some(9000));
    let s = parse("preset = \"final\"\n");
    assert_eq!(
        s.body.particles,
        MorphSettings::preset(Preset::Final).body.particles
    );
}

#[test]
fn a_grid_the_file_gives_turns_the_thin_parts_rule_off() {
    let parse = |text: &str| {
        SceneFile::parse(text, Path::new("shot.toml"), None)
            .unwrap()
            .settings
    };
    assert_eq!(parse("").body.thin_across, 2.5);
    assert_eq!(parse("resolution = 40\n").body.thin_across, 0.0);
    assert_eq!(parse("particles_per_cell = 3\n").body.thin_across, 0.0);
    assert_eq!(
        parse("resolution = 40\nthin_across = 3.0\n")
            .body
            .thin_across,
        3.0
    );
    let negative = SceneFile::parse("thin_across = -1.0\n", Path::new("shot.toml"), None);
    assert!(negative.is_err() || negative.unwrap().settings.validate().is_err());
}

#[test]
fn the_resolved_scene_reads_back_to_the_same_settings() {
    let mut s = MorphSettings::preset(Preset::Final);
    let world = "gravity = [0.0, -9.81, 0.0]\n[ground]\nheight = -1.0\nfriction = 0.2\n";
    s.world = SceneFile::parse(world, Path::new("w.toml"), None)
        .unwrap()
        .settings
        .world;
    assert_eq!(s.world.ground(), Some((-1.0, 0.2)));
    s.shot.at = vec![10, 20];
    s.shot.fps = None;
    s.shot.frame_every = 4;
    s.method.dt = Some(1e-3);
    let text = SceneFile::resolved(
        &s,
        Path::new("/m/a.obj"),
        &["/m/b.obj".into(), "/m/c.obj".into()],
    );
    let back = SceneFile::parse(&text, Path::new("/out/scene.toml"), None).unwrap();
    assert_eq!(back.settings, s);
    assert_eq!(back.source, Some(PathBuf::from("/m/a.obj")));
    assert_eq!(back.targets.len(), 2);
}

/// A value other than `default` (a knob's, as a scene file writes it) within its kind.
fn another(default: &str, range: &str) -> String {
    if let Ok(i) = default.parse::<i64>() {
        return (i + 1).to_string();
    }
    if let Ok(f) = default.parse::<f64>() {
        return if f == 0.0 {
            "0.25".into()
        } else {
            format!("{:?}", f * 0.5)
        };
    }
    if default == "none" {
        // The unset knobs: a time step, or a count.
        return if range.starts_with('>') {
            "0.001".into()
        } else {
            "3".into()
        };
    }
    // An enumeration: its first other value.
    let other = range
        .split(", ")
        .find(|v| *v != default)
        .expect("two values");
    format!("\"{other}\"")
}

/// Every knob set by `--set` (by its key, its part's path and any alias), by a scene file
/// and by the resolved `OUT/scene.toml` gives the same settings, and changes that knob.
#[test]
fn every_knob_round_trips_through_set_the_scene_file_and_the_resolved_scene() {
    use crate::morph::settings::knobs::{ALIASES, knobs, value_of};
    let base = MorphSettings::preset(Preset::Default);
    for k in knobs() {
        let default = value_of(&base, k.part, k.key);
        let value = another(&default, &k.range);
        let bare = value.trim_matches('"');
        let by_key = with_keys(base.clone(), &[format!("{}={bare}", k.key)]).unwrap();
        assert_eq!(
            value_of(&by_key, k.part, k.key),
            bare,
            "--set {}={bare}",
            k.key
        );
        let by_part = format!("{}.{}={value}", k.part, k.key.replace('_', "-"));
        assert_eq!(
            with_keys(base.clone(), &[by_part.clone()]).unwrap(),
            by_key,
            "--set {by_part}"
        );
        for (alias, path) in ALIASES {
            if path.join(".") == k.key {
                let a = with_keys(base.clone(), &[format!("{alias}={bare}")]).unwrap();
                assert_eq!(a, by_key, "alias {alias}");
                let scene = format!("{alias} = {value}\n");
                let read = SceneFile::parse(&scene, Path::new("s.toml"), None).unwrap();
                assert_eq!(read.settings, by_key, "scene file alias {alias}");
            }
        }
        let (table, key) = match k.key.rsplit_once('.') {
            Some((inner, key)) => (format!("{}.{inner}", k.part), key),
            None => (k.part.to_string(), k.key),
        };
        let scene = format!("[{table}]\n{key} = {value}\n");
        let read = SceneFile::parse(&scene, Path::new("s.toml"), None).unwrap();
        assert_eq!(read.settings, by_key, "scene file {scene}");
        let resolved = SceneFile::resolved(&by_key, Path::new("/m/a.obj"), &["/m/b.obj".into()]);
        let back = SceneFile::parse(&resolved, Path::new("/o/scene.toml"), None).unwrap();
        assert_eq!(back.settings, by_key, "OUT/scene.toml of {}", k.key);
    }
}

#[test]
fn a_bad_set_is_one_line_naming_the_keys() {
    let base = MorphSettings::default();
    for (pair, says) in [
        ("bogus=1", "unknown key `bogus`; the keys: "),
        ("iterations", "give KEY=VALUE"),
        ("iterations=many", "in `method.optimizer.iterations`"),
        ("optimizer.bogus=1", "unknown key `method.optimizer.bogus`"),
    ] {
        let e = with_keys(base.clone(), &[pair.to_string()]).unwrap_err();
        assert!(e.contains(says) && !e.contains('\n'), "{pair}: {e}");
    }
    let e = with_keys(
        base,
        &["iterations=3".into(), "optimizer.iterations=4".into()],
    );
    assert!(e.unwrap_err().contains("given twice"));
}
