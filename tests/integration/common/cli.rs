//! Running the `morph` binary from a test: the repository root, a scratch folder per test,
//! the command and the manifest it writes.

use std::ffi::OsStr;
use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A test's scratch path (a folder or a file). It is removed when the test passes, so a
/// suite of morphs does not fill the disk (each writes tens of MB); a failing test keeps it
/// to look at.
pub struct Scratch(PathBuf);

impl Scratch {
    /// The path `name` in the test binary's scratch folder `group`, removed if it was there.
    pub fn empty(group: &str, name: &str) -> Scratch {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(group);
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        remove(&p);
        Scratch(p)
    }

    /// The same, made as an empty folder.
    pub fn folder(group: &str, name: &str) -> Scratch {
        let s = Scratch::empty(group, name);
        std::fs::create_dir_all(&s.0).unwrap();
        s
    }
}

fn remove(p: &Path) {
    if p.is_dir() {
        let _ = std::fs::remove_dir_all(p);
    } else {
        let _ = std::fs::remove_file(p);
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            remove(&self.0);
        }
    }
}

impl Deref for Scratch {
    type Target = PathBuf;
    fn deref(&self) -> &PathBuf {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<OsStr> for Scratch {
    fn as_ref(&self) -> &OsStr {
        self.0.as_os_str()
    }
}

/// An empty path `name` under the test binary's scratch folder `group`.
pub fn scratch_in(group: &str, name: &str) -> Scratch {
    Scratch::empty(group, name)
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
