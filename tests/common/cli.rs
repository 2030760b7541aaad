//! Running the `morph` binary from a test: the repository root, a scratch folder per test,
//! the command and the manifest it writes.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// An empty path `name` under the test binary's scratch folder `group` (removed if there).
pub fn scratch_in(group: &str, name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(group);
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    let _ = std::fs::remove_dir_all(&p);
    p
}

/// `morph ARGS` run in the repository root.
pub fn morph(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_morph"))
        .current_dir(root())
        .args(args)
        .output()
        .unwrap()
}

pub fn manifest(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap()
}

/// Asserts a run succeeded, showing its exit code and stderr when not.
pub fn ok(r: &Output) {
    assert!(
        r.status.success(),
        "exit {:?}: {}",
        r.status.code(),
        String::from_utf8_lossy(&r.stderr)
    );
}
