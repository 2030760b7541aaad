//! `preview.gif`: at most [`GIF_FRAMES`] frames evenly through the sequence, read back from
//! the frames on disk, each shown for as long as the frames it stands for.

use super::{FrameRecord, FrameSink, SinkFrame, frame_files, out_err};
use crate::io::images;
use crate::morph::MorphError;
use std::path::PathBuf;

/// Frames at most in `preview.gif`.
pub const GIF_FRAMES: usize = 48;

pub struct PreviewGif {
    /// The output folder.
    pub dir: PathBuf,
    /// The first frame's number, and how many there are.
    pub start: usize,
    pub count: usize,
    pub fps: f64,
    /// A particle's drawn radius (world units).
    pub radius: f64,
}

impl FrameSink for PreviewGif {
    fn name(&self) -> &'static str {
        "gif"
    }

    fn frame(&mut self, _: &SinkFrame, _: &mut FrameRecord) -> Result<(), MorphError> {
        Ok(())
    }

    fn finish(&mut self) -> Result<(), MorphError> {
        let every = self.count.div_ceil(GIF_FRAMES).max(1);
        let files = frame_files("frames", "ply", self.start, self.count);
        let frames = (0..self.count)
            .step_by(every)
            .map(|i| {
                let path = self.dir.join(&files[i]);
                crate::io::usd::read_points_ply(&path)
                    .map(|p| (i + 1, p.x))
                    .map_err(|e| out_err("preview", &path, e))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let path = self.dir.join("preview.gif");
        images::write_preview_gif(&path, &frames, self.radius, self.fps / every as f64)
            .map_err(|e| out_err("preview", &path, e))
    }
}
