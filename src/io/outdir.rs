//! The output folder of a run, guarded so that no run can destroy a user's files.
//!
//! 1. [`plan`] checks `-o` before any work: trailing slashes are normalised; `.`, `..`, `/`,
//!    the home folder, the working folder or one of its parents, a folder that is or contains
//!    an input file, a symbolic link and an existing non-folder are refused. An existing
//!    non-empty folder may be replaced only when it holds the run's marker file (a morph
//!    manifest); anything else is refused whatever the flags.
//! 2. [`Staging::take`] creates `OUT.partial` beside it and takes an exclusive lock on
//!    `OUT.partial/.lock` (the operating system's advisory file lock, through `std::fs::File`,
//!    released by the kernel when the process dies, so a killed run never leaves a stale
//!    lock). The lock file holds the owner's process id, which a second run names when it
//!    refuses.
//! 3. [`Staging::commit`] puts the complete folder in place atomically: the old folder is
//!    moved aside, the new one renamed into place, and only then is the old one deleted.

use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Component, Path, PathBuf};

/// The lock file inside the staging folder.
pub const LOCK_FILE: &str = ".lock";

/// What `-o` names today.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Existing {
    /// Nothing there.
    Absent,
    /// An empty folder.
    Empty,
    /// A folder holding the marker file: an earlier output of this tool.
    Ours,
}

/// A checked output location.
#[derive(Clone, Debug)]
pub struct OutputPlan {
    /// The output folder as given, without trailing slashes.
    pub out: PathBuf,
    /// `OUT.partial`, where the run writes.
    pub staging: PathBuf,
    pub existing: Existing,
    /// The file that marks a folder as one of ours (e.g. `manifest.json`).
    pub marker: &'static str,
}

/// `OUT.partial` beside `out` (`out` without trailing slashes).
pub fn partial_dir(out: &Path) -> PathBuf {
    let mut s = normalise(out).into_os_string();
    s.push(".partial");
    PathBuf::from(s)
}

/// `out` rebuilt from its components: `prev/` and `prev//` become `prev`.
fn normalise(out: &Path) -> PathBuf {
    out.components().collect()
}

/// `path` made absolute and free of `.` and `..`, resolving symbolic links of the part that
/// exists.
fn resolve(path: &Path) -> Result<PathBuf, String> {
    let cwd =
        std::env::current_dir().map_err(|e| format!("cannot read the working folder: {e}"))?;
    let mut abs = PathBuf::new();
    for c in cwd.join(path).components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                abs.pop();
            }
            other => abs.push(other),
        }
    }
    // Canonicalise the longest existing prefix, then append the rest.
    let mut existing = abs.clone();
    let mut rest = Vec::new();
    while !existing.exists() {
        match existing.file_name() {
            Some(name) => rest.push(name.to_owned()),
            None => break,
        }
        existing.pop();
    }
    let mut resolved = existing.canonicalize().unwrap_or(existing);
    for name in rest.into_iter().rev() {
        resolved.push(name);
    }
    Ok(resolved)
}

/// Checks `out` before any work; every refusal is one line that says why.
pub fn plan(
    out: &Path,
    inputs: &[&Path],
    overwrite: bool,
    marker: &'static str,
) -> Result<OutputPlan, String> {
    let shown = out.display();
    let given = normalise(out);
    match given.components().next_back() {
        None => return Err("the output folder name is empty".into()),
        Some(Component::Normal(_)) => {}
        Some(Component::CurDir) | Some(Component::ParentDir) => {
            return Err(format!(
                "output folder '{shown}' names an existing folder by '.' or '..'; give a new folder name, e.g. -o morph-out"
            ));
        }
        Some(_) => return Err(format!("output folder '{shown}' is a filesystem root")),
    }
    let resolved = resolve(&given)?;
    let staging = partial_dir(&given);
    if let Some(home) = std::env::var_os("HOME").map(PathBuf::from)
        && resolve(&home).is_ok_and(|h| h == resolved)
    {
        return Err(format!("output folder '{shown}' is the home folder"));
    }
    if let Ok(cwd) = std::env::current_dir()
        && cwd.canonicalize().unwrap_or(cwd).starts_with(&resolved)
    {
        return Err(format!(
            "output folder '{shown}' is the working folder or one of its parents"
        ));
    }
    let resolved_staging = resolve(&staging)?;
    for input in inputs {
        let inp = resolve(input)?;
        if inp.starts_with(&resolved) || inp.starts_with(&resolved_staging) {
            return Err(format!(
                "output folder '{shown}' contains the input '{}'; choose another -o",
                input.display()
            ));
        }
    }
    let existing = match fs::symlink_metadata(&given) {
        Err(_) => Existing::Absent,
        Ok(m) if m.file_type().is_symlink() => {
            return Err(format!(
                "output folder '{shown}' is a symbolic link; give the folder it points to"
            ));
        }
        Ok(m) if !m.is_dir() => {
            return Err(format!(
                "output '{shown}' exists and is not a folder; choose another -o"
            ));
        }
        Ok(_) => {
            let mut entries =
                fs::read_dir(&given).map_err(|e| format!("cannot read '{shown}': {e}"))?;
            if entries.next().is_none() {
                Existing::Empty
            } else if given.join(marker).is_file() {
                Existing::Ours
            } else {
                return Err(format!(
                    "output folder '{shown}' exists and is not a morph output (it has no {marker}); morph will not replace it: choose another -o"
                ));
            }
        }
    };
    if existing == Existing::Ours && !overwrite {
        return Err(format!(
            "output folder '{shown}' already exists; pass --overwrite to replace it"
        ));
    }
    Ok(OutputPlan {
        out: given,
        staging,
        existing,
        marker,
    })
}

