//! What a morph writes: PLY point frames, the nodal mass grid file (and its comparison),
//! the manifest, the loss / preview images and the USD file of the whole sequence. Every file is written to a temporary name
//! and renamed, so no reader ever sees half a file.

pub mod frames;
pub mod images;
pub mod massgrid;
pub mod outdir;
pub mod usd;

pub use crate::geometry::mesh::write_atomically;

/// SHA-256 of a file's bytes, as lowercase hex.
pub fn sha256_file(path: &std::path::Path) -> std::io::Result<String> {
    use sha2::{Digest, Sha256};
    let bytes = std::fs::read(path)?;
    let digest = Sha256::digest(&bytes);
    Ok(digest.iter().map(|b| format!("{b:02x}")).collect())
}
