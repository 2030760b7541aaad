//! Two corrections to `openusd` 0.6's `.usdc` files so Pixar's USD opens them.
//!
//! 1. **Children lists.** `openusd` 0.6 writes a prim's lists of children (`primChildren`,
//!    `properties`) as token *arrays* (`VtArray<TfToken>`, type 11 with the array bit).
//!    Pixar's crate reader wants them as `TfTokenVector` (type 41) and, since USD 25.x checks
//!    layers as it opens them, refuses the file: "Invalid children found in primChildren
//!    field". Both types are stored the same way (a u64 count, then u32 token indices), so
//!    only the tags differ: this retags those two fields' values in the `FIELDS` section and
//!    moves the sections after it.
//! 2. **The format version.** `openusd` stamps every file 0.12.0, the newest crate version,
//!    which USD before 25.x refuses ("file is 0.12.0, software supports 0.10.0": usd-core
//!    24.3, and the DCCs of its day). Versions 0.9 to 0.12 only added value types (time codes
//!    0.9, path expressions 0.10, relocates 0.11, ...), none of which a morph's layer holds,
//!    so the file is stamped 0.8.0, as Pixar's own writer stamps the same content.
//!
//! (`openusd` 0.7 and later need a newer Rust than ours. The client check opens the file with
//! usd-core, an older usd-core and Blender on every CI run, so a change of layout in a new
//! `openusd` would show there.)

use openusd::usdc::CrateFile;
use std::io::{Read, Seek, SeekFrom, Write};

/// The crate file's type tags (Pixar's `crateDataTypes.h`).
const TOKEN: u64 = 11;
const TOKEN_VECTOR: u64 = 41;
const ARRAY_BIT: u64 = 1 << 63;
const TYPE_SHIFT: u32 = 48;
/// The first type tag newer than crate version 0.8.0 (`TimeCode`, version 0.9.0).
const FIRST_AFTER_0_8: u64 = 56;
/// The version the corrected file is stamped with.
const VERSION: [u8; 3] = [0, 8, 0];

fn bad(why: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, format!("usdc: {why}"))
}

fn u64_at(bytes: &[u8], at: usize) -> std::io::Result<u64> {
    bytes
        .get(at..at + 8)
        .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
        .ok_or_else(|| bad("truncated"))
}

/// Corrects `file`, a whole `.usdc` from `openusd`, as the module docs say: its children lists
/// retagged, and stamped 0.8.0 when it holds no newer value type. Only the header and the end
/// of the file change (the structural sections and the table of contents come after the
/// values), so the values are never read or held.
pub fn correct(file: &mut std::fs::File) -> std::io::Result<()> {
    let newest_type = retag_children(file)?;
    if newest_type < FIRST_AFTER_0_8 {
        file.seek(SeekFrom::Start(8))?;
        file.write_all(&VERSION)?;
    }
    file.seek(SeekFrom::End(0))?;
    Ok(())
}

/// Retags the children lists of `file` (see the module docs); returns the newest type tag of
/// its fields' values.
fn retag_children(file: &mut std::fs::File) -> std::io::Result<u64> {
    file.seek(SeekFrom::Start(0))?;
    let crate_file =
        CrateFile::open(std::io::BufReader::new(&mut *file)).map_err(|e| bad(format!("{e:#}")))?;
    let is_children = |token: usize| {
        matches!(
            crate_file.tokens.get(token).map(String::as_str),
            Some("primChildren" | "properties")
        )
    };
    let mut changed = false;
    let newest_type = crate_file
        .fields
        .iter()
        .map(|f| (f.value_rep.0 >> TYPE_SHIFT) & 0xff)
        .max()
        .unwrap_or(0);
    let reps: Vec<u64> = crate_file
        .fields
        .iter()
        .map(|field| {
            let rep = field.value_rep.0;
            let token_array = (rep >> TYPE_SHIFT) & 0xff == TOKEN && rep & ARRAY_BIT != 0;
            if token_array && is_children(field.token_index) {
                changed = true;
                let payload = rep & !(ARRAY_BIT | (0xff << TYPE_SHIFT));
                payload | (TOKEN_VECTOR << TYPE_SHIFT)
            } else {
                rep
            }
        })
        .collect();
    if !changed {
        return Ok(newest_type);
    }
    let fields = crate_file
        .sections
        .iter()
        .find(|s| s.name() == "FIELDS")
        .ok_or_else(|| bad("no FIELDS section"))?;
    let (start, size) = (fields.start, fields.size as usize);
    drop(crate_file);

    // Everything from FIELDS on: FIELDS, the sections after it and the table of contents.
    file.seek(SeekFrom::Start(start))?;
    let mut tail = Vec::new();
    file.read_to_end(&mut tail)?;
    let mut header = [0u8; 24];
    file.seek(SeekFrom::Start(0))?;
    file.read_exact(&mut header)?;
    let toc = u64_at(&header, 16)?;
    if toc < start + size as u64 {
        return Err(bad("the table of contents before the sections"));
    }

    // FIELDS: the field count, the token indices (a u64 size, then compressed), then the value
    // representations (a u64 size, then LZ4 with a leading chunk count of 0).
    let reps_at = 16 + u64_at(&tail, 8)? as usize;
    let mut section = tail
        .get(..reps_at)
        .ok_or_else(|| bad("truncated"))?
        .to_vec();
    let raw: Vec<u8> = reps.iter().flat_map(|r| r.to_le_bytes()).collect();
    let mut packed = vec![0u8];
    packed.extend(lz4_flex::block::compress(&raw));
    section.extend((packed.len() as u64).to_le_bytes());
    section.extend(packed);
    let shift = section.len() as i64 - size as i64;
    let moved = |offset: u64| (offset as i64 + shift) as u64;
    let mut new_tail = section;
    new_tail.extend_from_slice(&tail[size..]);

    // The table of contents: a u64 count, then per section a 16-byte name, start and size.
    let at = (moved(toc) - start) as usize;
    let count = u64_at(&new_tail, at)? as usize;
    for k in 0..count {
        let entry = at + 8 + k * 32;
        let section_start = u64_at(&new_tail, entry + 16)?;
        if section_start == start {
            let new_size = (size as i64 + shift) as u64;
            new_tail[entry + 24..entry + 32].copy_from_slice(&new_size.to_le_bytes());
        } else if section_start > start {
            new_tail[entry + 16..entry + 24].copy_from_slice(&moved(section_start).to_le_bytes());
        }
    }
    file.seek(SeekFrom::Start(start))?;
    file.write_all(&new_tail)?;
    // A shorter tail leaves old bytes after the new end; nothing reads past the table of
    // contents, but the file is cut there all the same.
    let end = file.stream_position()?;
    file.set_len(end)?;
    file.seek(SeekFrom::Start(16))?;
    file.write_all(&moved(toc).to_le_bytes())?;
    Ok(newest_type)
}

