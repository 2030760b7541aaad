//! `meshes/frame_NNNN.obj`: a closed surface rebuilt from the particles on every frame, by
//! `--rebuilt-method` (docs/geometry.md, "Surfaces out"), cleaned, put back to the body's
//! volume, written with vertex normals, and measured against the source on the first frame
//! and the target on the last.

use super::{FrameRecord, FrameSink, SinkFrame, out_err};
use crate::geometry::Similarity;
use crate::geometry::TriMesh;
use crate::geometry::cleanup::{CleanReport, SurfaceQuality, clean, keep_volume, quality};
use crate::geometry::features::{SourcePlanes, sharpen};
use crate::geometry::fidelity::{Fidelity, Reference, crease_share, mesh_fidelity};
use crate::geometry::likeness::{Likeness, likeness};
use crate::geometry::splashsurf::extract_splashsurf_surface;
use crate::geometry::surface::{FillField, SurfaceError, deformed_fill_field, fill_field};
use crate::morph::MorphError;
use crate::morph::settings::RebuiltMethod;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

/// A frame's rebuilt surface: its shape as marching tetrahedra made it, as written, and what
/// cleaning did.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RebuiltStats {
    pub before: SurfaceQuality,
    pub after: SurfaceQuality,
    pub cleanup: CleanReport,
    /// How true the written surface is to the reference of its frame: the source on the
    /// first frame, the target on the last ([`crate::geometry::fidelity`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<Fidelity>,
    /// Share of its faces that turn past [`crate::geometry::fidelity::CREASE_DEGREES`] from
    /// their neighbours: crack-like lines a render shows (every frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crease_share: Option<f64>,
    /// The last frame's silhouettes and tips against the target
    /// ([`crate::geometry::likeness`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub likeness: Option<Likeness>,
    /// Seconds spent making, cleaning, writing and measuring it (the frame writer's thread).
    #[serde(default)]
    pub seconds: f64,
}

/// The fill field the rebuilt surface of `method` is made from (simulation units). The
/// splashsurf pipeline makes its own field inside the library; the deformed kernels' field
/// stands in for it.
pub(super) fn fill_field_of(
    method: RebuiltMethod,
    frame: &SinkFrame,
    rest_volume: f64,
    edge_weights: &[f64],
    spacing: f64,
) -> Result<FillField, SurfaceError> {
    let state = frame.state;
    match method {
        RebuiltMethod::Lattice => {
            let volumes: Vec<f64> = frame
                .world
                .j
                .iter()
                .map(|j| rest_volume * j.max(0.0))
                .collect();
            fill_field(&state.x, &volumes, spacing)
        }
        RebuiltMethod::Sharp | RebuiltMethod::Deformed | RebuiltMethod::Splashsurf => {
            deformed_fill_field(&state.x, &state.f, rest_volume, Some(edge_weights), spacing)
        }
    }
}

pub struct RebuiltObj {
    /// The `meshes` folder.
    pub dir: PathBuf,
    pub method: RebuiltMethod,
    /// Particle spacing (simulation units) and rest volume.
    pub spacing: f64,
    pub rest_volume: f64,
    /// Each particle's weight in the deformed kernels' field (`MorphGeometry::source_edge_weights`).
    pub edge_weights: Arc<[f64]>,
    /// The source's tangent planes carried by the particles near its surface, for `sharp`
    /// ([`crate::geometry::features`]).
    pub planes: Option<Arc<SourcePlanes>>,
    /// The source mesh's volume, simulation units.
    pub body_volume: f64,
    pub to_world: Similarity,
    /// The source and the target surfaces (world units), which the first and the last
    /// frames' surfaces are measured against.
    pub references: Option<Arc<(Reference, Reference)>>,
    /// The target as the run placed it (world units), which the last frame is likened to.
    pub target: Arc<TriMesh>,
}

impl FrameSink for RebuiltObj {
    fn name(&self) -> &'static str {
        "rebuilt"
    }

    fn frame(&mut self, frame: &SinkFrame, record: &mut FrameRecord) -> Result<(), MorphError> {
        let clock = std::time::Instant::now();
        let raw = match self.method {
            RebuiltMethod::Splashsurf => extract_splashsurf_surface(&frame.state.x, self.spacing),
            method => Ok(frame
                .fill_field(method, self.rest_volume, &self.edge_weights, self.spacing)?
                .march()),
        }
        .map_err(|e| MorphError::Output(e.to_string()))?;
        let (mut surface, cleanup) = clean(&raw, self.spacing);
        if let Some(planes) = self.planes.as_deref() {
            sharpen(&mut surface, &frame.state.x, planes, self.spacing);
        }
        if self.method != RebuiltMethod::Lattice {
            // A wide kernel (and smoothing) rounds the body by a thin layer: put it back
            // evenly, to the body's volume times the particles' mean volume change.
            keep_volume(&mut surface, self.body_volume * frame.world.mean_j());
        }
        let path = self.dir.join(format!("{}.obj", frame.name()));
        let world = self.to_world.apply_mesh(&surface);
        world
            .write_obj_with_normals(&path)
            .map_err(|e| out_err("surface", &path, e))?;
        // The source on the first frame (the body at rest), the target on the last.
        let reference = match self.references.as_deref() {
            Some((source, _)) if frame.index == 0 => Some(source),
            Some((_, target)) if frame.index + 1 == frame.count => Some(target),
            _ => None,
        };
        let world_spacing = self.spacing * self.to_world.scale;
        let last = frame.index + 1 == frame.count;
        record.rebuilt = Some(RebuiltStats {
            before: quality(&raw),
            after: quality(&surface),
            cleanup,
            fidelity: reference.map(|r| mesh_fidelity(&world, r, world_spacing)),
            crease_share: Some(crease_share(&surface)),
            likeness: last.then(|| likeness(&world, &self.target)).flatten(),
            seconds: clock.elapsed().as_secs_f64(),
        });
        record.surface_volume = Some(world.signed_volume());
        Ok(())
    }
}
