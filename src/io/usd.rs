//! One USD file per run (`OUT/morph.usdc`, or `.usda` as text): the whole sequence as time
//! samples, for Blender, Houdini, Maya or any USD client.
//!
//! The layer is built with `openusd` (a pure-Rust USD library: its `sdf` data model and its
//! crate (`.usdc`) and text (`.usda`) writers), so both formats hold the same prims and
//! values. Binary is the default: the text (floats at double width) is about five times its
//! size, and a client opens the binary and reads every frame without parsing text. The file is assembled once the frames are on
//! disk, from them (the PLY points and the OBJ surfaces), so it covers frames written before
//! a `--resume` too; the writer needs the whole layer in memory (about the size of the
//! `.usdc`). `openusd` 0.6's binary files need two corrections before Pixar's USD opens them
//! (`usdc_fix.rs`).
//!
//! ```text
//! /Morph                 Xform (kind component), the stage's default prim
//!   /Morph/particles     Points: points, velocities, ids, widths, primvars:J (vertex),
//!                        primvars:rest (the first frame's points)
//!   /Morph/carried       Mesh: the source's topology, primvars:st (faceVarying), points and
//!                        velocities per frame, primvars:rest
//!   /Morph/target_carried  Mesh (--surface all): the last target's topology, the same
//!                        attributes; `primvars:weight` (constant, per frame) on it and on
//!                        /Morph/carried: the target's share of a cross-fade, and 1 minus it
//!   /Morph/rebuilt       Mesh: topology and points per frame
//!   /Morph/volume        Volume (--volume): field:density -> /Morph/volume/density, an
//!                        OpenVDBAsset whose filePath is each frame's volumes/frame_NNNN.vdb
//! ```
//!
//! Frame k (0-based) is time code `start + k` (`--start-frame`); `timeCodesPerSecond` and
//! `framesPerSecond` are the run's fps, so the sequence plays at the shot's rate. Y is up (the
//! meshes' own convention), and a unit of the source mesh is taken as a metre.

use nalgebra::Vector3;
use openusd::gf;
use openusd::sdf::{
    self, ChildrenKey, FieldKey, SpecData, SpecType, Specifier, Value, Variability,
};
use serde::{Deserialize, Serialize};
use std::io::BufRead;
use std::path::{Path, PathBuf};

/// The stage's default prim, under which everything is.
const ROOT: &str = "Morph";

/// The files' names in the output folder.
pub const USDC_FILE: &str = "morph.usdc";
pub const USDA_FILE: &str = "morph.usda";

/// Which USD file a run writes (`--usd`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UsdFormat {
    /// Binary (crate) USD, `morph.usdc`: what DCC exporters write.
    #[default]
    Usdc,
    /// Text USD, `morph.usda`: readable, about five times larger.
    Usda,
    /// No USD file.
    None,
}

impl UsdFormat {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [UsdFormat; 3] = [UsdFormat::Usdc, UsdFormat::Usda, UsdFormat::None];

    /// The file's name in the output folder, if one is written.
    pub fn file_name(self) -> Option<&'static str> {
        match self {
            UsdFormat::Usdc => Some(USDC_FILE),
            UsdFormat::Usda => Some(USDA_FILE),
            UsdFormat::None => None,
        }
    }
}

/// What the USD file is made from: each frame's files, in order, relative to `dir`.
pub struct UsdSequence<'a> {
    pub dir: &'a Path,
    /// The first frame's time code (`--start-frame`); frame `k` (0-based) is at `start + k`.
    pub start: usize,
    pub fps: f64,
    pub points: Vec<PathBuf>,
    pub carried: Option<Vec<PathBuf>>,
    /// The last target's carried surface and its weight on each frame (`--surface all`).
    pub target_carried: Option<(Vec<PathBuf>, Vec<f64>)>,
    pub rebuilt: Option<Vec<PathBuf>>,
    /// Each frame's OpenVDB file (`--volume`), with its grid `density`.
    pub volumes: Option<Vec<PathBuf>>,
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

