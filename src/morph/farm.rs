//! Farm job templates: an Open Job Description template that runs a morph on a render farm
//! (`morph farm-template openjd`). The template carries the resolved scene (every setting, the
//! meshes' absolute paths) as an embedded file, so the farm runs the same morph bit for bit,
//! and runs it with `--resume`: a task re-queued after a pre-emption continues from the last
//! completed segment, never starts over. Progress is reported the farm's way
//! (`--progress openjd`); a cancel sends SIGTERM first, which keeps the checkpoint.

use super::MorphSettings;
use super::scene_file::SceneFile;
use std::path::{Path, PathBuf};

/// The Open Job Description job template (specification `jobtemplate-2023-09`, JSON) for the
/// morph of `source` into `targets` with `settings` into `out`, run by the `morph` executable
/// at `command` (both parameters the farm may change at submission). The template is to be
/// written into the folder `template_dir`: the specification wants a path's default relative
/// to it.
pub fn openjd_template(
    settings: &MorphSettings,
    source: &Path,
    targets: &[PathBuf],
    out: &Path,
    command: &Path,
    template_dir: &Path,
) -> String {
    let absolute = |p: &Path| {
        std::path::absolute(p)
            .unwrap_or_else(|_| p.to_path_buf())
            .display()
            .to_string()
    };
    let stem = |p: &Path| {
        p.file_stem()
            .map_or("mesh".into(), |s| s.to_string_lossy().into_owned())
    };
    let name = format!(
        "morph {} to {}",
        stem(source),
        targets.last().map_or("mesh".into(), |t| stem(t))
    );
    let template = serde_json::json!({
        "specificationVersion": "jobtemplate-2023-09",
        "name": name,
        "parameterDefinitions": [
            {
                "name": "MorphCommand",
                "type": "STRING",
                "description": "The morph executable on the workers.",
                "default": absolute(command),
            },
            {
                "name": "Output",
                "type": "PATH",
                "objectType": "DIRECTORY",
                "dataFlow": "OUT",
                "description": "The morph's output folder (written in Output.partial until complete).",
                "default": relative(Path::new(&absolute(out)), Path::new(&absolute(template_dir)))
                    .display()
                    .to_string(),
            },
        ],
        "steps": [{
            "name": "Morph",
            "script": {
                "embeddedFiles": [{
                    "name": "Scene",
                    "type": "TEXT",
                    "filename": "scene.toml",
                    "data": SceneFile::resolved(settings, source, targets),
                }],
                "actions": {
                    "onRun": {
                        "command": "{{Param.MorphCommand}}",
                        "args": [
                            "--scene", "{{Task.File.Scene}}",
                            "-o", "{{Param.Output}}",
                            "--resume",
                            "--progress", "openjd",
                        ],
                        "cancelation": {
                            "mode": "NOTIFY_THEN_TERMINATE",
                            "notifyPeriodInSeconds": 30,
                        },
                    },
                },
            },
        }],
    });
    serde_json::to_string_pretty(&template).expect("plain data")
}

/// `path` relative to the folder `from` (both absolute): `../x/y` when they part below the root.
fn relative(path: &Path, from: &Path) -> PathBuf {
    let (a, b): (Vec<_>, Vec<_>) = (path.components().collect(), from.components().collect());
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut r: PathBuf = b[common..].iter().map(|_| "..").collect();
    r.extend(&a[common..]);
    if r.as_os_str().is_empty() {
        r.push(".");
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_defaults_are_relative_to_the_template() {
        let r = |p: &str, f: &str| relative(Path::new(p), Path::new(f)).display().to_string();
        assert_eq!(r("/shots/a/out", "/shots/a"), "out");
        assert_eq!(r("/shots/b/out", "/shots/a/jobs"), "../../b/out");
        assert_eq!(r("/shots/a", "/shots/a"), ".");
    }

    #[test]
    fn the_template_runs_the_resolved_scene_with_resume() {
        let settings = MorphSettings::default();
        let text = openjd_template(
            &settings,
            Path::new("/m/sphere.obj"),
            &[PathBuf::from("/m/bunny.obj")],
            Path::new("/shots/out"),
            Path::new("/usr/bin/morph"),
            Path::new("/shots/jobs"),
        );
        let t: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(t["specificationVersion"], "jobtemplate-2023-09");
        assert_eq!(t["parameterDefinitions"][1]["default"], "../out");
        let run = &t["steps"][0]["script"]["actions"]["onRun"];
        let args: Vec<&str> = run["args"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a.as_str().unwrap())
            .collect();
        assert!(
            args.contains(&"--resume") && args.windows(2).any(|w| w == ["--progress", "openjd"])
        );
        // The embedded scene reads back to the same settings.
        let scene = t["steps"][0]["script"]["embeddedFiles"][0]["data"]
            .as_str()
            .unwrap();
        let back = SceneFile::parse(scene, Path::new("/tmp/scene.toml"), None).unwrap();
        assert_eq!(back.settings, settings);
        assert_eq!(back.targets, vec![PathBuf::from("/m/bunny.obj")]);
    }
}
