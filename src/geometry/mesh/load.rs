//! Meshes in: OBJ and PLY read, checked (sizes, counts, finite coordinates) and repaired
//! where that is safe (welding, winding), each problem a [`MeshError`] naming the file.

use super::super::error::MeshError;
use super::TriMesh;
use nalgebra::Vector3;
use std::path::Path;

/// A mesh read from disk, with the warnings its loading produced (e.g. a missing .mtl).
#[derive(Clone, Debug)]
pub struct LoadedMesh {
    pub mesh: TriMesh,
    pub warnings: Vec<String>,
    /// Vertices merged by welding, and triangles that collapsed doing so.
    pub welded_vertices: usize,
    pub collapsed_triangles: usize,
}

/// Vertices closer than this fraction of the bounding-box diagonal are one vertex.
pub const WELD_TOLERANCE: f64 = 1e-7;

/// File formats morph reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    Obj,
    Ply,
}

impl MeshFormat {
    /// From the extension, or from the `ply` magic when the extension says nothing.
    fn detect(path: &Path, bytes: &[u8]) -> Option<MeshFormat> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("obj") => Some(MeshFormat::Obj),
            Some("ply") => Some(MeshFormat::Ply),
            _ if bytes.starts_with(b"ply") => Some(MeshFormat::Ply),
            _ => None,
        }
    }
}

/// Reads and validates a mesh: the file exists and parses, has triangles, every vertex is
/// finite, indices are in range, and the mesh is not flat. Polygons are fan-triangulated and
/// the orientation is made consistent and outward (a warning says when faces were flipped).
pub fn load_mesh(path: &Path) -> Result<LoadedMesh, MeshError> {
    let bytes =
        crate::files::read(path, crate::files::MESH_BYTES).map_err(|e| MeshError::Unreadable {
            path: path.into(),
            reason: e.to_string(),
        })?;
    parse_mesh(path, &bytes)
}

/// [`load_mesh`] on bytes already read; `path` names the mesh in messages and, by its
/// extension, the format.
pub fn parse_mesh(path: &Path, bytes: &[u8]) -> Result<LoadedMesh, MeshError> {
    if bytes.is_empty() {
        return Err(MeshError::Empty { path: path.into() });
    }
    let format = MeshFormat::detect(path, bytes)
        .ok_or_else(|| MeshError::UnknownFormat { path: path.into() })?;
    let (mesh, warnings) = match format {
        MeshFormat::Obj => parse_obj(path, bytes)?,
        MeshFormat::Ply => (parse_ply(path, bytes)?, Vec::new()),
    };
    prepare_mesh(path, mesh, warnings)
}

/// What loading does after parsing, for meshes from anywhere (a file, or built in memory by a
/// program using the library): validation, welding, topology warnings and orientation repair.
/// `path` names the mesh in messages.
pub fn prepare_mesh(
    path: &Path,
    mut mesh: TriMesh,
    mut warnings: Vec<String>,
) -> Result<LoadedMesh, MeshError> {
    validate(path, &mesh)?;
    // The diagonal formed at unit size: squaring 1e300-unit extents would overflow.
    let extent = mesh.bounds().extent();
    let diagonal = extent.max() * (extent / extent.max()).norm();
    let (welded_vertices, collapsed_triangles) = mesh.weld(WELD_TOLERANCE * diagonal);
    validate(path, &mesh)?;
    let topo = mesh.topology();
    if topo.non_manifold_edges > 0 {
        warnings.push(format!(
            "{}: {} non-manifold edges (shared by three or more faces); inside is decided by winding number",
            path.display(),
            topo.non_manifold_edges
        ));
    }
    if topo.boundary_edges > 0 {
        warnings.push(format!(
            "{}: mesh is open ({} boundary edges); inside is decided by winding number",
            path.display(),
            topo.boundary_edges
        ));
    }
    let flipped = mesh.repair_orientation();
    if flipped > 0 {
        warnings.push(format!(
            "{}: {flipped} of {} faces pointed inward and were flipped",
            path.display(),
            mesh.triangles.len()
        ));
    }
    Ok(LoadedMesh {
        mesh,
        warnings,
        welded_vertices,
        collapsed_triangles,
    })
}