fn vec3f(p: &Vector3<f64>) -> gf::Vec3f {
    gf::Vec3f::from([p.x as f32, p.y as f32, p.z as f32])
}

fn vec3fs(values: &[Vector3<f64>]) -> Value {
    Value::Vec3fVec(values.iter().map(vec3f).collect())
}

fn ints(values: &[usize]) -> Value {
    Value::IntVec(values.iter().map(|&i| i as i32).collect())
}

/// `extent` of a point set: its bounding box.
fn extent(points: &[Vector3<f64>]) -> Value {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    if points.is_empty() {
        (lo, hi) = (Vector3::zeros(), Vector3::zeros());
    }
    vec3fs(&[lo, hi])
}

/// Reads every frame `read(k)` in parallel (reading and decoding is most of the cost) and
/// returns the results in frame order: the same layer on any thread count.
fn per_frame<T: Send>(
    frames: usize,
    read: impl Fn(usize) -> std::io::Result<T> + Sync,
) -> std::io::Result<Vec<T>> {
    use rayon::prelude::*;
    (0..frames).into_par_iter().map(&read).collect()
}

/// Each frame's `K` attribute values regrouped as each attribute's values over the frames.
fn by_attribute<const K: usize>(frames: Vec<[Value; K]>) -> [Vec<Value>; K] {
    let mut out: [Vec<Value>; K] = std::array::from_fn(|_| Vec::with_capacity(frames.len()));
    for frame in frames {
        for (values, v) in out.iter_mut().zip(frame) {
            values.push(v);
        }
    }
    out
}

/// A USD layer under construction: prims and their attributes, in the order they are
/// authored. Both file formats are written from it (`openusd`'s crate and text writers).
struct Layer {
    data: sdf::Data,
    /// Frame `k` (0-based) is at time code `start + k`.
    start: usize,
}

impl Layer {
    /// An empty layer with the stage's metadata: the default prim, the time range and rate,
    /// Y up and metres.
    fn new(seq: &UsdSequence, frames: usize) -> Layer {
        let mut data = sdf::Data::new();
        let root = data.create_spec(sdf::Path::abs_root(), SpecType::PseudoRoot);
        root.add(FieldKey::DefaultPrim, Value::Token(ROOT.into()));
        root.add(
            FieldKey::Documentation,
            Value::String(format!("morph {} sequence", env!("CARGO_PKG_VERSION"))),
        );
        root.add(FieldKey::StartTimeCode, Value::Double(seq.start as f64));
        let end = seq.start + frames.max(1) - 1;
        root.add(FieldKey::EndTimeCode, Value::Double(end as f64));
        root.add(FieldKey::TimeCodesPerSecond, Value::Double(seq.fps));
        root.add(FieldKey::FramesPerSecond, Value::Double(seq.fps));
        root.add("upAxis", Value::Token("Y".into()));
        root.add("metersPerUnit", Value::Double(1.0));
        Layer {
            data,
            start: seq.start,
        }
    }

    /// Appends `name` to the `key` children list of the spec at `parent`.
    fn add_child(&mut self, parent: &sdf::Path, key: ChildrenKey, name: &str) {
        let spec = self
            .data
            .spec_mut(parent)
            .expect("the parent was made first");
        match spec.get_mut(key.as_str()) {
            Some(Value::TokenVec(names)) => names.push(name.into()),
            _ => spec.add(key, Value::TokenVec(vec![name.into()])),
        }
    }

    /// Defines the prim `parent/name` of schema `type_name`.
    fn prim(&mut self, parent: &sdf::Path, name: &str, type_name: &str) -> sdf::Path {
        let path = parent
            .append_path(name)
            .expect("prim names are identifiers");
        self.add_child(parent, ChildrenKey::PrimChildren, name);
        let spec = self.data.create_spec(path.clone(), SpecType::Prim);
        spec.add(FieldKey::Specifier, Value::Specifier(Specifier::Def));
        spec.add(FieldKey::TypeName, Value::Token(type_name.into()));
        path
    }