/// What the staging folder held when it was taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Previous {
    /// Nothing (created now, or empty).
    Nothing,
    /// An earlier run's files: it holds the identity file.
    Run,
}

/// The locked staging folder `OUT.partial`. Dropping it releases the lock and keeps the
/// folder; [`Staging::commit`] and [`Staging::discard`] end it.
#[derive(Debug)]
pub struct Staging {
    pub dir: PathBuf,
    pub previous: Previous,
    _lock: File,
}

impl Staging {
    /// Creates (or opens) the staging folder and locks it. `identity` is the file by which a
    /// run marks the staging folder as its own; a folder holding anything else is refused.
    pub fn take(plan: &OutputPlan, identity: &str) -> Result<Staging, String> {
        let dir = &plan.staging;
        let shown = dir.display();
        if let Ok(m) = fs::symlink_metadata(dir)
            && !m.is_dir()
        {
            return Err(format!(
                "'{shown}' exists and is not a folder; move it away"
            ));
        }
        fs::create_dir_all(dir).map_err(|e| format!("cannot create folder '{shown}': {e}"))?;
        let lock_path = dir.join(LOCK_FILE);
        let mut lock = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&lock_path)
            .map_err(|e| format!("cannot create '{}': {e}", lock_path.display()))?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                let mut owner = String::new();
                let _ = lock.read_to_string(&mut owner);
                let owner = owner.trim();
                let who = if owner.is_empty() {
                    "another morph run".to_string()
                } else {
                    format!("another morph run (process {owner})")
                };
                return Err(format!(
                    "output folder '{}' is being written by {who}; wait for it or choose another -o",
                    plan.out.display()
                ));
            }
            Err(fs::TryLockError::Error(e)) => {
                return Err(format!("cannot lock '{}': {e}", lock_path.display()));
            }
        }
        lock.set_len(0)
            .and_then(|_| writeln!(lock, "{}", std::process::id()))
            .and_then(|_| lock.flush())
            .map_err(|e| format!("cannot write '{}': {e}", lock_path.display()))?;
        let others: Vec<String> = fs::read_dir(dir)
            .map_err(|e| format!("cannot read '{shown}': {e}"))?
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n != LOCK_FILE)
            .collect();
        let previous = if others.is_empty() {
            Previous::Nothing
        } else if others.iter().any(|n| n == identity) {
            Previous::Run
        } else {
            return Err(format!(
                "'{shown}' holds files morph did not write (no {identity}); move it away"
            ));
        };
        Ok(Staging {
            dir: dir.clone(),
            previous,
            _lock: lock,
        })
    }

    /// Empties the staging folder (an earlier run's files), keeping the lock.
    pub fn clear(&mut self) -> Result<(), String> {
        for entry in fs::read_dir(&self.dir).map_err(|e| e.to_string())? {
            let entry = entry.map_err(|e| e.to_string())?;
            if entry.file_name() == LOCK_FILE {
                continue;
            }
            let path = entry.path();
            let removed = if entry.file_type().is_ok_and(|t| t.is_dir()) {
                fs::remove_dir_all(&path)
            } else {
                fs::remove_file(&path)
            };
            removed.map_err(|e| format!("cannot remove '{}': {e}", path.display()))?;
        }
        self.previous = Previous::Nothing;
        Ok(())
    }

    /// Removes the staging folder (a run that failed before leaving anything worth keeping).
    pub fn discard(self) {
        let _ = fs::remove_dir_all(&self.dir);
    }

    /// Puts the complete staging folder in place of `plan.out`: the old folder (if any) is
    /// moved aside, the new one renamed into place, then the old one deleted.
    pub fn commit(self, plan: &OutputPlan) -> Result<(), String> {
        let out = &plan.out;
        let shown = out.display();
        let aside = match fs::symlink_metadata(out) {
            Err(_) => None,
            Ok(m) => {
                // Check again: the folder may have changed while the run was computing.
                let ours = m.is_dir()
                    && (out.join(plan.marker).is_file()
                        || fs::read_dir(out).is_ok_and(|mut d| d.next().is_none()));
                if !ours {
                    return Err(format!(
                        "'{shown}' changed during the run and is no longer a morph output; the result is kept in '{}'",
                        self.dir.display()
                    ));
                }
                let mut name = std::ffi::OsString::from(".");
                name.push(out.file_name().expect("checked by plan"));
                name.push(format!(".replaced-{}", std::process::id()));
                let aside = out.with_file_name(name);
                fs::rename(out, &aside)
                    .map_err(|e| format!("cannot move the old '{shown}' aside: {e}"))?;
                Some(aside)
            }
        };
        if let Err(e) = fs::rename(&self.dir, out) {
            if let Some(aside) = &aside {
                let _ = fs::rename(aside, out);
            }
            return Err(format!(
                "cannot rename '{}' to '{shown}': {e}",
                self.dir.display()
            ));
        }
        let _ = fs::remove_file(out.join(LOCK_FILE));
        if let Some(aside) = aside {
            fs::remove_dir_all(&aside).map_err(|e| {
                format!(
                    "the new '{shown}' is in place, but the old one could not be removed from '{}': {e}",
                    aside.display()
                )
            })?;
        }
        Ok(())
    }
}
