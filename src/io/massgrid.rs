//! The nodal mass grid file (`final_mass.mgrid`), and comparing two of them.
//!
//! Layout (all little-endian):
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `MORPHMG1` |
//! | 4 | u32: length H of the JSON header |
//! | H | JSON: `{"dims":[nx,ny,nz],"origin":[x,y,z],"dx":h,"dtype":"f64le","order":"x-slowest","units":"world","mass_units":"simulation"}` |
//! | 8 nx ny nz | f64 node masses, node (i,j,k) at index (i*ny + j)*nz + k |
//!
//! `dims` counts nodes; node (i,j,k) sits at `origin + dx * (i,j,k)` in world units (`units`
//! names the unit of `origin` and `dx`). Masses are in simulation units, density x sim volume
//! (`mass_units`; files written before that field existed read as "simulation" too); both
//! files of a comparison come from the same kind of run, so only their agreement matters.

use super::write_atomically;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

const MAGIC: &[u8; 8] = b"MORPHMG1";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MassGridHeader {
    pub dims: [usize; 3],
    pub origin: [f64; 3],
    pub dx: f64,
    pub dtype: String,
    pub order: String,
    /// Unit of `origin` and `dx`: "world" (the source mesh's units).
    pub units: String,
    /// Unit of the masses: "simulation" (density x simulation-frame volume).
    #[serde(default = "simulation_units")]
    pub mass_units: String,
}

fn simulation_units() -> String {
    "simulation".into()
}

#[derive(Clone, Debug, PartialEq)]
pub struct MassGrid {
    pub header: MassGridHeader,
    pub values: Vec<f64>,
}

impl MassGrid {
    pub fn new(dims: [usize; 3], origin: [f64; 3], dx: f64, values: Vec<f64>) -> MassGrid {
        assert_eq!(dims[0] * dims[1] * dims[2], values.len());
        MassGrid {
            header: MassGridHeader {
                dims,
                origin,
                dx,
                dtype: "f64le".into(),
                order: "x-slowest".into(),
                units: "world".into(),
                mass_units: simulation_units(),
            },
            values,
        }
    }

    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        if let Some(i) = self.values.iter().position(|v| !v.is_finite()) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("node {:?} has a non-finite mass", self.node(i)),
            ));
        }
        let header = serde_json::to_vec(&self.header).map_err(std::io::Error::other)?;
        write_atomically(path, |w| {
            w.write_all(MAGIC)?;
            w.write_all(&(header.len() as u32).to_le_bytes())?;
            w.write_all(&header)?;
            let mut buf = Vec::with_capacity(self.values.len() * 8);
            for v in &self.values {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            w.write_all(&buf)
        })
    }

    /// The (i, j, k) of flat index `index`.
    pub fn node(&self, index: usize) -> [usize; 3] {
        let [_, ny, nz] = self.header.dims;
        [index / (ny * nz), (index / nz) % ny, index % nz]
    }

    /// Reads and checks a mass grid file; errors name the file and the problem.
    pub fn read(path: &Path) -> Result<MassGrid, String> {
        let bytes = crate::files::read(path, crate::files::MASS_GRID_BYTES)
            .map_err(|e| format!("cannot read '{}': {e}", path.display()))?;
        MassGrid::from_bytes(path, &bytes)
    }

    /// [`MassGrid::read`] on bytes already read; `path` names the file in messages.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<MassGrid, String> {
        let name = path.display();
        if bytes.len() < 12 || &bytes[..8] != MAGIC {
            return Err(format!("'{name}' is not a morph mass grid (bad magic)"));
        }
        let h = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes")) as usize;
        let body = 12usize
            .checked_add(h)
            .filter(|&b| b <= bytes.len())
            .ok_or_else(|| format!("'{name}': truncated header"))?;
        let header: MassGridHeader = serde_json::from_slice(&bytes[12..body]).map_err(|e| {
            format!(
                "'{name}': bad header: {}",
                crate::files::short_message(&e.to_string())
            )
        })?;
        if header.dtype != "f64le" {
            return Err(format!(
                "'{name}': unsupported dtype '{}' (morph reads f64le)",
                short(&header.dtype)
            ));
        }
        let z_slowest = match header.order.as_str() {
            "x-slowest" => false,
            "z-slowest" => true,
            other => {
                return Err(format!(
                    "'{name}': unsupported order '{}' (morph reads x-slowest or z-slowest)",
                    short(other)
                ));
            }
        };
        if header.units != "world" {
            return Err(format!(
                "'{name}': unsupported units '{}' (morph's grids are in world units)",
                short(&header.units)
            ));
        }
        if header.mass_units != "simulation" {
            return Err(format!(
                "'{name}': unsupported mass_units '{}' (morph's masses are in simulation units)",
                short(&header.mass_units)
            ));
        }
        let n = header
            .dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .ok_or_else(|| format!("'{name}': dims {:?} overflow", header.dims))?;
        if n.checked_mul(8) != Some(bytes.len() - body) {
            return Err(format!(
                "'{name}': {} data bytes for {n} nodes (expected {})",
                bytes.len() - body,
                n * 8
            ));
        }
        let stored: Vec<f64> = bytes[body..]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        // Held x-slowest in memory, whatever the file's order, so nodes compare as nodes.
        let values = if z_slowest {
            let [nx, ny, nz] = header.dims;
            let mut v = Vec::with_capacity(n);
            for i in 0..nx {
                for j in 0..ny {
                    for k in 0..nz {
                        v.push(stored[i + nx * (j + ny * k)]);
                    }
                }
            }
            v
        } else {
            stored
        };
        let header = MassGridHeader {
            order: "x-slowest".into(),
            ..header
        };
        Ok(MassGrid { header, values })
    }
}

