//! One USD file per run (`OUT/morph.usda`): the whole sequence as time samples, for Blender,
//! Houdini, Maya or any USD client.
//!
//! It is text USD (`.usda`) written directly: the format is plain text with a published
//! grammar, a run writes only three prims, and no Rust crate reads and writes USD layers well
//! enough to rely on. The file is assembled once the frames are on disk, from them (the PLY
//! points and the OBJ surfaces), one attribute at a time, so it needs one frame in memory and
//! covers frames written before a `--resume` too.
//!
//! ```text
//! /Morph                 Xform (kind component), the stage's default prim
//!   /Morph/particles     Points: points, velocities, ids, widths, primvars:J (vertex)
//!   /Morph/carried       Mesh: the source's topology, primvars:st (faceVarying), points and
//!                        velocities per frame
//!   /Morph/rebuilt       Mesh: topology and points per frame
//! ```
//!
//! Frame k (from 1) is time code k; `timeCodesPerSecond` and `framesPerSecond` are the run's
//! fps, so the sequence plays at the shot's rate. Y is up (the meshes' own convention), and a
//! unit of the source mesh is taken as a metre.

use nalgebra::Vector3;
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};

/// The file's name in the output folder.
pub const FILE: &str = "morph.usda";

/// What the USD file is made from: each frame's files, in order, relative to `dir`.
pub struct UsdSequence<'a> {
    pub dir: &'a Path,
    /// The first frame's time code (`--start-frame`); frame `k` (0-based) is at `start + k`.
    pub start: usize,
    pub fps: f64,
    pub points: Vec<PathBuf>,
    pub carried: Option<Vec<PathBuf>>,
    pub rebuilt: Option<Vec<PathBuf>>,
    /// Point width (the particle spacing), world units.
    pub width: f64,
}

/// A mesh frame read from an OBJ: positions, and per face its vertex and texture indices.
#[derive(Default)]
struct ObjFrame {
    positions: Vec<Vector3<f64>>,
    uvs: Vec<[f64; 2]>,
    counts: Vec<usize>,
    indices: Vec<usize>,
    uv_indices: Vec<Option<usize>>,
}

fn bad(what: &Path, why: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!("{}: {why}", what.display()),
    )
}

/// Reads an OBJ frame (vertices, texture coordinates, polygon faces).
fn read_obj(path: &Path) -> std::io::Result<ObjFrame> {
    let file = std::io::BufReader::new(std::fs::File::open(path)?);
    let mut frame = ObjFrame::default();
    for line in file.lines() {
        let line = line?;
        let mut words = line.split_whitespace();
        let numbers = |words: std::str::SplitWhitespace| -> Vec<f64> {
            words.filter_map(|w| w.parse().ok()).collect()
        };
        match words.next() {
            Some("v") => {
                let v = numbers(words);
                if v.len() < 3 {
                    return Err(bad(path, "a vertex with fewer than 3 coordinates"));
                }
                frame.positions.push(Vector3::new(v[0], v[1], v[2]));
            }
            Some("vt") => {
                let t = numbers(words);
                frame.uvs.push([
                    t.first().copied().unwrap_or(0.0),
                    t.get(1).copied().unwrap_or(0.0),
                ]);
            }
            Some("f") => {
                let mut count = 0;
                for corner in words {
                    let mut parts = corner.split('/');
                    let index = |s: Option<&str>, n: usize| -> Option<usize> {
                        let i: i64 = s.filter(|s| !s.is_empty())?.parse().ok()?;
                        let i = if i < 0 { n as i64 + i } else { i - 1 };
                        (0..n as i64).contains(&i).then_some(i as usize)
                    };
                    let v = index(parts.next(), frame.positions.len()).ok_or_else(|| {
                        bad(path, format!("a face corner '{corner}' out of range"))
                    })?;
                    frame.indices.push(v);
                    frame.uv_indices.push(index(parts.next(), frame.uvs.len()));
                    count += 1;
                }
                frame.counts.push(count);
            }
            _ => {}
        }
    }
    Ok(frame)
}

/// A frame's particles: positions, velocities and `J`.
pub struct PointsFrame {
    pub x: Vec<Vector3<f64>>,
    pub v: Vec<Vector3<f64>>,
    pub j: Vec<f64>,
}