/// Checks that apply to any mesh however it was made.
pub fn validate(path: &Path, mesh: &TriMesh) -> Result<(), MeshError> {
    let bad = |reason: String| {
        Err(MeshError::Invalid {
            path: path.into(),
            reason,
        })
    };
    if mesh.triangles.is_empty() {
        return bad("no faces (a solid needs at least 4 triangles)".into());
    }
    if let Some((i, v)) = mesh
        .vertices
        .iter()
        .enumerate()
        .find(|(_, v)| v.iter().any(|c| !c.is_finite()))
    {
        return bad(format!(
            "vertex {} has a non-finite coordinate ({}, {}, {})",
            i + 1,
            v.x,
            v.y,
            v.z
        ));
    }
    let nv = mesh.vertices.len() as u32;
    if let Some((i, _)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&k| k >= nv))
    {
        return bad(format!(
            "face {} refers to a vertex that does not exist",
            i + 1
        ));
    }
    if mesh.triangles.len() < 4 {
        return bad(format!(
            "only {} triangle(s), which cannot enclose a volume (a solid needs at least 4)",
            mesh.triangles.len()
        ));
    }
    let ext = mesh.bounds().extent();
    let longest = ext.max();
    if longest <= 0.0 {
        return bad("all vertices coincide".into());
    }
    if let Some(axis) = (0..3).find(|&a| ext[a] <= 1e-9 * longest) {
        return bad(format!(
            "flat (zero thickness along {}), so it encloses no volume",
            ["x", "y", "z"][axis]
        ));
    }
    Ok(())
}

fn parse_obj(path: &Path, bytes: &[u8]) -> Result<(TriMesh, Vec<String>), MeshError> {
    let warnings = std::cell::RefCell::new(Vec::new());
    let folder = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    if let Err(e) = std::str::from_utf8(bytes) {
        let at = e.valid_up_to();
        let line = bytes[..at].iter().filter(|&&b| b == b'\n').count() + 1;
        return Err(MeshError::Malformed {
            path: path.into(),
            format: "OBJ",
            reason: format!(
                "line {line} is not text (byte 0x{:02x} at offset {at})",
                bytes[at]
            ),
        });
    }
    // tobj parses `l` (polyline) and `p` (point) lines as faces when they have three or more
    // indices; they are not surface, so they are blanked first (line numbers stay the same).
    let cleaned = without_lines_and_points(bytes);
    let mut reader = std::io::Cursor::new(cleaned.as_deref().unwrap_or(bytes));
    let (models, _materials) = tobj::load_obj_buf(&mut reader, &options, |mtl| {
        // Materials are not used; a missing library is only worth a warning.
        let full = folder.join(mtl);
        if !full.exists() {
            warnings.borrow_mut().push(format!(
                "{}: material library '{}' not found (materials are not used)",
                path.display(),
                mtl.display()
            ));
        }
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| MeshError::Malformed {
        path: path.into(),
        format: "OBJ",
        reason: one_line(&e.to_string()),
    })?;
    let mut mesh = TriMesh::default();
    for model in &models {
        let m = &model.mesh;
        let offset = mesh.vertices.len() as u32;
        mesh.vertices.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| Vector3::new(p[0], p[1], p[2])),
        );
        mesh.triangles.extend(
            m.indices
                .chunks_exact(3)
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }
    Ok((mesh, warnings.into_inner()))
}

/// The OBJ text with every `l` and `p` line emptied, or `None` when it has none.
fn without_lines_and_points(bytes: &[u8]) -> Option<Vec<u8>> {
    let is_element = |line: &[u8]| {
        let t = line.trim_ascii_start();
        (t.starts_with(b"l") || t.starts_with(b"p"))
            && t.get(1).is_none_or(|c| c.is_ascii_whitespace())
    };
    if !bytes.split(|&b| b == b'\n').any(is_element) {
        return None;
    }
    let mut out = Vec::with_capacity(bytes.len());
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if i > 0 {
            out.push(b'\n');
        }
        if !is_element(line) {
            out.extend_from_slice(line);
        }
    }
    Some(out)
}

