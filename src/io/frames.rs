//! Per-frame particle files: binary little-endian PLY with `x y z` (world position),
//! `vx vy vz` (world velocity, units per second) and `J` (volume ratio det F), all float32.
//! Blender's PLY importer and Houdini's File SOP read these as point clouds with attributes.
//!
//! Written by hand rather than through ply-rs-bw: the layout is fixed and a frame is one
//! header plus a flat block of floats, which is several times faster than building a
//! property map per particle.

use super::write_atomically;
use nalgebra::Vector3;
use std::io::Write;
use std::path::Path;

pub fn write_points_ply(
    path: &Path,
    positions: &[Vector3<f64>],
    velocities: &[Vector3<f64>],
    volume_ratio: &[f64],
) -> std::io::Result<()> {
    assert_eq!(positions.len(), velocities.len());
    assert_eq!(positions.len(), volume_ratio.len());
    // Exit 0 means every written value is finite: refuse what float32 cannot hold.
    for p in 0..positions.len() {
        let values = positions[p].iter().chain(velocities[p].iter());
        if !values
            .chain(std::iter::once(&volume_ratio[p]))
            .all(|&c| (c as f32).is_finite())
        {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("particle {p} has a value that is not a finite 32-bit float"),
            ));
        }
    }
    write_atomically(path, |w| {
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment morph {} particle frame\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float vx\nproperty float vy\nproperty float vz\nproperty float J\nproperty int id\nend_header\n",
            env!("CARGO_PKG_VERSION"),
            positions.len()
        )?;
        let mut buf = Vec::with_capacity(positions.len() * 32);
        for p in 0..positions.len() {
            for c in positions[p].iter().chain(velocities[p].iter()) {
                buf.extend_from_slice(&(*c as f32).to_le_bytes());
            }
            buf.extend_from_slice(&(volume_ratio[p] as f32).to_le_bytes());
            // The particle's id: its index, the same on every frame.
            buf.extend_from_slice(&(p as i32).to_le_bytes());
        }
        w.write_all(&buf)
    })
}
