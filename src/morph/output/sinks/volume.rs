//! `volumes/frame_NNNN.vdb` (`--volume`): each frame's fill field, the field the rebuilt
//! surface is the 1/2 level set of, as an OpenVDB float grid `density` in world units, for
//! rendering the body as a volume (Blender, Houdini) or meshing it elsewhere.

use super::rebuilt::fill_field_of;
use super::{FrameRecord, FrameSink, SinkFrame, out_err};
use crate::geometry::Similarity;
use crate::morph::MorphError;
use crate::morph::settings::RebuiltMethod;
use std::path::PathBuf;
use std::sync::Arc;

/// The grid's name in each file: what renderers read as a volume's density.
pub const GRID: &str = "density";

pub struct VolumeVdb {
    /// The `volumes` folder.
    pub dir: PathBuf,
    pub method: RebuiltMethod,
    /// Particle spacing (simulation units) and rest volume.
    pub spacing: f64,
    pub rest_volume: f64,
    /// Each particle's weight in the deformed kernels' field (`MorphGeometry::source_edge_weights`).
    pub edge_weights: Arc<[f64]>,
    pub to_world: Similarity,
}

impl FrameSink for VolumeVdb {
    fn name(&self) -> &'static str {
        "volume"
    }

    fn frame(&mut self, frame: &SinkFrame, _: &mut FrameRecord) -> Result<(), MorphError> {
        let field = fill_field_of(
            self.method,
            frame,
            self.rest_volume,
            &self.edge_weights,
            self.spacing,
        )
        .map_err(|e| MorphError::Output(e.to_string()))?;
        let path = self.dir.join(format!("{}.vdb", frame.name()));
        // A similarity keeps the lattice axis-aligned: its origin and spacing map over.
        let origin = self.to_world.apply(&field.origin);
        let dx = field.h * self.to_world.scale;
        crate::io::vdb::write_float_grid(&path, GRID, field.dims, origin.into(), dx, &field.values)
            .map_err(|e| out_err("volume", &path, e))
    }
}
