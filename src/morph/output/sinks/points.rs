//! `frames/frame_NNNN.ply`: every frame's particles (binary PLY: x y z vx vy vz J id, world
//! units).

use super::{FrameRecord, FrameSink, SinkFrame, out_err};
use crate::io::frames::write_points_ply;
use crate::morph::MorphError;
use std::path::PathBuf;

pub struct PointsPly {
    /// The `frames` folder.
    pub dir: PathBuf,
}

impl FrameSink for PointsPly {
    fn name(&self) -> &'static str {
        "points"
    }

    fn frame(&mut self, frame: &SinkFrame, _: &mut FrameRecord) -> Result<(), MorphError> {
        let path = self.dir.join(format!("{}.ply", frame.name()));
        let w = frame.world;
        write_points_ply(&path, &w.x, &w.v, &w.j).map_err(|e| out_err("frame", &path, e))
    }
}