/// Reads a frame PLY written by [`super::frames::write_points_ply`].
pub fn read_points_ply(path: &Path) -> std::io::Result<PointsFrame> {
    let bytes = std::fs::read(path)?;
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| bad(path, "no PLY header"))?
        + end.len();
    let header = std::str::from_utf8(&bytes[..at]).map_err(|e| bad(path, e))?;
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .ok_or_else(|| bad(path, "no vertex count"))?;
    let properties = header
        .lines()
        .filter(|l| l.starts_with("property "))
        .count();
    let floats: Vec<f32> = bytes[at..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    if properties < 7 || floats.len() < n * properties {
        return Err(bad(path, "a frame PLY of another layout"));
    }
    let (mut x, mut v, mut j) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for p in floats.chunks_exact(properties).take(n) {
        x.push(Vector3::new(p[0], p[1], p[2]).cast::<f64>());
        v.push(Vector3::new(p[3], p[4], p[5]).cast::<f64>());
        j.push(p[6] as f64);
    }
    Ok(PointsFrame { x, v, j })
}

fn vec3s(w: &mut dyn Write, values: &[Vector3<f64>]) -> std::io::Result<()> {
    write!(w, "[")?;
    for (i, p) in values.iter().enumerate() {
        if i > 0 {
            write!(w, ", ")?;
        }
        write!(w, "({}, {}, {})", p.x as f32, p.y as f32, p.z as f32)?;
    }
    write!(w, "]")
}

fn list<T: std::fmt::Display>(
    w: &mut dyn Write,
    values: impl IntoIterator<Item = T>,
) -> std::io::Result<()> {
    write!(w, "[")?;
    for (i, v) in values.into_iter().enumerate() {
        if i > 0 {
            write!(w, ", ")?;
        }
        write!(w, "{v}")?;
    }
    write!(w, "]")
}

/// `extent` of a point set: its bounding box.
fn extent(points: &[Vector3<f64>]) -> [Vector3<f64>; 2] {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    if points.is_empty() {
        [Vector3::zeros(), Vector3::zeros()]
    } else {
        [lo, hi]
    }
}

/// Writes `name.timeSamples = { start + k: value, ... }` for every frame, `value` writing
/// frame `k`'s (0-based).
fn samples(
    w: &mut dyn Write,
    start: usize,
    declaration: &str,
    frames: usize,
    value: impl Fn(&mut dyn Write, usize) -> std::io::Result<()> + Sync,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    writeln!(w, "        {declaration}.timeSamples = {{")?;
    // Frames are read and formatted in parallel, a batch at a time (text is most of the
    // cost), and written in order: the same bytes on any thread count.
    const BATCH: usize = 8;
    for batch in (0..frames).step_by(BATCH) {
        let texts: Vec<Vec<u8>> = (batch..(batch + BATCH).min(frames))
            .into_par_iter()
            .map(|k| {
                let mut text = Vec::new();
                write!(text, "            {}: ", start + k)?;
                value(&mut text, k)?;
                writeln!(text, ",")?;
                Ok(text)
            })
            .collect::<std::io::Result<_>>()?;
        for text in texts {
            w.write_all(&text)?;
        }
    }
    writeln!(w, "        }}")
}

/// Writes `primvars:rest`, each point where it is on the first frame (the rest shape), for
/// procedural textures that must stick to the body.
fn rest(w: &mut dyn Write, first: &[Vector3<f64>]) -> std::io::Result<()> {
    write!(w, "        point3f[] primvars:rest = ")?;
    vec3s(w, first)?;
    writeln!(w, " (\n            interpolation = \"vertex\"\n        )")
}