    /// Authors the attribute `prim.name` of USD type `type_name`: `value` for all time, or
    /// a [`Layer::samples`] value, one per frame.
    fn attribute(
        &mut self,
        prim: &sdf::Path,
        name: &str,
        type_name: &str,
        value: Value,
    ) -> &mut SpecData {
        let path = prim
            .append_property(name)
            .expect("attribute names are identifiers");
        self.add_child(prim, ChildrenKey::PropertyChildren, name);
        let spec = self.data.create_spec(path, SpecType::Attribute);
        spec.add(FieldKey::TypeName, Value::Token(type_name.into()));
        let field = match value {
            Value::TimeSamples(_) => FieldKey::TimeSamples,
            _ => FieldKey::Default,
        };
        spec.add(field, value);
        spec
    }

    /// One value per frame, `values[k]` at frame `k`'s time code.
    fn samples(&self, values: Vec<Value>) -> Value {
        let start = self.start;
        Value::TimeSamples(
            values
                .into_iter()
                .enumerate()
                .map(|(k, v)| ((start + k) as f64, v))
                .collect(),
        )
    }

    /// A per-point primvar (`interpolation = "vertex"`) with one value for all time.
    fn vertex_primvar(&mut self, prim: &sdf::Path, name: &str, type_name: &str, value: Value) {
        self.attribute(prim, name, type_name, value)
            .add("interpolation", Value::Token("vertex".into()));
    }

    /// The relationship `prim.name` to the one prim `target`.
    fn relationship(&mut self, prim: &sdf::Path, name: &str, target: &sdf::Path) {
        let path = prim
            .append_property(name)
            .expect("relationship names are identifiers");
        self.add_child(prim, ChildrenKey::PropertyChildren, name);
        let spec = self.data.create_spec(path, SpecType::Relationship);
        spec.add(
            FieldKey::TargetPaths,
            Value::PathListOp(sdf::PathListOp::explicit([target.clone()])),
        );
    }

    /// A `uniform token` attribute (a schema's fixed choice, e.g. `subdivisionScheme`).
    fn uniform_token(&mut self, prim: &sdf::Path, name: &str, value: &str) {
        self.attribute(prim, name, "token", Value::Token(value.into()))
            .add(
                FieldKey::Variability,
                Value::Variability(Variability::Uniform),
            );
    }
}
/// Writes the USD file of `seq` to `path` (atomically) in `format`.
pub fn write(path: &Path, seq: &UsdSequence, format: UsdFormat) -> std::io::Result<()> {
    let layer = build(seq)?;
    let failed = |e: anyhow::Error| std::io::Error::other(format!("{e:#}"));
    crate::io::write_atomically(path, |file| match format {
        UsdFormat::Usdc => {
            openusd::usdc::CrateWriter::write(&layer.data, file).map_err(failed)?;
            std::io::Write::flush(file)?;
            super::usdc_fix::correct(file.get_mut())
        }
        UsdFormat::Usda => openusd::usda::TextWriter::write(&layer.data, file).map_err(failed),
        UsdFormat::None => Ok(()),
    })
}

