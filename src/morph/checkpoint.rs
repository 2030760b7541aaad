//! Checkpoints of a chain run, kept in the staging folder so that an interrupted run (Ctrl-C,
//! SIGTERM, a pre-empted farm node, `kill -9`) continues bit for bit with `--resume`.
//!
//! ```text
//! OUT.partial/run.json                      who the run is: tool version, input hashes, settings
//! OUT.partial/checkpoint/progress.json      pass, segments done, frames, records, file names
//! OUT.partial/checkpoint/state_pP_sK.bin    full particle state (x, v, C, F) after segment K of pass P
//! OUT.partial/checkpoint/controls_K_pP.bin  segment K's controls as pass P left them
//! OUT.partial/checkpoint/controls_K_pP_sJ.bin  where segment K's optimization starts, as the
//!                                           look-ahead window of pass P's segment J-1 left it
//! OUT.partial/checkpoint/preview_NNNNNN.bin  world positions of a preview frame (written by
//!                                           the folder writer, read back on resume)
//! ```
//!
//! Every checkpoint file is sealed with the run's identity and a SHA-256 of its content, so
//! that a flipped bit, a truncation, an edit or a file of another run is refused by name
//! instead of continuing into a different result:
//!
//! - binary files are `MORPHCK2`, the run id (64 hex digits), a u64 count, that many
//!   little-endian f64 (exact bits), then the SHA-256 of everything before it;
//! - JSON files are `{"format", "run_id", "sha256", "body"}`, the hash over the run id and the
//!   body's exact bytes.
//!
//! Every file is written to a temporary name and renamed; `progress.json` is written last and
//! names the files it belongs with, so a run killed at any instant leaves either the old or
//! the new checkpoint whole. Files no longer named are removed after the new one is in place.
//! A finished run removes `progress.json` before the rest ([`remove`]).

use super::{IterationRecord, MorphError, RunProgress, SegmentRecord, segment::Layers};
use crate::engine::mpm::State;
use crate::io::write_atomically;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"MORPHCK2";
const FORMAT: u32 = 2;
/// Bytes of a binary checkpoint file around its values: magic, run id, count, digest.
const FRAME_BYTES: usize = 8 + 64 + 8 + 32;
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

