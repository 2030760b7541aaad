//! The device's floating-point precision: f64 where the adapter has it (the CPU engine's, to
//! within rounding), or f32 for consumer GPUs, whose f64 runs at 1/32-1/64 of their f32 rate.
//! The shaders are written once in f64 and made f32 by text; the host converts at the
//! boundary and keeps f64.

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    #[default]
    F64,
    F32,
}

impl Precision {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Precision; 2] = [Precision::F64, Precision::F32];

    /// Bytes of one real on the device.
    pub fn bytes(self) -> usize {
        match self {
            Precision::F64 => 8,
            Precision::F32 => 4,
        }
    }

    /// Host reals as the device holds them.
    pub fn encode(self, values: &[f64]) -> Vec<u8> {
        match self {
            Precision::F64 => bytemuck::cast_slice(values).to_vec(),
            Precision::F32 => {
                let narrow: Vec<f32> = values.iter().map(|&v| v as f32).collect();
                bytemuck::cast_slice(&narrow).to_vec()
            }
        }
    }

    /// Device reals as the host holds them.
    pub fn decode(self, bytes: &[u8]) -> Vec<f64> {
        match self {
            Precision::F64 => bytemuck::pod_collect_to_vec(bytes),
            Precision::F32 => bytemuck::pod_collect_to_vec::<u8, f32>(bytes)
                .into_iter()
                .map(f64::from)
                .collect(),
        }
    }

    /// The step's and the reverse's WGSL in this precision.
    pub fn shader(self) -> String {
        let f64_source = concat!(include_str!("step.wgsl"), include_str!("reverse.wgsl"));
        match self {
            Precision::F64 => f64_source.to_string(),
            Precision::F32 => to_f32(f64_source),
        }
    }
}

/// The f64 source in f32: the type, its literals' suffix (`1.5lf` -> `1.5f`), its largest
/// finite value and the polar iteration's tolerance.
fn to_f32(source: &str) -> String {
    let source = source
        .replace("f64", "f32")
        .replace("1.7976931348623157e308lf", "3.4028235e38lf")
        .replace("POLAR_TOL: f32 = 1e-15lf", "POLAR_TOL: f32 = 1e-6lf");
    let chars: Vec<char> = source.chars().collect();
    let mut out = String::with_capacity(source.len());
    let mut i = 0;
    while i < chars.len() {
        let literal_end = i > 0
            && chars[i] == 'l'
            && chars.get(i + 1) == Some(&'f')
            && chars[i - 1].is_ascii_digit()
            && !chars
                .get(i + 2)
                .is_some_and(|c| c.is_alphanumeric() || *c == '_');
        if literal_end {
            i += 1; // drop the `l`, keep the `f`
            continue;
        }
        out.push(chars[i]);
        i += 1;
    }
    out
}
