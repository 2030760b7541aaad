//! Bounded reads: every file morph reads goes through here, so that a device
//! (`/dev/zero`), a FIFO, a socket or a file far larger than its kind can be is refused with
//! a message instead of filling memory or blocking forever.
//!
//! The file is opened without blocking (a FIFO with no writer would block `open` itself),
//! then checked on the open handle (`fstat`, so a symbolic link swapped in between is
//! seen), and read no further than its bound even when it grows while being read.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

/// The largest mesh file morph reads (OBJ or PLY).
pub const MESH_BYTES: u64 = 2 << 30;
/// The largest scene file, run identity, study table or JSON side file.
pub const SMALL_FILE_BYTES: u64 = 64 << 20;
/// The largest manifest (one entry per frame with its measurements).
pub const MANIFEST_BYTES: u64 = 1 << 30;
/// The largest mass grid (`.mgrid`): 257^3 nodes of f64 is 136 MB.
pub const MASS_GRID_BYTES: u64 = 1 << 30;

/// Opens `path` for reading if it is a regular file of at most `max` bytes; returns it with
/// its size.
pub fn open(path: &Path, max: u64) -> io::Result<(File, u64)> {
    use std::os::unix::fs::OpenOptionsExt;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        let kind = {
            use std::os::unix::fs::FileTypeExt;
            let t = meta.file_type();
            if t.is_dir() {
                "a folder"
            } else if t.is_fifo() {
                "a FIFO (named pipe)"
            } else if t.is_char_device() || t.is_block_device() {
                "a device"
            } else if t.is_socket() {
                "a socket"
            } else {
                "not a regular file"
            }
        };
        return Err(io::Error::other(format!(
            "it is {kind}, not a regular file; morph reads only regular files"
        )));
    }
    let len = meta.len();
    if len > max {
        return Err(io::Error::other(format!(
            "it is {}, more than the {} morph reads from a file of this kind",
            show(len),
            show(max)
        )));
    }
    Ok((file, len))
}

/// The whole of `path`, a regular file of at most `max` bytes (see the module docs).
pub fn read(path: &Path, max: u64) -> io::Result<Vec<u8>> {
    let (file, len) = open(path, max)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(io::Error::other(format!(
            "it grew past {} while being read",
            show(max)
        )));
    }
    Ok(bytes)
}

/// [`read`] as UTF-8 text.
pub fn read_to_string(path: &Path, max: u64) -> io::Result<String> {
    String::from_utf8(read(path, max)?)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e.to_string()))
}

/// A size as people read it.
fn show(bytes: u64) -> String {
    let b = bytes as f64;
    if bytes >= 1 << 30 {
        format!("{:.1} GB", b / (1u64 << 30) as f64)
    } else if bytes >= 1 << 20 {
        format!("{:.1} MB", b / (1u64 << 20) as f64)
    } else {
        format!("{bytes} bytes")
    }
}

/// The longest piece of a file's text an error message quotes, in bytes as shown.
pub const QUOTE_CHARS: usize = 40;

/// The most of a parser's message an error repeats, in bytes (cut at a word).
pub const MESSAGE_BYTES: usize = 240;

/// `text` as an error message quotes it: at most about [`QUOTE_CHARS`] bytes, control and
/// non-printing characters escaped (and counted as shown), and the length said when it was
/// cut, so that a header line of megabytes (or binary junk) gives a short error.
pub fn quote_short(text: &str) -> String {
    let mut out = String::new();
    for (at, c) in text.char_indices() {
        if out.len() >= QUOTE_CHARS {
            out.push_str(&format!("... ({} bytes)", text.len()));
            return out;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
        debug_assert!(at < text.len());
    }
    out
}

/// A parser's message as one short line: its whitespace made single spaces, each word quoted
/// short ([`quote_short`]) and about [`MESSAGE_BYTES`] at most (parsers quote what they
/// failed on, whole).
pub fn short_message(message: &str) -> String {
    let mut out = String::new();
    for word in message.split_whitespace() {
        if out.len() >= MESSAGE_BYTES {
            out.push_str(" ...");
            break;
        }
        if !out.is_empty() {
            out.push(' ');
        }
        out.push_str(&quote_short(word));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_fifos_and_oversized_files_are_refused() {
        let e = read(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(e.to_string().contains("a device"), "{e}");
        let dir = std::env::temp_dir().join(format!("morph-bounded-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a plain libc call on a valid C string.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = read(&fifo, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("FIFO"), "{e}");
        let big = dir.join("big");
        std::fs::write(&big, vec![b'x'; 2000]).unwrap();
        let e = read(&big, 1000).unwrap_err();
        assert!(e.to_string().contains("more than the 1000 bytes"), "{e}");
        assert_eq!(read(&big, 2000).unwrap().len(), 2000);
        let e = read(&dir, 1000).unwrap_err();
        assert!(e.to_string().contains("a folder"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
