//! Checkpoints of a chain run, kept in the staging folder so that an interrupted run (Ctrl-C,
//! SIGTERM, a pre-empted farm node, `kill -9`) continues bit for bit with `--resume`.
//!
//! ```text
//! OUT.partial/run.json                      who the run is: tool version, input hashes, settings
//! OUT.partial/checkpoint/progress.json      pass, segments done, frames, records, file names
//! OUT.partial/checkpoint/state_pP_sK.bin    full particle state (x, v, C, F) after segment K of pass P
//! OUT.partial/checkpoint/controls_K_pP.bin  segment K's controls as pass P left them
//! OUT.partial/checkpoint/preview_NNNNNN.bin  world positions of a preview frame (written by
//!                                           the folder writer, read back on resume)
//! ```
//!
//! Binary files are `MORPHCK1`, a u64 count, then that many little-endian f64: exact bits.
//! Every file is written to a temporary name and renamed; `progress.json` is written last and
//! names the files it belongs with, so a run killed at any instant leaves either the old or
//! the new checkpoint whole. Files no longer named are removed after the new one is in place.

use super::{IterationRecord, MorphError, RunProgress, SegmentRecord, segment::Layers};
use crate::io::write_atomically;
use crate::mpm::State;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"MORPHCK1";
const FORMAT: u32 = 1;
/// The checkpoint folder inside the staging folder.
pub const FOLDER: &str = "checkpoint";
const PROGRESS: &str = "progress.json";

#[derive(Serialize, Deserialize)]
struct ProgressFile {
    format: u32,
    pass: usize,
    segments_done: usize,
    frames: usize,
    elapsed_s: f64,
    state: String,
    /// Per segment: its controls file, or none while they are still zero.
    controls: Vec<Option<String>>,
    iterations: Vec<IterationRecord>,
    segments: Vec<SegmentRecord>,
}

/// A file name this module writes: a plain name, never a path (a damaged or edited
/// `progress.json` must not make a run read or delete anything outside its folder).
fn is_checkpoint_name(name: &str) -> bool {
    (name.starts_with("state_") || name.starts_with("controls_"))
        && name.ends_with(".bin")
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.')
}

fn io_err(what: &str, path: &Path, e: impl std::fmt::Display) -> MorphError {
    MorphError::Output(format!(
        "cannot {what} checkpoint '{}': {e}",
        path.display()
    ))
}

/// Writes `values` as a checkpoint array.
pub fn write_f64s(path: &Path, values: &[f64]) -> std::io::Result<()> {
    write_atomically(path, |w| {
        w.write_all(MAGIC)?;
        w.write_all(&(values.len() as u64).to_le_bytes())?;
        let mut buf = Vec::with_capacity(values.len() * 8);
        for v in values {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&buf)
    })
}

/// Reads a checkpoint array of exactly `expected` values.
pub fn read_f64s(path: &Path, expected: usize) -> Result<Vec<f64>, String> {
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    if bytes.len() < 16 || &bytes[..8] != MAGIC {
        return Err("not a morph checkpoint array".into());
    }
    let n = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
    if n != expected as u64 || (bytes.len() - 16) as u64 != 8 * n {
        return Err(format!(
            "holds {n} values in {} bytes, expected {expected}",
            bytes.len() - 16
        ));
    }
    Ok(bytes[16..]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect())
}

fn flatten_state(s: &State) -> Vec<f64> {
    let mut out = Vec::with_capacity(s.len() * 24);
    out.extend(s.x.iter().flat_map(|v| v.iter().copied()));
    out.extend(s.v.iter().flat_map(|v| v.iter().copied()));
    out.extend(s.c.iter().flat_map(|m| m.iter().copied()));
    out.extend(s.f.iter().flat_map(|m| m.iter().copied()));
    out
}

fn unflatten_state(data: &[f64], n: usize) -> State {
    let vec3 = |k: usize, p: usize| Vector3::from_column_slice(&data[k * n + 3 * p..][..3]);
    let mat3 = |off: usize, p: usize| Matrix3::from_column_slice(&data[off + 9 * p..][..9]);
    State {
        x: (0..n).map(|p| vec3(0, p)).collect(),
        v: (0..n).map(|p| vec3(3, p)).collect(),
        c: (0..n).map(|p| mat3(6 * n, p)).collect(),
        f: (0..n).map(|p| mat3(15 * n, p)).collect(),
    }
}

