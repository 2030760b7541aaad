//! The likeness of a written morph to its target, recomputed from its files alone: the last
//! frame's surface as written and the target mesh placed by the manifest's `target` map. What
//! `morph liken OUT` prints, and the check that the manifest's own figure describes the files.

use super::manifest::Manifest;
use crate::geometry::likeness::{Likeness, likeness};
use crate::geometry::{MeshError, load_mesh};
use crate::morph::MorphError;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Which of a morph's surfaces to liken to the target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WrittenSurface {
    /// `meshes/`: the surface rebuilt from the particles.
    Rebuilt,
    /// `carried/`: the source's own mesh carried by the particles.
    Carried,
}

/// The last frame's `surface` in the morph output `dir` against its final target.
pub fn written_likeness(dir: &Path, surface: WrittenSurface) -> Result<Likeness, MorphError> {
    let manifest_path = dir.join(super::MANIFEST);
    let bad = |reason: String| MorphError::Output(format!("'{}': {reason}", dir.display()));
    let bytes = crate::files::read(&manifest_path, crate::files::MANIFEST_BYTES)
        .map_err(|e| bad(format!("cannot read its manifest.json: {e}")))?;
    let manifest: Manifest = serde_json::from_slice(&bytes).map_err(|e| {
        bad(format!(
            "manifest.json is not a morph manifest: {}",
            crate::files::short_message(&e.to_string())
        ))
    })?;
    let last = manifest
        .frames
        .last()
        .ok_or_else(|| bad("its manifest lists no frames".into()))?;
    let file = match surface {
        WrittenSurface::Rebuilt => last.mesh.as_ref(),
        WrittenSurface::Carried => last.carried.as_ref(),
    }
    .ok_or_else(|| bad("the run wrote no such surface (see --surface)".into()))?;
    let written = load_mesh(&dir.join(file))?.mesh;
    let target_file = manifest
        .keyframes
        .last()
        .map(|k| k.target.clone())
        .or_else(|| manifest.inputs.get(1).map(|i| i.path.clone()))
        .ok_or_else(|| bad("its manifest names no target".into()))?;
    let target = load_mesh(&find_input(dir, Path::new(&target_file)))?.mesh;
    let t = &manifest.target;
    let placed = target.transformed(t.scale, &Vector3::from(t.translation));
    likeness(&written, &placed).ok_or_else(|| {
        MorphError::Mesh(MeshError::Invalid {
            path: dir.join(file),
            reason: "no triangle of non-zero area".into(),
        })
    })
}

/// An input as the manifest names it: as given when that exists from here, else beside
/// the output folder (a relative path written from the folder's parent).
fn find_input(dir: &Path, path: &Path) -> PathBuf {
    if path.is_relative()
        && !path.exists()
        && let Some(parent) = dir.parent()
    {
        return parent.join(path);
    }
    path.to_path_buf()
}