fn parse_ply(path: &Path, bytes: &[u8]) -> Result<TriMesh, MeshError> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};
    let malformed = |reason: String| MeshError::Malformed {
        path: path.into(),
        format: "PLY",
        reason: one_line(&reason),
    };
    check_ply_counts(bytes).map_err(malformed)?;
    let mut reader = std::io::Cursor::new(bytes);
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut reader)
        .map_err(|e| malformed(e.to_string()))?;
    let scalar = |p: &Property| -> Option<f64> {
        Some(match *p {
            Property::Char(v) => v as f64,
            Property::UChar(v) => v as f64,
            Property::Short(v) => v as f64,
            Property::UShort(v) => v as f64,
            Property::Int(v) => v as f64,
            Property::UInt(v) => v as f64,
            Property::Float(v) => v as f64,
            Property::Double(v) => v,
            _ => return None,
        })
    };
    let index_list = |p: &Property| -> Option<Vec<i64>> {
        Some(match p {
            Property::ListChar(v) => v.iter().map(|&i| i as i64).collect(),
            Property::ListUChar(v) => v.iter().map(|&i| i as i64).collect(),
            Property::ListShort(v) => v.iter().map(|&i| i as i64).collect(),
            Property::ListUShort(v) => v.iter().map(|&i| i as i64).collect(),
            Property::ListInt(v) => v.iter().map(|&i| i as i64).collect(),
            Property::ListUInt(v) => v.iter().map(|&i| i as i64).collect(),
            _ => return None,
        })
    };
    let mut mesh = TriMesh::default();
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or_else(|| malformed("no 'vertex' element".into()))?;
    for (i, v) in vertices.iter().enumerate() {
        let mut c = [0.0; 3];
        for (a, name) in ["x", "y", "z"].iter().enumerate() {
            c[a] = v
                .get(*name)
                .and_then(scalar)
                .ok_or_else(|| malformed(format!("vertex {} has no numeric '{name}'", i + 1)))?;
        }
        mesh.vertices.push(Vector3::from(c));
    }
    let faces = ply.payload.get("face").map(Vec::as_slice).unwrap_or(&[]);
    let nv = mesh.vertices.len() as i64;
    for (fi, f) in faces.iter().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(index_list)
            .ok_or_else(|| malformed(format!("face {} has no vertex index list", fi + 1)))?;
        if let Some(&bad) = list.iter().find(|&&i| i < 0 || i >= nv) {
            return Err(malformed(format!(
                "face {} refers to vertex {bad}, but there are {nv}",
                fi + 1
            )));
        }
        // Fan-triangulate polygons; lists of fewer than 3 indices are skipped.
        for k in 1..list.len().saturating_sub(1) {
            mesh.triangles
                .push([list[0] as u32, list[k] as u32, list[k + 1] as u32]);
        }
    }
    // Triangle strips (Stanford's scans): each list holds strips separated by -1; triangle k
    // of a strip is (s[k], s[k+1], s[k+2]), every second one reversed to keep the strip's
    // orientation; triangles with a repeated corner only join strips and are skipped.
    let strips = ply
        .payload
        .get("tristrips")
        .map(Vec::as_slice)
        .unwrap_or(&[]);
    for (si, f) in strips.iter().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(index_list)
            .ok_or_else(|| malformed(format!("tristrips {} has no vertex index list", si + 1)))?;
        if let Some(&bad) = list.iter().find(|&&i| i < -1 || i >= nv) {
            return Err(malformed(format!(
                "tristrips {} refers to vertex {bad}, but there are {nv}",
                si + 1
            )));
        }
        for strip in list.split(|&i| i == -1) {
            for k in 0..strip.len().saturating_sub(2) {
                let (a, b, c) = (strip[k] as u32, strip[k + 1] as u32, strip[k + 2] as u32);
                if a == b || b == c || a == c {
                    continue;
                }
                mesh.triangles
                    .push(if k % 2 == 0 { [a, b, c] } else { [b, a, c] });
            }
        }
    }
    Ok(mesh)
}

