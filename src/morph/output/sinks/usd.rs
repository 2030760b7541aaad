//! `morph.usdc` (or `.usda`): the whole sequence as one USD stage (points, and the surfaces
//! the run wrote), from the frames on disk once they are all there (`io/usd.rs`).

use super::{FrameRecord, FrameSink, SinkFrame, frame_files, out_err};
use crate::io::usd::UsdFormat;
use crate::morph::MorphError;
use std::path::PathBuf;

pub struct UsdSequence {
    /// The output folder.
    pub dir: PathBuf,
    /// Binary or text (never `None`: then there is no sink).
    pub format: UsdFormat,
    /// The first frame's number (its time code), and how many there are.
    pub start: usize,
    pub count: usize,
    pub fps: f64,
    /// Which surfaces the run writes (the target's carried one with its weight per frame).
    pub carried: bool,
    pub target_weights: Option<Vec<f64>>,
    pub rebuilt: bool,
    /// Whether the run writes a volume per frame (`--volume`).
    pub volume: bool,
    /// The points' width (world units).
    pub width: f64,
}

impl FrameSink for UsdSequence {
    fn name(&self) -> &'static str {
        "usd"
    }

    fn frame(&mut self, _: &SinkFrame, _: &mut FrameRecord) -> Result<(), MorphError> {
        Ok(())
    }

    fn finish(&mut self) -> Result<(), MorphError> {
        let Some(name) = self.format.file_name() else {
            return Ok(());
        };
        let path = self.dir.join(name);
        let files = |folder: &str, ext: &str| frame_files(folder, ext, self.start, self.count);
        crate::io::usd::write(
            &path,
            &crate::io::usd::UsdSequence {
                dir: &self.dir,
                start: self.start,
                fps: self.fps,
                points: files("frames", "ply"),
                carried: self.carried.then(|| files("carried", "obj")),
                target_carried: self
                    .target_weights
                    .clone()
                    .map(|w| (files("target_carried", "obj"), w)),
                rebuilt: self.rebuilt.then(|| files("meshes", "obj")),
                volumes: self.volume.then(|| files("volumes", "vdb")),
                width: self.width,
            },
            self.format,
        )
        .map_err(|e| out_err("USD file", &path, e))
    }
}
