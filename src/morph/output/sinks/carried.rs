//! `carried/frame_NNNN.obj`: the source's own mesh (topology, UVs, groups) carried by the
//! particles it was bound to at rest (`geometry/carried.rs`), with its fold share on every
//! frame and its fidelity to the target on the last.

use super::{FrameRecord, FrameSink, SinkFrame, out_err};
use crate::geometry::Similarity;
use crate::geometry::carried::CarriedSurface;
use crate::geometry::fidelity::{Reference, fidelity};
use crate::geometry::likeness::likeness;
use crate::geometry::mesh::TriMesh;
use crate::morph::MorphError;
use nalgebra::Vector3;
use std::path::PathBuf;
use std::sync::Arc;

/// What fits the carried surface to the body's boundary on each frame: the fill field the
/// rebuilt surface is made from, and the share of the way to it each frame goes.
pub struct CarriedFit {
    pub method: crate::morph::settings::RebuiltMethod,
    pub rest_volume: f64,
    pub edge_weights: Arc<[f64]>,
    /// Per frame, from 0 (frame 1: the source itself) to 1.
    pub strength: Vec<f64>,
    /// Each carried vertex's neighbours (`geometry::fit::vertex_neighbours`), found once.
    pub rings: Vec<Vec<usize>>,
    /// The source mesh's volume (simulation units), which a closed surface's fit is brought
    /// back to as the rebuilt surface is (the fill field's level lies a thin layer inside).
    pub body_volume: f64,
    /// Whether the source mesh is closed (an open one has no volume to keep).
    pub closed: bool,
}

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
    /// The target as the run placed it (world units), which the last frame is likened to.
    pub target: Arc<TriMesh>,
    /// The fit to the body's boundary (none: the binding's motion alone).
    pub fit: Option<CarriedFit>,
}

impl FrameSink for CarriedObj {
    fn name(&self) -> &'static str {
        "carried"
    }

    fn frame(&mut self, frame: &SinkFrame, record: &mut FrameRecord) -> Result<(), MorphError> {
        let clock = std::time::Instant::now();
        let state = frame.state;
        let mut on_frame = self.surface.carry(&self.rest, &state.x, &state.f);
        if let Some(fit) = &self.fit {
            self.fit_frame(fit, frame, &mut on_frame)?;
        }
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
        if frame.index + 1 == frame.count {
            let world = TriMesh::indexed(on_frame.positions.clone(), &self.surface.triangles);
            stats.likeness = likeness(&world, &self.target);
        }
        stats.seconds = clock.elapsed().as_secs_f64();
        record.carried = Some(stats);
        Ok(())
    }
}

impl CarriedObj {
    /// Moves the frame's carried vertices toward the body's boundary (the fill field's level
    /// set, as the rebuilt surface is), by the frame's strength, and turns its normals.
    fn fit_frame(
        &self,
        fit: &CarriedFit,
        frame: &SinkFrame,
        on_frame: &mut crate::geometry::carried::CarriedFrame,
    ) -> Result<(), MorphError> {
        let strength = fit.strength.get(frame.index).copied().unwrap_or(1.0);
        if strength <= 0.0 {
            return Ok(());
        }
        let field =
            frame.fill_field(fit.method, fit.rest_volume, &fit.edge_weights, self.spacing)?;
        let to_sim = self.to_world.inverse();
        let mut sim: Vec<Vector3<f64>> =
            on_frame.positions.iter().map(|v| to_sim.apply(v)).collect();
        let reach = crate::geometry::fit::REACH_SPACINGS * self.spacing;
        let mesh = crate::geometry::fit::FitMesh {
            triangles: &self.surface.triangles,
            faces: self.surface.face_neighbours(),
            rings: &fit.rings,
        };
        let volume = fit.closed.then_some(fit.body_volume * frame.world.mean_j());
        crate::geometry::fit::fit_to_field(&mut sim, &mesh, field, reach, strength, volume);
        on_frame.positions = sim.iter().map(|v| self.to_world.apply(v)).collect();
        if !on_frame.normals.is_empty() {
            on_frame.normals = crate::geometry::mesh::area_weighted_normals(
                &on_frame.positions,
                self.surface.triangles.iter().copied(),
            );
        }
        Ok(())
    }
}
