//! `morph bench morph`: whole morphs at fixed settings, as a user runs them (every output
//! written), one JSON line each: wall time, optimizer evaluations, particles and the quality
//! judge's verdict. The performance goals of whole morphs are measured here, never in a test.

use crate::morph::output::{OutputRequest, morph_to_folder};
use crate::morph::{MorphSettings, Preset, memory::MemoryLimit};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A fixed whole-morph benchmark.
pub struct MorphCase {
    pub name: &'static str,
    pub source: &'static str,
    /// A mesh in the shared meshes folder.
    pub target: &'static str,
    pub preset: Preset,
}

/// The cases: sphere -> spot at the default preset, sphere -> stanford-bunny at `final`.
pub const CASES: [MorphCase; 2] = [
    MorphCase {
        name: "spot-default",
        source: "assets/sphere.obj",
        target: "spot.obj",
        preset: Preset::Default,
    },
    MorphCase {
        name: "bunny-final",
        source: "assets/sphere.obj",
        target: "stanford-bunny.obj",
        preset: Preset::Final,
    },
];

/// Runs the cases named in `only` (all when empty), with the target meshes from `meshes`;
/// each writes into a folder of its own under the system's temporary folder, removed after.
pub fn run(meshes: &Path, only: &[String]) -> anyhow::Result<()> {
    for case in CASES
        .iter()
        .filter(|c| only.is_empty() || only.iter().any(|o| o == c.name))
    {
        let target = meshes.join(case.target);
        let out: PathBuf =
            std::env::temp_dir().join(format!("morph-bench-{}-{}", case.name, std::process::id()));
        // The folder must be this run's own: it is removed afterwards.
        if out.exists() || crate::io::outdir::partial_dir(&out).exists() {
            anyhow::bail!(
                "{}: '{}' exists; remove it or rerun (the benchmark deletes only what it made)",
                case.name,
                out.display()
            );
        }
        let settings = MorphSettings::preset(case.preset)
            .checked()
            .map_err(anyhow::Error::msg)?;
        let clock = Instant::now();
        let summary = morph_to_folder(
            &settings,
            Path::new(case.source),
            &[target],
            &OutputRequest {
                out: &out,
                overwrite: false,
                resume: false,
                stop: None,
                memory_limit: MemoryLimit::Auto,
                scene: None,
                on_frame: None,
            },
            |_| {},
        );
        let wall = clock.elapsed().as_secs_f64();
        let manifest: Option<serde_json::Value> = std::fs::read(out.join("manifest.json"))
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok());
        // This run made the folder (and its staging folder): removed whatever happened.
        let _ = std::fs::remove_dir_all(&out);
        let _ = std::fs::remove_dir_all(crate::io::outdir::partial_dir(&out));
        let summary = summary.map_err(|e| anyhow::anyhow!("{}: {e}", case.name))?;
        let evaluations: u64 = manifest
            .as_ref()
            .and_then(|m| m["segments"].as_array().cloned())
            .unwrap_or_default()
            .iter()
            .filter_map(|s| s["evaluations"].as_u64())
            .sum();
        let quality = summary.quality.as_ref();
        println!(
            "{}",
            json!({
                "bench": "morph", "case": case.name, "source": case.source,
                "target": case.target, "preset": case.preset,
                "threads": rayon::current_num_threads(),
                "wall_s": wall, "evaluations": evaluations,
                "particles": summary.particles, "frames": summary.frames,
                "iou": quality.map(|q| q.iou), "fill": quality.map(|q| q.fill),
            })
        );
    }
    Ok(())
}