/// The stage of `seq`: the frames on disk read back into one layer.
fn build(seq: &UsdSequence) -> std::io::Result<Layer> {
    let n = seq.points.len();
    let mut layer = Layer::new(seq, n);
    let root = layer.prim(&sdf::Path::abs_root(), ROOT, "Xform");
    layer
        .data
        .spec_mut(&root)
        .expect("just made")
        .add(FieldKey::Kind, Value::Token("component".into()));
    add_particles(&mut layer, &root, seq)?;
    let weights = seq.target_carried.as_ref().map(|(_, w)| w);
    if let Some(files) = &seq.carried {
        let source_weights = weights.map(|w| w.iter().map(|w| 1.0 - w).collect());
        add_carried(&mut layer, &root, seq, ("carried", files), source_weights)?;
    }
    if let Some((files, w)) = &seq.target_carried {
        add_carried(
            &mut layer,
            &root,
            seq,
            ("target_carried", files),
            Some(w.clone()),
        )?;
    }
    // The rebuilt surface: its topology changes from frame to frame.
    if let Some(files) = &seq.rebuilt {
        add_rebuilt(&mut layer, &root, seq, files)?;
    }
    // The volume: a Volume prim whose `density` field reads each frame's OpenVDB file
    // (paths relative to this file, as the frames are).
    if let Some(files) = &seq.volumes {
        add_volume(&mut layer, &root, files);
    }
    Ok(layer)
}

/// The particles: ids, widths, rest positions, and per frame points, velocities, extent and
/// J.
fn add_particles(layer: &mut Layer, root: &sdf::Path, seq: &UsdSequence) -> std::io::Result<()> {
    let (n, at) = (seq.points.len(), |p: &PathBuf| seq.dir.join(p));
    // Particles: each frame's values made as it is read (in f32, as USD holds them), so no
    // more than one f64 frame per thread is held at once.
    let first = match seq.points.first() {
        Some(p) => Some(read_points_ply(&at(p))?),
        None => None,
    };
    let frames = per_frame(n, |k| {
        let f = read_points_ply(&at(&seq.points[k]))?;
        let j = Value::FloatVec(f.j.iter().map(|&j| j as f32).collect());
        Ok([vec3fs(&f.x), vec3fs(&f.v), extent(&f.x), j])
    })?;
    let particles = layer.prim(root, "particles", "Points");
    let count = first.as_ref().map_or(0, |f| f.x.len());
    layer.attribute(
        &particles,
        "ids",
        "int64[]",
        Value::Int64Vec((0..count as i64).collect()),
    );
    layer.attribute(
        &particles,
        "widths",
        "float[]",
        Value::FloatVec(vec![seq.width as f32; count]),
    );
    if let Some(first) = first {
        layer.vertex_primvar(&particles, "primvars:rest", "point3f[]", vec3fs(&first.x));
    }
    let [points, velocities, extents, j] = by_attribute(frames);
    let points = layer.samples(points);
    layer.attribute(&particles, "points", "point3f[]", points);
    let velocities = layer.samples(velocities);
    layer.attribute(&particles, "velocities", "vector3f[]", velocities);
    let extents = layer.samples(extents);
    layer.attribute(&particles, "extent", "float3[]", extents);
    let j = layer.samples(j);
    layer.vertex_primvar(&particles, "primvars:J", "float[]", j);

    Ok(())
}

