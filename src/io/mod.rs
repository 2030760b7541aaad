//! What a morph writes: PLY point frames, the nodal mass grid file (and its comparison),
//! the manifest, the loss / preview images and the USD file of the whole sequence. Every file is written to a temporary name
//! and renamed, so no reader ever sees half a file.

pub mod frames;
pub mod images;
pub mod massgrid;
pub mod outdir;
pub mod usd;
mod usdc_fix;
pub mod vdb;

pub use crate::geometry::mesh::write_atomically;

/// SHA-256 of a file's bytes, as lowercase hex: a regular file of at most `max` bytes
/// (see [`crate::files`]), streamed.
pub fn sha256_file(path: &std::path::Path, max: u64) -> std::io::Result<String> {
    use sha2::{Digest, Sha256};
    use std::io::Read;
    let (file, _) = crate::files::open(path, max)?;
    let mut hasher = Sha256::new();
    let mut reader = file.take(max + 1);
    let mut buf = vec![0u8; 1 << 16];
    let mut total = 0u64;
    loop {
        let n = reader.read(&mut buf)?;
        if n == 0 {
            break;
        }
        total += n as u64;
        hasher.update(&buf[..n]);
    }
    if total > max {
        return Err(std::io::Error::other(
            "it grew past its size limit while being read",
        ));
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}