/// At most a few dozen characters of a value read from a file, for an error message.
fn short(s: &str) -> String {
    crate::files::quote_short(s)
}

/// Outcome of comparing two grids.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Comparison {
    pub nodes: usize,
    pub max_abs_diff: f64,
    pub mean_abs_diff: f64,
    /// Largest |a - b| / (atol + rtol |b|): 1 or less means within tolerance.
    pub worst_ratio: f64,
    pub within_tolerance: bool,
    /// The first node where either grid holds NaN or infinity (then never within tolerance).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub non_finite: Option<NonFinite>,
}

/// A node where a grid holds a non-finite value.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NonFinite {
    pub node: [usize; 3],
    pub index: usize,
    /// The values as text ("NaN", "inf", or the number), since JSON has no NaN.
    pub a: String,
    pub b: String,
    /// Nodes with a non-finite value in either grid.
    pub count: usize,
}

/// Compares `a` with the reference `b`: equal when every node has
/// `|a - b| <= atol + rtol * |b|` (numpy's `allclose`). Grids of different shape, origin or
/// spacing are an error.
pub fn compare(a: &MassGrid, b: &MassGrid, rtol: f64, atol: f64) -> Result<Comparison, String> {
    let (ha, hb) = (&a.header, &b.header);
    if ha.dims != hb.dims {
        return Err(format!(
            "incompatible grids: dims {:?} vs {:?}",
            ha.dims, hb.dims
        ));
    }
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1e-300);
    if !close(ha.dx, hb.dx) || (0..3).any(|i| !close(ha.origin[i], hb.origin[i])) {
        return Err(format!(
            "incompatible grids: origin {:?} dx {} vs origin {:?} dx {}",
            ha.origin, ha.dx, hb.origin, hb.dx
        ));
    }
    let mut max_abs: f64 = 0.0;
    let mut sum = crate::loss::CompensatedSum::default();
    let mut worst: f64 = 0.0;
    let mut non_finite: Option<NonFinite> = None;
    for (i, (&x, &y)) in a.values.iter().zip(&b.values).enumerate() {
        if !(x.is_finite() && y.is_finite()) {
            worst = f64::INFINITY;
            match &mut non_finite {
                Some(n) => n.count += 1,
                None => {
                    non_finite = Some(NonFinite {
                        node: a.node(i),
                        index: i,
                        a: x.to_string(),
                        b: y.to_string(),
                        count: 1,
                    })
                }
            }
            continue;
        }
        let d = (x - y).abs();
        max_abs = max_abs.max(d);
        sum.add(d);
        let allowed = atol + rtol * y.abs();
        worst = worst.max(if allowed > 0.0 {
            d / allowed
        } else if d > 0.0 {
            f64::INFINITY
        } else {
            0.0
        });
    }
    let nodes = a.values.len();
    Ok(Comparison {
        nodes,
        max_abs_diff: max_abs,
        mean_abs_diff: sum.value() / nodes.max(1) as f64,
        worst_ratio: worst,
        within_tolerance: worst <= 1.0 && non_finite.is_none(),
        non_finite,
    })
}
