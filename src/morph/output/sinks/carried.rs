//! `carried/frame_NNNN.obj`: the source's own mesh (topology, UVs, groups) carried by the
//! particles it was bound to at rest (`geometry/carried.rs`), with its fold share on every
//! frame and its fidelity to the target on the last.

use super::{FrameRecord, FrameSink, SinkFrame, out_err};
use crate::geometry::Similarity;
use crate::geometry::carried::CarriedSurface;
use crate::geometry::fidelity::{Reference, fidelity};
use crate::morph::MorphError;
use nalgebra::Vector3;
use std::path::PathBuf;
use std::sync::Arc;

pub struct CarriedObj {
    /// The `carried` folder.
    pub dir: PathBuf,
    pub surface: CarriedSurface,
    /// The particles' rest positions the surface was bound to.
    pub rest: Vec<Vector3<f64>>,
    /// Particle spacing, simulation units.
    pub spacing: f64,
    pub to_world: Similarity,
    /// The source and the target surfaces (world units), which the first and the last
    /// frames' surfaces are measured against.
    pub references: Option<Arc<(Reference, Reference)>>,
}

impl FrameSink for CarriedObj {
    fn name(&self) -> &'static str {
        "carried"
    }

    fn frame(&mut self, frame: &SinkFrame, record: &mut FrameRecord) -> Result<(), MorphError> {
        let clock = std::time::Instant::now();
        let state = frame.state;
        let on_frame = self.surface.carry(&self.rest, &state.x, &state.f);
        let path = self.dir.join(format!("{}.obj", frame.name()));
        self.surface
            .write_obj(&path, &on_frame)
            .map_err(|e| out_err("carried surface", &path, e))?;
        let mut stats = self.surface.stats(&on_frame, &state.x, self.spacing);
        // Measured against the target on the last frame (frame 1 is the source itself).
        let world_spacing = self.spacing * self.to_world.scale;
        stats.fidelity = self
            .references
            .as_deref()
            .filter(|_| frame.index + 1 == frame.count)
            .map(|(_, target)| {
                fidelity(
                    &on_frame.positions,
                    &self.surface.triangles,
                    target,
                    world_spacing,
                )
            });
        stats.seconds = clock.elapsed().as_secs_f64();
        record.carried = Some(stats);
        Ok(())
    }
}