/// Refuses a PLY header whose element counts the file's data cannot hold, before the parser
/// allocates for them (found by fuzzing: `element vertex 4294967295` in a small file made
/// the parser exhaust memory). Headers this check cannot read are left to the parser.
fn check_ply_counts(bytes: &[u8]) -> Result<(), String> {
    let marker = b"end_header";
    let Some(at) = check_ply_header(bytes)? else {
        return Ok(());
    };
    debug_assert!(bytes[at..].starts_with(marker));
    let body = bytes.len().saturating_sub(at + marker.len() + 1) as u128;
    let header = String::from_utf8_lossy(&bytes[..at]);
    let binary = header
        .lines()
        .any(|l| l.trim_start().starts_with("format binary"));
    let size = |t: &str| -> u128 {
        match t {
            "char" | "uchar" | "int8" | "uint8" => 1,
            "short" | "ushort" | "int16" | "uint16" => 2,
            "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
            "double" | "float64" => 8,
            _ => 1,
        }
    };
    // (name, count, least bytes one element takes)
    let mut elements: Vec<(String, u128, u128)> = Vec::new();
    for line in header.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["element", name, count] => {
                let count: u128 = count.parse().unwrap_or(0);
                elements.push((name.to_string(), count, 0));
            }
            ["property", "list", count_type, _, _] => {
                if let Some(e) = elements.last_mut() {
                    e.2 += if binary { size(count_type) } else { 2 };
                }
            }
            ["property", t, _] => {
                if let Some(e) = elements.last_mut() {
                    e.2 += if binary { size(t) } else { 2 };
                }
            }
            _ => {}
        }
    }
    let mut least = 0u128;
    for (name, count, per) in &elements {
        // An element of no properties takes no bytes; still, no file has more of them
        // than it has bytes.
        if *count > body.max(1) && *per == 0 || count * per.max(&1) > body.max(1) * 2 {
            return Err(format!(
                "the header declares {count} '{name}' elements, more than its {body} bytes of data can hold"
            ));
        }
        least += count * per;
    }
    // ASCII separators are counted in `per` (2 per value), so allow for a missing last one.
    if least > body + 1 {
        return Err(format!(
            "the header's elements need at least {least} bytes of data, the file has {body}"
        ));
    }
    Ok(())
}

/// Parser messages can span lines and end in a debug dump; errors are printed on one line.
fn one_line(s: &str) -> String {
    // A parser quotes the line it failed on: the message is cut short, word by word.
    let flat = crate::files::short_message(s);
    match flat.split_once(" Error: ParseError") {
        Some((head, _)) => head.to_string(),
        None => flat,
    }
}

/// The longest PLY header line morph reads (the format's own lines are a few words).
const PLY_HEADER_LINE: usize = 1024;
/// How far into a PLY file its header may end.
const PLY_HEADER_BYTES: usize = 1 << 20;

/// Where a PLY file's `end_header` starts, `None` when the parser should find out (no
/// marker in a short file). Refused here, before the parser reads anything: a file that does
/// not start with `ply`, a header line longer than [`PLY_HEADER_LINE`] (a count of megabytes
/// of digits) or a header not ended within [`PLY_HEADER_BYTES`] (binary junk).
fn check_ply_header(bytes: &[u8]) -> Result<Option<usize>, String> {
    let first = bytes.split(|&b| b == b'\n').next().unwrap_or(&[]);
    if first.trim_ascii() != b"ply" {
        let shown = String::from_utf8_lossy(&first[..first.len().min(PLY_HEADER_LINE)]);
        return Err(format!(
            "the file does not start with the line 'ply' (it starts '{}')",
            crate::files::quote_short(&shown)
        ));
    }
    let marker = b"end_header";
    let mut at = 0;
    for (number, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if line.len() > PLY_HEADER_LINE {
            let shown = String::from_utf8_lossy(&line[..PLY_HEADER_LINE]);
            return Err(format!(
                "header line {} is {} bytes long (at most {PLY_HEADER_LINE}): '{}'",
                number + 1,
                line.len(),
                crate::files::quote_short(&shown)
            ));
        }
        if line.trim_ascii() == marker {
            return Ok(Some(at + line.iter().position(|&b| b == b'e').unwrap_or(0)));
        }
        at += line.len() + 1;
        if at > PLY_HEADER_BYTES {
            return Err(format!(
                "no end_header within the first {PLY_HEADER_BYTES} bytes"
            ));
        }
    }
    Ok(None)
}