#[cfg(test)]
mod tests {
    use super::*;
    use openusd::sdf::{self, AbstractData, ChildrenKey, FieldKey, SpecType, Specifier, Value};

    /// `/A` with a child prim `/A/b` that has an attribute, as `openusd` writes it.
    fn layer() -> Vec<u8> {
        let mut data = sdf::Data::new();
        let names = |n: &[&str]| Value::TokenVec(n.iter().map(|&s| s.into()).collect());
        data.create_spec(sdf::Path::abs_root(), SpecType::PseudoRoot)
            .add(ChildrenKey::PrimChildren, names(&["A"]));
        for (path, child) in [("/A", "b"), ("/A/b", "")] {
            let spec = data.create_spec(sdf::path(path).unwrap(), SpecType::Prim);
            spec.add(FieldKey::Specifier, Value::Specifier(Specifier::Def));
            spec.add(FieldKey::TypeName, Value::Token("Xform".into()));
            if child.is_empty() {
                spec.add(ChildrenKey::PropertyChildren, names(&["size"]));
            } else {
                spec.add(ChildrenKey::PrimChildren, names(&[child]));
            }
        }
        let size = data.create_spec(sdf::path("/A/b.size").unwrap(), SpecType::Attribute);
        size.add(FieldKey::TypeName, Value::Token("double".into()));
        size.add(FieldKey::Default, Value::Double(2.5));
        let mut bytes = std::io::Cursor::new(Vec::new());
        openusd::usdc::CrateWriter::write(&data, &mut bytes).unwrap();
        bytes.into_inner()
    }

    /// `bytes` written to a file, retagged there, and read back.
    fn retagged(bytes: &[u8]) -> Vec<u8> {
        let path = std::env::temp_dir().join(format!("usdc-fix-{}.usdc", std::process::id()));
        std::fs::write(&path, bytes).unwrap();
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .unwrap();
        correct(&mut file).unwrap();
        drop(file);
        let out = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        out
    }

    fn children_types(bytes: &[u8]) -> Vec<u64> {
        let file = CrateFile::open(std::io::Cursor::new(bytes)).unwrap();
        file.fields
            .iter()
            .filter(|f| {
                ["primChildren", "properties"].contains(&file.tokens[f.token_index].as_str())
            })
            .map(|f| f.value_rep.0 >> TYPE_SHIFT)
            .collect()
    }

    #[test]
    fn children_lists_become_token_vectors_and_the_file_still_reads_the_same() {
        let before = layer();
        // openusd 0.6 tags them token arrays (this fails, usefully, once a new version stops).
        assert!(
            children_types(&before)
                .iter()
                .all(|t| *t == (ARRAY_BIT >> TYPE_SHIFT) | TOKEN)
        );
        let after = retagged(&before);
        let types = children_types(&after);
        assert_eq!(types.len(), 3);
        assert!(types.iter().all(|t| *t == TOKEN_VECTOR), "{types:?}");
        // Stamped with the oldest version that holds it (openusd stamps 0.12.0).
        assert_eq!(&before[8..11], &[0, 12, 0]);
        assert_eq!(&after[8..11], &VERSION);
        // Same fields and values, read back through the moved sections.
        let read = |bytes: &[u8]| {
            let path = std::env::temp_dir().join(format!("usdc-read-{}.usdc", std::process::id()));
            std::fs::write(&path, bytes).unwrap();
            let data = openusd::usdc::read_file(&path).unwrap();
            std::fs::remove_file(&path).unwrap();
            let get = |p: &str, f: &str| {
                let p = if p == "/" {
                    sdf::Path::abs_root()
                } else {
                    sdf::path(p).unwrap()
                };
                data.get_field(&p, f).unwrap().into_owned()
            };
            [
                get("/", "primChildren"),
                get("/A", "primChildren"),
                get("/A/b", ChildrenKey::PropertyChildren.as_str()),
                get("/A/b.size", "default"),
            ]
        };
        assert_eq!(read(&before), read(&after));
        // Already right: left alone.
        assert_eq!(retagged(&after), after);
    }
}