fn sha256(parts: &[&[u8]]) -> [u8; 32] {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    for p in parts {
        h.update(p);
    }
    h.finalize().into()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn check_run_id(run_id: &str) {
    debug_assert!(run_id.len() == 64, "a run id is a SHA-256 in hex");
}

/// Writes `values` as a checkpoint array of run `run_id`.
pub fn write_f64s(path: &Path, run_id: &str, values: &[f64]) -> std::io::Result<()> {
    check_run_id(run_id);
    let mut buf = Vec::with_capacity(FRAME_BYTES + values.len() * 8);
    buf.extend_from_slice(MAGIC);
    buf.extend_from_slice(run_id.as_bytes());
    buf.extend_from_slice(&(values.len() as u64).to_le_bytes());
    for v in values {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    let digest = sha256(&[&buf]);
    buf.extend_from_slice(&digest);
    write_atomically(path, |w| w.write_all(&buf))
}

/// Reads a checkpoint array of exactly `expected` values written by run `run_id`.
pub fn read_f64s(path: &Path, run_id: &str, expected: usize) -> Result<Vec<f64>, String> {
    let size = expected
        .checked_mul(8)
        .and_then(|b| b.checked_add(FRAME_BYTES))
        .ok_or("too many values")?;
    let bytes = crate::files::read(path, size as u64).map_err(|e| e.to_string())?;
    if bytes.len() < FRAME_BYTES || &bytes[..8] != MAGIC {
        return Err("not a morph checkpoint array of this version".into());
    }
    let (body, digest) = bytes.split_at(bytes.len() - 32);
    if sha256(&[body]) != digest {
        return Err("its checksum does not match its content".into());
    }
    if &body[8..72] != run_id.as_bytes() {
        return Err("it belongs to another run".into());
    }
    let n = u64::from_le_bytes(body[72..80].try_into().expect("8 bytes"));
    if n != expected as u64 || bytes.len() != size {
        return Err(format!("holds {n} values, expected {expected}"));
    }
    Ok(body[80..]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect())
}

#[derive(Serialize, Deserialize)]
struct Sealed<B> {
    format: u32,
    run_id: String,
    sha256: String,
    body: B,
}

/// Writes `value` as a sealed JSON checkpoint file of run `run_id`.
pub fn write_json<T: Serialize>(path: &Path, run_id: &str, value: &T) -> std::io::Result<()> {
    check_run_id(run_id);
    let body = serde_json::value::to_raw_value(value).map_err(std::io::Error::other)?;
    let sealed = Sealed {
        format: FORMAT,
        run_id: run_id.to_string(),
        sha256: hex(&sha256(&[run_id.as_bytes(), body.get().as_bytes()])),
        body,
    };
    let json = serde_json::to_vec(&sealed).map_err(std::io::Error::other)?;
    write_atomically(path, |w| w.write_all(&json))
}

/// Reads a sealed JSON checkpoint file written by run `run_id`.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path, run_id: &str) -> Result<T, String> {
    let bytes =
        crate::files::read(path, crate::files::MANIFEST_BYTES).map_err(|e| e.to_string())?;
    // A parser quotes what it failed on whole (a damaged field can be megabytes): keep it short.
    let parse_error = |e: serde_json::Error| crate::files::short_message(&e.to_string());
    let sealed: Sealed<Box<serde_json::value::RawValue>> =
        serde_json::from_slice(&bytes).map_err(parse_error)?;
    if sealed.format != FORMAT {
        return Err(format!(
            "format {} (this morph reads {FORMAT})",
            sealed.format
        ));
    }
    let digest = hex(&sha256(&[
        sealed.run_id.as_bytes(),
        sealed.body.get().as_bytes(),
    ]));
    if digest != sealed.sha256 {
        return Err("its checksum does not match its content".into());
    }
    if sealed.run_id != run_id {
        return Err("it belongs to another run".into());
    }
    serde_json::from_str(sealed.body.get()).map_err(parse_error)
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
/// are new, and those its look-ahead window left for the next `p.ahead`), then removes the
/// files the previous checkpoint named and this one does not.
pub fn save(dir: &Path, run_id: &str, p: &RunProgress, changed: usize) -> Result<(), MorphError> {
    let folder = dir.join(FOLDER);
    std::fs::create_dir_all(&folder).map_err(|e| io_err("create", &folder, e))?;
    let progress_path = folder.join(PROGRESS);
    let old: Option<ProgressFile> = read_json(&progress_path, run_id).ok();
    let mut controls = old
        .as_ref()
        .map(|o| o.controls.clone())
        .unwrap_or_else(|| vec![None; p.controls.len()]);
    controls.resize(p.controls.len(), None);

    // Its controls, and those its look-ahead window left for the segments after it. The
    // latter are named for this checkpoint: the previous one may name a file of the same
    // segment, which must stay as it was until the new progress file replaces it.
    #[allow(clippy::needless_range_loop)] // k names the file as well as indexing two lists
    for k in changed..=changed + p.ahead {
        let name = if k == changed {
            format!("controls_{k:04}_p{}.bin", p.pass)
        } else {
            format!("controls_{k:04}_p{}_s{}.bin", p.pass, p.segments_done)
        };
        let flat: Vec<f64> = p.controls[k]
            .iter()
            .flat_map(|layer| layer.iter().flat_map(|m| m.iter().copied()))
            .collect();
        let path = folder.join(&name);
        write_f64s(&path, run_id, &flat).map_err(|e| io_err("write", &path, e))?;
        controls[k] = Some(name);
    }

    let state = format!("state_p{}_s{}.bin", p.pass, p.segments_done);
    let path = folder.join(&state);
    write_f64s(&path, run_id, &flatten_state(&p.state)).map_err(|e| io_err("write", &path, e))?;

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
    write_json(&progress_path, run_id, &file).map_err(|e| io_err("write", &progress_path, e))?;

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

/// Removes the checkpoint of a complete run. `progress.json` goes first: it is what makes
/// the folder a checkpoint, so a run killed while the rest is being deleted leaves no
/// checkpoint naming files that are gone (a `--resume` then finds the finished folder).
pub fn remove(dir: &Path) -> Result<(), MorphError> {
    let folder = dir.join(FOLDER);
    let progress = folder.join(PROGRESS);
    match std::fs::remove_file(&progress) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(io_err("remove", &progress, e)),
    }
    match std::fs::remove_dir_all(&folder) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io_err("remove", &folder, e)),
    }
}

/// Whether the staging folder holds a checkpoint.
pub fn exists(dir: &Path) -> bool {
    dir.join(FOLDER).join(PROGRESS).is_file()
}

/// Reads the checkpoint of run `run_id`, of `particles` particles whose segment `k` has
/// `layers[k]` control layers; `Ok(None)` when there is none yet. A damaged file (or one of
/// another run) is refused, naming it.
pub fn load(
    dir: &Path,
    run_id: &str,
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
            "checkpoint file '{}' is damaged or not this run's ({e}); start over with --overwrite",
            what.display()
        ))
    };
    let file: ProgressFile =
        read_json(&progress_path, run_id).map_err(|e| damaged(&progress_path, e))?;
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
        &read_f64s(&path, run_id, particles * 24).map_err(|e| damaged(&path, e))?,
        particles,
    );
    let mut controls = Vec::with_capacity(segments);
    for (entry, &layers) in file.controls.iter().zip(layers) {
        let layers_k: Layers = match entry {
            // Never optimized: zero (see `RunProgress::controls`).
            None => Vec::new(),
            Some(name) => {
                let path = folder.join(name);
                let data = read_f64s(&path, run_id, layers * particles * 9)
                    .map_err(|e| damaged(&path, e))?;
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
        ahead: 0,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A field made a long string (as a damaged or edited file can have it) is refused in a
    /// short message: the parser's own message quotes the whole string.
    #[test]
    fn a_long_string_in_a_sealed_file_gives_a_short_refusal() {
        let dir = std::env::temp_dir().join(format!("morph-sealed-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sealed.json");
        let run_id = "ab".repeat(32);
        write_json(&path, &run_id, &vec![1.0f64, 2.0]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let long = format!("\"{}dims\"", "2".repeat(60_000));
        let damaged = text.replacen(
            &format!("\"format\":{FORMAT}"),
            &format!("\"format\":{long}"),
            1,
        );
        assert_ne!(damaged, text);
        std::fs::write(&path, damaged).unwrap();
        let e = read_json::<Vec<f64>>(&path, &run_id).unwrap_err();
        assert!(e.len() < 300, "{} bytes: {}", e.len(), &e[..200]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