/// Writes the USD file of `seq` to `path` (atomically).
pub fn write_usda(path: &Path, seq: &UsdSequence) -> std::io::Result<()> {
    let n = seq.points.len();
    let at = |p: &PathBuf| seq.dir.join(p);
    crate::io::write_atomically(path, |file| {
        let w: &mut dyn Write = file;
        writeln!(w, "#usda 1.0")?;
        writeln!(
            w,
            "(\n    defaultPrim = \"Morph\"\n    doc = \"morph {} sequence\"\n    startTimeCode = {start}\n    endTimeCode = {end}\n    timeCodesPerSecond = {fps}\n    framesPerSecond = {fps}\n    upAxis = \"Y\"\n    metersPerUnit = 1\n)\n",
            env!("CARGO_PKG_VERSION"),
            start = seq.start,
            end = seq.start + n - 1,
            fps = seq.fps
        )?;
        writeln!(w, "def Xform \"Morph\" (\n    kind = \"component\"\n)\n{{")?;

        // Particles.
        let x0 = read_points_ply(&at(&seq.points[0]))?.x;
        writeln!(w, "    def Points \"particles\"\n    {{")?;
        write!(w, "        int64[] ids = ")?;
        list(w, 0..x0.len())?;
        writeln!(w)?;
        write!(w, "        float[] widths = ")?;
        list(w, std::iter::repeat_n(seq.width as f32, x0.len()))?;
        writeln!(w)?;
        rest(w, &x0)?;
        let read = |k: usize| read_points_ply(&at(&seq.points[k]));
        samples(w, seq.start, "point3f[] points", n, |w, k| {
            vec3s(w, &read(k)?.x)
        })?;
        samples(w, seq.start, "vector3f[] velocities", n, |w, k| {
            vec3s(w, &read(k)?.v)
        })?;
        samples(w, seq.start, "float3[] extent", n, |w, k| {
            vec3s(w, &extent(&read(k)?.x))
        })?;
        writeln!(
            w,
            "        float[] primvars:J (\n            interpolation = \"vertex\"\n        )"
        )?;
        samples(w, seq.start, "float[] primvars:J", n, |w, k| {
            list(w, read(k)?.j.iter().map(|j| *j as f32))
        })?;
        writeln!(w, "    }}")?;

        // The carried surface: the source's topology and UVs, points and velocities per frame.
        if let Some(files) = &seq.carried {
            let first = read_obj(&at(&files[0]))?;
            writeln!(w, "\n    def Mesh \"carried\"\n    {{")?;
            writeln!(w, "        uniform token subdivisionScheme = \"none\"")?;
            writeln!(w, "        uniform token orientation = \"rightHanded\"")?;
            write!(w, "        int[] faceVertexCounts = ")?;
            list(w, &first.counts)?;
            write!(w, "\n        int[] faceVertexIndices = ")?;
            list(w, &first.indices)?;
            writeln!(w)?;
            rest(w, &first.positions)?;
            if !first.uvs.is_empty() && first.uv_indices.iter().all(Option::is_some) {
                write!(w, "        texCoord2f[] primvars:st = ")?;
                write!(w, "[")?;
                for (i, t) in first.uvs.iter().enumerate() {
                    if i > 0 {
                        write!(w, ", ")?;
                    }
                    write!(w, "({}, {})", t[0] as f32, t[1] as f32)?;
                }
                writeln!(
                    w,
                    "] (\n            interpolation = \"faceVarying\"\n        )"
                )?;
                write!(w, "        int[] primvars:st:indices = ")?;
                list(w, first.uv_indices.iter().map(|i| i.expect("checked")))?;
                writeln!(w)?;
            }
            let read = |k: usize| read_obj(&at(&files[k])).map(|f| f.positions);
            samples(w, seq.start, "point3f[] points", n, |w, k| {
                vec3s(w, &read(k)?)
            })?;
            // Velocities by central differences of the frames (one-sided at the ends).
            samples(w, seq.start, "vector3f[] velocities", n, |w, k| {
                let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
                let (pa, pb) = (read(a)?, read(b)?);
                let dt = (b - a).max(1) as f64 / seq.fps;
                let v: Vec<Vector3<f64>> = pa.iter().zip(&pb).map(|(p, q)| (q - p) / dt).collect();
                vec3s(w, &v)
            })?;
            samples(w, seq.start, "float3[] extent", n, |w, k| {
                vec3s(w, &extent(&read(k)?))
            })?;
            writeln!(w, "    }}")?;
        }

        // The rebuilt surface: its topology changes from frame to frame.
        if let Some(files) = &seq.rebuilt {
            let read = |k: usize| read_obj(&at(&files[k]));
            writeln!(w, "\n    def Mesh \"rebuilt\"\n    {{")?;
            writeln!(w, "        uniform token subdivisionScheme = \"none\"")?;
            samples(w, seq.start, "int[] faceVertexCounts", n, |w, k| {
                list(w, &read(k)?.counts)
            })?;
            samples(w, seq.start, "int[] faceVertexIndices", n, |w, k| {
                list(w, &read(k)?.indices)
            })?;
            samples(w, seq.start, "point3f[] points", n, |w, k| {
                vec3s(w, &read(k)?.positions)
            })?;
            samples(w, seq.start, "float3[] extent", n, |w, k| {
                vec3s(w, &extent(&read(k)?.positions))
            })?;
            writeln!(w, "    }}")?;
        }
        writeln!(w, "}}")?;
        Ok(())
    })
}