/// A carried surface (the prim `name`): its topology and UVs, points and velocities per
/// frame, and its weight in a cross-fade on each frame when given.
fn add_carried(
    layer: &mut Layer,
    root: &sdf::Path,
    seq: &UsdSequence,
    (name, files): (&str, &[PathBuf]),
    weights: Option<Vec<f64>>,
) -> std::io::Result<()> {
    let (n, at) = (seq.points.len(), |p: &PathBuf| seq.dir.join(p));
    // The topology and UVs once, from the first frame; each frame's positions.
    let first = &read_obj(&at(&files[0]))?;
    let frames = per_frame(n, |k| read_obj(&at(&files[k])).map(|f| f.positions))?;
    let carried = layer.prim(root, name, "Mesh");
    if let Some(w) = weights {
        let w = layer.samples(w.iter().map(|&w| Value::Float(w as f32)).collect());
        layer
            .attribute(&carried, "primvars:weight", "float", w)
            .add("interpolation", Value::Token("constant".into()));
    }
    layer.uniform_token(&carried, "subdivisionScheme", "none");
    layer.uniform_token(&carried, "orientation", "rightHanded");
    layer.attribute(&carried, "faceVertexCounts", "int[]", ints(&first.counts));
    layer.attribute(&carried, "faceVertexIndices", "int[]", ints(&first.indices));
    layer.vertex_primvar(
        &carried,
        "primvars:rest",
        "point3f[]",
        vec3fs(&first.positions),
    );
    if !first.uvs.is_empty() && first.uv_indices.iter().all(Option::is_some) {
        let st = first
            .uvs
            .iter()
            .map(|t| gf::Vec2f::from([t[0] as f32, t[1] as f32]))
            .collect();
        layer
            .attribute(&carried, "primvars:st", "texCoord2f[]", Value::Vec2fVec(st))
            .add("interpolation", Value::Token("faceVarying".into()));
        let indices: Vec<usize> = first
            .uv_indices
            .iter()
            .map(|i| i.expect("checked"))
            .collect();
        layer.attribute(&carried, "primvars:st:indices", "int[]", ints(&indices));
    }
    let points = layer.samples(frames.iter().map(|f| vec3fs(f)).collect());
    layer.attribute(&carried, "points", "point3f[]", points);
    // Velocities by central differences of the frames (one-sided at the ends).
    let velocities = (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let dt = (b - a).max(1) as f64 / seq.fps;
            let (pa, pb) = (&frames[a], &frames[b]);
            Value::Vec3fVec(
                pa.iter()
                    .zip(pb)
                    .map(|(p, q)| vec3f(&((q - p) / dt)))
                    .collect(),
            )
        })
        .collect();
    let velocities = layer.samples(velocities);
    layer.attribute(&carried, "velocities", "vector3f[]", velocities);
    let extents = layer.samples(frames.iter().map(|f| extent(f)).collect());
    layer.attribute(&carried, "extent", "float3[]", extents);
    Ok(())
}

/// The rebuilt surface, its topology per frame.
fn add_rebuilt(
    layer: &mut Layer,
    root: &sdf::Path,
    seq: &UsdSequence,
    files: &[PathBuf],
) -> std::io::Result<()> {
    let (n, at) = (seq.points.len(), |p: &PathBuf| seq.dir.join(p));
    // Each frame's values made as it is read, as for the particles.
    let frames = per_frame(n, |k| {
        let f = read_obj(&at(&files[k]))?;
        Ok([
            ints(&f.counts),
            ints(&f.indices),
            vec3fs(&f.positions),
            extent(&f.positions),
        ])
    })?;
    let rebuilt = layer.prim(root, "rebuilt", "Mesh");
    layer.uniform_token(&rebuilt, "subdivisionScheme", "none");
    let [counts, indices, points, extents] = by_attribute(frames);
    let counts = layer.samples(counts);
    layer.attribute(&rebuilt, "faceVertexCounts", "int[]", counts);
    let indices = layer.samples(indices);
    layer.attribute(&rebuilt, "faceVertexIndices", "int[]", indices);
    let points = layer.samples(points);
    layer.attribute(&rebuilt, "points", "point3f[]", points);
    let extents = layer.samples(extents);
    layer.attribute(&rebuilt, "extent", "float3[]", extents);
    Ok(())
}

/// The volume prim and its density field's file per frame.
fn add_volume(layer: &mut Layer, root: &sdf::Path, files: &[PathBuf]) {
    let volume = layer.prim(root, "volume", "Volume");
    let density = layer.prim(&volume, "density", "OpenVDBAsset");
    layer.attribute(
        &density,
        "fieldName",
        "token",
        Value::Token("density".into()),
    );
    let paths = files
        .iter()
        .map(|f| Value::AssetPath(sdf::AssetPath::new(format!("./{}", f.display()))))
        .collect();
    let paths = layer.samples(paths);
    layer.attribute(&density, "filePath", "asset", paths);
    layer.relationship(&volume, "field:density", &density);
}
