//! Errors about input meshes: each names the file and says what is wrong in one line.

use std::path::PathBuf;
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum MeshError {
    #[error("cannot read mesh '{}': {reason}", path.display())]
    Unreadable { path: PathBuf, reason: String },

    #[error("mesh '{}' is an empty file", path.display())]
    Empty { path: PathBuf },

    #[error("mesh '{}': unknown format (expected a .obj or .ply file)", path.display())]
    UnknownFormat { path: PathBuf },

    #[error("mesh '{}' is not a valid {format} file: {reason}", path.display())]
    Malformed {
        path: PathBuf,
        format: &'static str,
        reason: String,
    },

    #[error("mesh '{}': {reason}", path.display())]
    Invalid { path: PathBuf, reason: String },

    #[error("mesh '{}': cannot decide its inside: {reason}", path.display())]
    NoInside { path: PathBuf, reason: String },

    #[error("{0}")]
    BadOption(String),
}
