//! The output folder of a run, guarded so that no run can destroy a user's files.
//!
//! 1. [`plan`] checks `-o` before any work: trailing slashes are normalised; `.`, `..`, `/`,
//!    the home folder, the working folder or one of its parents, a folder that is or contains
//!    an input file, a symbolic link, a mount point, a name too long to stage beside and an
//!    existing non-folder are refused. An existing non-empty folder may be replaced only when
//!    morph provably made it ([`check_owned`]): its marker file (a morph manifest) parses as
//!    morph's, with tool, version and run id, and the folder holds nothing but the files that
//!    marker lists. Anything else is refused whatever the flags, naming the first foreign file.
//! 2. [`Staging::take`] creates `OUT.partial` beside it and takes an exclusive lock on
//!    `OUT.partial/.lock` (the operating system's advisory file lock, through `std::fs::File`,
//!    released by the kernel when the process dies, so a killed run never leaves a stale
//!    lock). The lock file holds the owner's process id, which a second run names when it
//!    refuses. A staging folder holding a name morph does not write is refused.
//! 3. [`Staging::commit`] puts the complete folder in place atomically: the old folder is
//!    checked again, moved aside, the new one renamed into place, and only then is the old
//!    one deleted, its marker last, so that a cleanup killed halfway leaves a folder that is
//!    still provably morph's; later runs remove such leftovers of dead processes.

use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Component, Path, PathBuf};

/// The lock file inside the staging folder.
pub const LOCK_FILE: &str = ".lock";

/// The longest output folder name: the file system's 255 bytes, less what the staging
/// (`.partial`) and replaced (`.` + `.replaced-` + a process id) names add to it.
pub const MAX_NAME: usize = 255 - 21;

/// The fields by which a marker file (a manifest) proves that morph made its folder: every
/// marker morph writes has them, and lists every other file of the folder (relative paths
/// with `/`, the marker itself and the lock file excepted).
#[derive(serde::Deserialize)]
struct Marker {
    tool: String,
    version: String,
    run_id: String,
    files: Vec<String>,
}

/// A folder morph made: the files its marker lists, and those of them that are missing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Owned {
    pub files: Vec<String>,
    pub missing: Vec<String>,
}

/// Whether `dir` is provably a folder morph made: `marker` parses as morph's (tool, version,
/// run id, file list) and the folder holds no file it does not list (folders may be empty).
/// The error says why not, naming the first foreign file.
pub fn check_owned(dir: &Path, marker: &str) -> Result<Owned, String> {
    let path = dir.join(marker);
    let bytes = match crate::files::read(&path, crate::files::MANIFEST_BYTES) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!("it has no {marker}"));
        }
        Err(e) => return Err(format!("cannot read its {marker}: {e}")),
    };
    let m: Marker = serde_json::from_slice(&bytes).map_err(|e| {
        let value: serde_json::Value = serde_json::from_slice(&bytes).unwrap_or_default();
        match (value["tool"].as_str(), value["version"].as_str()) {
            (Some(tool), Some(version)) if tool.starts_with("morph") && value["files"].is_null() => {
                format!(
                    "its {marker} was written by {tool} {version}, which did not list the folder's files, so nothing proves the folder holds only morph's; delete it yourself if it is"
                )
            }
            _ => format!(
                "its {marker} is not one morph wrote: {}",
                crate::files::short_message(&e.to_string())
            ),
        }
    })?;
    let plain = |f: &str| {
        !f.is_empty()
            && !f.starts_with('/')
            && f.split('/').all(|c| !c.is_empty() && c != "." && c != "..")
    };
    if !m.tool.starts_with("morph")
        || m.version.is_empty()
        || m.run_id.len() != 64
        || !m.run_id.bytes().all(|b| b.is_ascii_hexdigit())
    {
        return Err(format!(
            "its {marker} does not carry morph's tool, version and run id"
        ));
    }
    if let Some(bad) = m.files.iter().find(|f| !plain(f)) {
        return Err(format!(
            "its {marker} lists '{bad}', which is not a file inside it"
        ));
    }
    let listed: std::collections::HashSet<&str> = m.files.iter().map(String::as_str).collect();
    let mut present = std::collections::HashSet::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((folder, prefix)) = stack.pop() {
        let mut entries: Vec<_> = fs::read_dir(&folder)
            .map_err(|e| format!("cannot read '{}': {e}", folder.display()))?
            .filter_map(|e| e.ok())
            .collect();
        entries.sort_by_key(|e| e.file_name());
        for e in entries {
            let name = e.file_name().to_string_lossy().into_owned();
            let rel = format!("{prefix}{name}");
            let t = e
                .file_type()
                .map_err(|err| format!("cannot read '{}': {err}", e.path().display()))?;
            if t.is_dir() {
                stack.push((e.path(), format!("{rel}/")));
            } else if !t.is_file() {
                return Err(format!("it holds '{rel}', which is not a regular file"));
            } else if prefix.is_empty() && (name == marker || name == LOCK_FILE) {
                continue;
            } else if listed.contains(rel.as_str()) {
                present.insert(rel);
            } else {
                return Err(format!(
                    "it holds '{rel}', which its {marker} does not list"
                ));
            }
        }
    }
    let missing = m
        .files
        .iter()
        .filter(|f| !present.contains(*f))
        .cloned()
        .collect();
    Ok(Owned {
        files: m.files,
        missing,
    })
}