/// Writes the checkpoint after segment `changed` completed (only that segment's controls
/// are new), then removes the files the previous checkpoint named and this one does not.
pub fn save(dir: &Path, p: &RunProgress, changed: usize) -> Result<(), MorphError> {
    let folder = dir.join(FOLDER);
    std::fs::create_dir_all(&folder).map_err(|e| io_err("create", &folder, e))?;
    let progress_path = folder.join(PROGRESS);
    let old: Option<ProgressFile> = std::fs::read(&progress_path)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok());
    let mut controls = old
        .as_ref()
        .map(|o| o.controls.clone())
        .unwrap_or_else(|| vec![None; p.controls.len()]);
    controls.resize(p.controls.len(), None);

    let name = format!("controls_{changed:04}_p{}.bin", p.pass);
    let flat: Vec<f64> = p.controls[changed]
        .iter()
        .flat_map(|layer| layer.iter().flat_map(|m| m.iter().copied()))
        .collect();
    let path = folder.join(&name);
    write_f64s(&path, &flat).map_err(|e| io_err("write", &path, e))?;
    controls[changed] = Some(name);

    let state = format!("state_p{}_s{}.bin", p.pass, p.segments_done);
    let path = folder.join(&state);
    write_f64s(&path, &flatten_state(&p.state)).map_err(|e| io_err("write", &path, e))?;

    let file = ProgressFile {
        format: FORMAT,
        pass: p.pass,
        segments_done: p.segments_done,
        frames: p.frames,
        elapsed_s: p.elapsed_s,
        state,
        controls,
        iterations: p.iterations.clone(),
        segments: p.segments.clone(),
    };
    let json = serde_json::to_vec(&file).map_err(|e| io_err("encode", &progress_path, e))?;
    write_atomically(&progress_path, |w| w.write_all(&json))
        .map_err(|e| io_err("write", &progress_path, e))?;

    // The new checkpoint is whole: drop what only the old one named.
    if let Some(old) = old {
        let keep: Vec<&String> = std::iter::once(&file.state)
            .chain(file.controls.iter().flatten())
            .collect();
        for stale in std::iter::once(&old.state).chain(old.controls.iter().flatten()) {
            if !keep.contains(&stale) && is_checkpoint_name(stale) {
                let _ = std::fs::remove_file(folder.join(stale));
            }
        }
    }
    Ok(())
}

/// Whether the staging folder holds a checkpoint.
pub fn exists(dir: &Path) -> bool {
    dir.join(FOLDER).join(PROGRESS).is_file()
}

/// Reads the checkpoint of a run of `particles` particles whose segment `k` has `layers[k]`
/// control layers; `Ok(None)` when there is none yet.
pub fn load(
    dir: &Path,
    particles: usize,
    layers: &[usize],
) -> Result<Option<RunProgress>, MorphError> {
    let segments = layers.len();
    let folder: PathBuf = dir.join(FOLDER);
    let progress_path = folder.join(PROGRESS);
    if !progress_path.is_file() {
        return Ok(None);
    }
    let damaged = |what: &Path, e: String| {
        MorphError::Resume(format!(
            "checkpoint '{}' is damaged ({e}); start over with --overwrite",
            what.display()
        ))
    };
    let bytes =
        std::fs::read(&progress_path).map_err(|e| damaged(&progress_path, e.to_string()))?;
    let file: ProgressFile =
        serde_json::from_slice(&bytes).map_err(|e| damaged(&progress_path, e.to_string()))?;
    if file.format != FORMAT || file.controls.len() != segments {
        return Err(damaged(
            &progress_path,
            "format or segment count differs".into(),
        ));
    }
    let names = std::iter::once(&file.state).chain(file.controls.iter().flatten());
    if let Some(bad) = names.into_iter().find(|n| !is_checkpoint_name(n)) {
        return Err(damaged(&progress_path, format!("bad file name {bad:?}")));
    }
    let path = folder.join(&file.state);
    let state = unflatten_state(
        &read_f64s(&path, particles * 24).map_err(|e| damaged(&path, e))?,
        particles,
    );
    let mut controls = Vec::with_capacity(segments);
    for (entry, &layers) in file.controls.iter().zip(layers) {
        let layers_k: Layers = match entry {
            // Never optimized: zero (see `RunProgress::controls`).
            None => Vec::new(),
            Some(name) => {
                let path = folder.join(name);
                let data =
                    read_f64s(&path, layers * particles * 9).map_err(|e| damaged(&path, e))?;
                data.chunks_exact(particles * 9)
                    .map(|layer| {
                        layer
                            .chunks_exact(9)
                            .map(Matrix3::from_column_slice)
                            .collect()
                    })
                    .collect()
            }
        };
        controls.push(layers_k);
    }
    Ok(Some(RunProgress {
        pass: file.pass,
        segments_done: file.segments_done,
        state,
        controls,
        iterations: file.iterations,
        segments: file.segments,
        frames: file.frames,
        elapsed_s: file.elapsed_s,
    }))
}

/// Which checkpoint a progress file describes, for messages: "pass 1 of 2, segment 5 of 12".
pub fn describe(p: &RunProgress, passes: usize, segments: usize) -> String {
    format!(
        "pass {} of {passes}, {} of {segments} segments done",
        p.pass + 1,
        p.segments_done
    )
}
