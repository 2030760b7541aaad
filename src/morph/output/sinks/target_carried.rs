//! `target_carried/frame_NNNN.obj` (`--surface all`): the last target's own mesh (its
//! topology, UVs and groups), placed as the run placed it, bound to the particles on the last
//! frame and carried with them back to frame 1, so that a shot can end on the target asset
//! itself: its last frame is the placed target. Written in `finish`, from the frames on disk
//! (the binding needs the last one), with each frame's fold share.

use super::{FrameRecord, FrameSink, SinkFrame, frame_name, out_err};
use crate::geometry::carried::CarriedSurface;
use crate::geometry::{Similarity, TriMesh};
use crate::morph::MorphError;
use nalgebra::{Matrix3, Vector3};
use std::path::PathBuf;

pub struct TargetCarriedObj {
    /// The output folder (its `frames/` are read, `target_carried/` written).
    pub dir: PathBuf,
    /// The last target's file and the mesh as loaded.
    pub target: (PathBuf, TriMesh),
    /// Target file coordinates -> world, world -> sim.
    pub place: Similarity,
    pub to_sim: Similarity,
    /// Particle spacing, simulation units.
    pub spacing: f64,
    pub start: usize,
    pub count: usize,
    /// Each frame's fold share, filled by `finish`.
    pub fold_shares: Vec<f64>,
}

impl TargetCarriedObj {
    /// Frame `k`'s particle positions in simulation units, from its PLY.
    fn positions(&self, k: usize) -> Result<Vec<Vector3<f64>>, MorphError> {
        let last = self.start + self.count - 1;
        let name = frame_name(self.start + k, last);
        let path = self.dir.join("frames").join(format!("{name}.ply"));
        let frame = crate::io::usd::read_points_ply(&path)
            .map_err(|e| MorphError::Output(format!("cannot read '{}': {e}", path.display())))?;
        Ok(frame.x.iter().map(|x| self.to_sim.apply(x)).collect())
    }
}

impl FrameSink for TargetCarriedObj {
    fn name(&self) -> &'static str {
        "target_carried"
    }

    fn frame(&mut self, _: &SinkFrame, _: &mut FrameRecord) -> Result<(), MorphError> {
        Ok(())
    }

    fn measured_in_finish(&self) -> Option<(&'static str, &[f64])> {
        Some(("target_carried_fold_share", &self.fold_shares))
    }

    fn finish(&mut self) -> Result<(), MorphError> {
        let out = super::folder(&self.dir, "target_carried")?;
        let last = self.positions(self.count - 1)?;
        let (file, mesh) = &self.target;
        let surface =
            CarriedSurface::bind_placed(file, mesh, self.place, self.to_sim, &last, self.spacing)
                .map_err(|e| {
                MorphError::Mesh(crate::geometry::MeshError::Unreadable {
                    path: file.clone(),
                    reason: e.to_string(),
                })
            })?;
        // The frames hold no F: where a particle's neighbourhood does not fit, its vertices
        // follow the particles' motion alone.
        let still = vec![Matrix3::identity(); last.len()];
        self.fold_shares.clear();
        for k in 0..self.count {
            let x = self.positions(k)?;
            let on_frame = surface.carry(&last, &x, &still);
            let name = frame_name(self.start + k, self.start + self.count - 1);
            let path = out.join(format!("{name}.obj"));
            surface
                .write_obj(&path, &on_frame)
                .map_err(|e| out_err("target's carried surface", &path, e))?;
            let stats = surface.stats(&on_frame, &x, self.spacing);
            self.fold_shares.push(stats.fold_share);
        }
        Ok(())
    }
}