/// Every file under `dir`, as relative paths with `/`, sorted; top-level entries named in
/// `skip` are left out (what a marker file lists, see [`check_owned`]).
pub fn list_files(dir: &Path, skip: &[&str]) -> std::io::Result<Vec<String>> {
    let mut out = Vec::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((folder, prefix)) = stack.pop() {
        for e in fs::read_dir(&folder)? {
            let e = e?;
            let name = e.file_name().to_string_lossy().into_owned();
            if prefix.is_empty() && (skip.contains(&name.as_str()) || name == LOCK_FILE) {
                continue;
            }
            let rel = format!("{prefix}{name}");
            if e.file_type()?.is_dir() {
                stack.push((e.path(), format!("{rel}/")));
            } else {
                out.push(rel);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Whether `dir` holds nothing but (possibly nested) empty folders.
fn only_empty_folders(dir: &Path) -> bool {
    fs::read_dir(dir).is_ok_and(|entries| {
        entries
            .filter_map(|e| e.ok())
            .all(|e| e.file_type().is_ok_and(|t| t.is_dir()) && only_empty_folders(&e.path()))
    })
}

/// Deletes a folder morph provably made ([`check_owned`]), or one left holding only empty
/// folders: the listed files first, the marker last, then the folders, each removed only
/// when empty. A deletion stopped at any point leaves a folder that is still provably
/// morph's.
fn remove_owned(dir: &Path, marker: &str) -> std::io::Result<()> {
    if !only_empty_folders(dir) {
        let owned = check_owned(dir, marker).map_err(std::io::Error::other)?;
        for f in owned.files.iter().filter(|f| !owned.missing.contains(f)) {
            fs::remove_file(dir.join(f))?;
        }
        match fs::remove_file(dir.join(LOCK_FILE)) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
            _ => {}
        }
        fs::remove_file(dir.join(marker))?;
    }
    remove_empty_folders(dir)
}

fn remove_empty_folders(dir: &Path) -> std::io::Result<()> {
    for e in fs::read_dir(dir)? {
        let e = e?;
        if e.file_type()?.is_dir() {
            remove_empty_folders(&e.path())?;
        }
    }
    fs::remove_dir(dir)
}

/// Whether `path` (an existing folder) is a mount point: on another device than its parent,
/// or listed as one by the kernel (a bind mount of the same file system).
pub fn is_mount_point(path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    let Ok(abs) = path.canonicalize() else {
        return false;
    };
    let Some(parent) = abs.parent() else {
        return true;
    };
    if let (Ok(a), Ok(p)) = (fs::metadata(&abs), fs::metadata(parent))
        && a.dev() != p.dev()
    {
        return true;
    }
    let Ok(info) = crate::files::read_to_string(
        Path::new("/proc/self/mountinfo"),
        crate::files::SMALL_FILE_BYTES,
    ) else {
        return false;
    };
    // Field 5 is the mount point, with spaces and the like escaped as octal (`\040`).
    let unescape = |s: &str| {
        let mut out = Vec::new();
        let b = s.as_bytes();
        let mut i = 0;
        while i < b.len() {
            if b[i] == b'\\'
                && i + 3 < b.len()
                && let Ok(v) = u8::from_str_radix(&s[i + 1..i + 4], 8)
            {
                out.push(v);
                i += 4;
            } else {
                out.push(b[i]);
                i += 1;
            }
        }
        PathBuf::from(std::ffi::OsString::from(
            String::from_utf8_lossy(&out).into_owned(),
        ))
    };
    info.lines()
        .filter_map(|l| l.split(' ').nth(4))
        .any(|m| unescape(m) == abs)
}

/// Removes the `.NAME.replaced-PID` folders beside `out` that a replacing run whose process
/// has died left behind, when each is still provably morph's (see [`remove_owned`]).
fn remove_stale_asides(out: &Path, marker: &str) {
    let Some(name) = out.file_name() else { return };
    let prefix = format!(".{}.replaced-", name.to_string_lossy());
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let Ok(entries) = fs::read_dir(&parent) else {
        return;
    };
    for e in entries.filter_map(|e| e.ok()) {
        let n = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = n.strip_prefix(&prefix).and_then(|p| p.parse::<i32>().ok()) else {
            continue;
        };
        // SAFETY: signal 0 only asks whether the process exists.
        let alive = pid as u32 == std::process::id()
            || unsafe { libc::kill(pid, 0) } == 0
            || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
        if !alive && e.file_type().is_ok_and(|t| t.is_dir()) {
            let _ = remove_owned(&e.path(), marker);
        }
    }
}

/// What `-o` names today.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Existing {
    /// Nothing there.
    Absent,
    /// An empty folder.
    Empty,
    /// A folder morph provably made (see [`check_owned`]).
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
    let name_len = given.file_name().map_or(0, |n| n.len());
    if name_len > MAX_NAME {
        return Err(format!(
            "output folder name '{}' is {name_len} bytes long; morph stages its work in '<name>.partial' and keeps the old folder as '.<name>.replaced-<pid>' while replacing it, so the name may be at most {MAX_NAME} bytes",
            given.file_name().unwrap_or_default().to_string_lossy()
        ));
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
            if is_mount_point(&given) {
                return Err(format!(
                    "output folder '{shown}' is a mount point (another filesystem); morph writes beside the output and renames its result into place, which cannot replace a mount point: give a folder inside it, e.g. -o {}/morph-out",
                    given.display()
                ));
            }
            let mut entries =
                fs::read_dir(&given).map_err(|e| format!("cannot read '{shown}': {e}"))?;
            if entries.next().is_none() {
                Existing::Empty
            } else {
                check_owned(&given, marker).map_err(|why| {
                    format!(
                        "output folder '{shown}' is not provably a morph output ({why}); morph will not replace it: choose another -o"
                    )
                })?;
                Existing::Ours
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

/// Why [`Staging::take`] could not take the staging folder.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TakeError {
    /// Another live run holds its lock (the run fails: exit 1).
    #[error("{0}")]
    InUse(String),
    /// It cannot be made or used (a read-only or missing parent, a file in its place,
    /// foreign files): a bad output folder, refused before any work (exit 2).
    #[error("{0}")]
    Unusable(String),
}

/// The lock file a run holds open, by device and inode: what makes a staging folder that
/// run's, whatever its path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LockId {
    dev: u64,
    ino: u64,
}

impl LockId {
    /// Whether the lock file in `dir` is this one (the folder is still the run's own).
    pub fn holds(&self, dir: &Path) -> bool {
        use std::os::unix::fs::MetadataExt;
        fs::symlink_metadata(dir.join(LOCK_FILE))
            .is_ok_and(|m| (m.dev(), m.ino()) == (self.dev, self.ino))
    }

    /// `Err` with a message when `dir` is no longer the folder this run locked.
    pub fn check(&self, dir: &Path) -> Result<(), String> {
        if self.holds(dir) {
            Ok(())
        } else {
            Err(format!(
                "the staging folder '{}' was removed or replaced during the run (by another run?); this run stopped and touched nothing there",
                dir.display()
            ))
        }
    }
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
    /// run marks the staging folder as its own, and `known` the names a run writes at its
    /// top (with `.tmp` for a file being written); a folder without the identity, or holding
    /// any other name, is refused.
    pub fn take(plan: &OutputPlan, identity: &str, known: &[&str]) -> Result<Staging, TakeError> {
        use TakeError::Unusable;
        let dir = &plan.staging;
        let shown = dir.display();
        if let Ok(m) = fs::symlink_metadata(dir)
            && !m.is_dir()
        {
            return Err(Unusable(format!(
                "'{shown}' exists and is not a folder; move it away"
            )));
        }
        fs::create_dir_all(dir)
            .map_err(|e| Unusable(format!("cannot create folder '{shown}': {e}")))?;
        let lock_path = dir.join(LOCK_FILE);
        let mut lock = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&lock_path)
            .map_err(|e| Unusable(format!("cannot create '{}': {e}", lock_path.display())))?;
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
                return Err(TakeError::InUse(format!(
                    "output folder '{}' is being written by {who}; wait for it or choose another -o",
                    plan.out.display()
                )));
            }
            Err(fs::TryLockError::Error(e)) => {
                return Err(Unusable(format!(
                    "cannot lock '{}': {e}",
                    lock_path.display()
                )));
            }
        }
        lock.set_len(0)
            .and_then(|_| writeln!(lock, "{}", std::process::id()))
            .and_then(|_| lock.flush())
            .map_err(|e| Unusable(format!("cannot write '{}': {e}", lock_path.display())))?;
        let others: Vec<String> = fs::read_dir(dir)
            .map_err(|e| Unusable(format!("cannot read '{shown}': {e}")))?
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n != LOCK_FILE)
            .collect();
        let previous = if others.is_empty() {
            Previous::Nothing
        } else if others.iter().any(|n| n == identity) {
            let ours = |n: &str| n == identity || known.contains(&n);
            if let Some(foreign) = others
                .iter()
                .find(|n| !ours(n) && !n.strip_suffix(".tmp").is_some_and(ours))
            {
                return Err(Unusable(format!(
                    "'{shown}' holds '{foreign}', which morph does not write; move it away"
                )));
            }
            Previous::Run
        } else {
            return Err(Unusable(format!(
                "'{shown}' holds files morph did not write (no {identity}); move it away"
            )));
        };
        Ok(Staging {
            dir: dir.clone(),
            previous,
            _lock: lock,
        })
    }

    /// Whether `dir` is still the folder this run locked ([`LockId::holds`]). A folder
    /// removed during the run and made again by another run is that run's, and nothing of it
    /// may be touched.
    pub fn is_ours(&self) -> bool {
        self.lock_id().is_some_and(|id| id.holds(&self.dir))
    }

    /// The identity of the lock file this run holds open.
    pub fn lock_id(&self) -> Option<LockId> {
        use std::os::unix::fs::MetadataExt;
        let m = self._lock.metadata().ok()?;
        Some(LockId {
            dev: m.dev(),
            ino: m.ino(),
        })
    }

    /// The error for a staging folder that is no longer this run's.
    fn lost(&self) -> String {
        format!(
            "the staging folder '{}' was removed or replaced during the run (by another run?); this run's work is lost and nothing there was touched",
            self.dir.display()
        )
    }

    /// Empties the staging folder (an earlier run's files), keeping the lock.
    pub fn clear(&mut self) -> Result<(), String> {
        if !self.is_ours() {
            return Err(self.lost());
        }
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

    /// Removes the staging folder (a run that failed before leaving anything worth keeping),
    /// only while it is still the one this run locked ([`Staging::is_ours`]).
    pub fn discard(self) {
        if self.is_ours() {
            let _ = fs::remove_dir_all(&self.dir);
        }
    }

    /// Puts the complete staging folder in place of `plan.out`: the old folder (if any) is
    /// moved aside, the new one renamed into place, then the old one deleted.
    pub fn commit(self, plan: &OutputPlan) -> Result<(), String> {
        let out = &plan.out;
        let shown = out.display();
        if !self.is_ours() {
            return Err(self.lost());
        }
        let aside = match fs::symlink_metadata(out) {
            Err(_) => None,
            Ok(m) => {
                // Check again: the folder may have changed while the run was computing.
                let why = if !m.is_dir() {
                    Some("it is no longer a folder".to_string())
                } else if fs::read_dir(out).is_ok_and(|mut d| d.next().is_none()) {
                    None
                } else {
                    check_owned(out, plan.marker).err()
                };
                if let Some(why) = why {
                    return Err(format!(
                        "'{shown}' changed during the run and is not provably a morph output any more ({why}); the result is kept in '{}'",
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
        remove_stale_asides(out, plan.marker);
        if let Some(aside) = aside {
            remove_owned(&aside, plan.marker).map_err(|e| {
                format!(
                    "the new '{shown}' is in place, but the old one could not be removed from '{}': {e}",
                    aside.display()
                )
            })?;
        }
        Ok(())
    }
}
