//! Output formats as sinks the frame writer drives (see docs/architecture.md, "Recipes"):
//! each frame in order on the writer's thread, then `finish` once after the last, when every
//! frame is on disk. Per-frame formats write in `frame` (PLY points, carried and rebuilt OBJ
//! surfaces); whole-sequence formats (the USD file, the animated preview) write in `finish`
//! from the frames on disk, so a resumed run's sequence is whole though an earlier run wrote
//! its first frames. [`for_folder`] builds the list a morph's settings ask for.

mod carried;
mod gif;
mod points;
mod rebuilt;
mod target_carried;
mod usd;
mod volume;

pub use carried::{CarriedFit, CarriedObj};
pub use gif::PreviewGif;
pub use points::PointsPly;
pub use rebuilt::{RebuiltObj, RebuiltStats};
pub use target_carried::TargetCarriedObj;
pub use usd::UsdSequence;
pub use volume::VolumeVdb;

use crate::engine::mpm::State;
use crate::geometry::carried::{CarriedStats, CarriedSurface};
use crate::geometry::features::SourcePlanes;
use crate::geometry::fidelity::Reference;
use crate::geometry::surface::FillField;
use crate::morph::settings::RebuiltMethod;
use crate::morph::{Frame, MorphError, Prepared, WorldFrame};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One output format: told every frame in order, then that the sequence is complete.
pub trait FrameSink {
    /// A short name for reports (the manifest's timings).
    fn name(&self) -> &'static str {
        std::any::type_name::<Self>()
    }
    /// Writes frame `frame.index` of `frame.count`; what it measures goes into `record`.
    fn frame(&mut self, frame: &SinkFrame, record: &mut FrameRecord) -> Result<(), MorphError>;
    /// After the last frame, with every frame on disk.
    fn finish(&mut self) -> Result<(), MorphError> {
        Ok(())
    }
    /// What `finish` measured on each frame, one figure a frame (the manifest's frames take
    /// it under `name`).
    fn measured_in_finish(&self) -> Option<(&'static str, &[f64])> {
        None
    }
}

/// The source mesh's volume in simulation units, which the surfaces are put back to.
fn body_volume(prep: &Prepared) -> f64 {
    let scale = prep.geometry.placement.sim_to_world().scale;
    prep.geometry.source_solid.volume / scale.powi(3)
}

/// Whether the carried surface's triangles close a volume.
fn is_closed(surface: &CarriedSurface) -> bool {
    let mesh = crate::geometry::mesh::TriMesh::indexed(surface.rest().to_vec(), &surface.triangles);
    mesh.topology().is_closed()
}

/// What a sink sees of one frame.
pub struct SinkFrame<'a> {
    /// 0-based frame number, of `count`.
    pub index: usize,
    pub count: usize,
    /// The first frame's number in file names and time codes (`--start-frame`).
    pub start: usize,
    /// Simulated time (seconds).
    pub time: f64,
    /// Positions, velocities and volume ratios in the source mesh's units.
    pub world: &'a WorldFrame,
    /// The simulation state (simulation units).
    pub state: &'a State,
    /// The frame's fill field, made once for the sinks that need it (the rebuilt surface and
    /// the carried surface's fit): see [`SinkFrame::fill_field`].
    pub fill: std::cell::OnceCell<Result<FillField, String>>,
}

impl SinkFrame<'_> {
    /// The fill field the rebuilt surface of `method` is made from (simulation units), made
    /// on the first call of the frame. Every sink of a run asks with the run's settings.
    pub fn fill_field(
        &self,
        method: RebuiltMethod,
        rest_volume: f64,
        edge_weights: &[f64],
        spacing: f64,
    ) -> Result<&FillField, MorphError> {
        self.fill
            .get_or_init(|| {
                rebuilt::fill_field_of(method, self, rest_volume, edge_weights, spacing)
                    .map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|e| MorphError::Output(e.clone()))
    }
}

impl<'a> From<&'a Frame<'a>> for SinkFrame<'a> {
    fn from(frame: &'a Frame<'a>) -> SinkFrame<'a> {
        SinkFrame {
            index: frame.index,
            count: frame.prep.frame_count(),
            start: frame.prep.settings.shot.start_frame,
            time: frame.time,
            world: &frame.world,
            state: frame.state,
            fill: Default::default(),
        }
    }
}

/// What the sinks measured on one frame (the manifest's per-frame record takes it).
#[derive(Clone, Debug, Default)]
pub struct FrameRecord {
    /// The volume the rebuilt surface encloses (world units).
    pub surface_volume: Option<f64>,
    pub carried: Option<CarriedStats>,
    pub rebuilt: Option<RebuiltStats>,
}

/// The name of frame number `number` in a sequence whose last frame is number `last`:
/// zero-padded to the width the last needs (at least 4), so names sort in frame order.
pub fn frame_name(number: usize, last: usize) -> String {
    let width = last.to_string().len().max(4);
    format!("frame_{number:0width$}")
}

impl SinkFrame<'_> {
    /// This frame's file name, without extension (`frame_0001`, or `frame_1001` from 1001).
    pub fn name(&self) -> String {
        frame_name(self.start + self.index, self.start + self.count - 1)
    }
}

/// The folder-relative paths of the files in `folder` of `count` frames numbered from
/// `start`, in frame order.
fn frame_files(folder: &str, ext: &str, start: usize, count: usize) -> Vec<PathBuf> {
    let last = start + count - 1;
    (start..=last)
        .map(|n| Path::new(folder).join(format!("{}.{ext}", frame_name(n, last))))
        .collect()
}

/// The folder `name` in the output folder `dir`, made now: a per-frame sink owns its folder.
fn folder(dir: &Path, name: &str) -> Result<PathBuf, MorphError> {
    let d = dir.join(name);
    std::fs::create_dir_all(&d).map_err(|e| out_err("folder", &d, e))?;
    Ok(d)
}

pub(crate) fn out_err(what: &str, path: &Path, e: impl std::fmt::Display) -> MorphError {
    MorphError::Output(format!("cannot write {what} '{}': {e}", path.display()))
}

/// The sinks a morph's folder gets from its settings, in the order they run: the PLY points,
/// the carried surface, the rebuilt surface, the volume, the target's carried surface, the
/// USD file and the animated preview. `source` is the source mesh's file (the carried surface
/// is bound to it), `target` the last target's (the target's carried surface is).
pub fn for_folder(
    prep: &Prepared,
    dir: &Path,
    (source, target_file): (&Path, &Path),
) -> Result<Vec<Box<dyn FrameSink + Send>>, MorphError> {
    let settings = &prep.settings;
    let to_world = prep.geometry.placement.sim_to_world();
    let spacing = prep.model().grid.dx / settings.body.particles_per_cell as f64;
    let count = prep.frame_count();
    let edge_weights: Arc<[f64]> = prep.geometry.source_edge_weights.as_slice().into();
    let fps = 1.0 / (prep.sim_frame_every() as f64 * prep.model().dt);
    // The source as read, for the carried surface and as the first frame's reference.
    let loaded = match settings.outputs.surfaces {
        crate::morph::settings::Surfaces::None => None,
        _ => Some(crate::geometry::load_mesh(source)?),
    };
    let target = Arc::new(to_world.apply_mesh(&prep.geometry.target_sim));
    let references = loaded.as_ref().and_then(|l| {
        Some(Arc::new((
            Reference::new(&l.mesh)?,
            Reference::new(&target)?,
        )))
    });
    let mut sinks: Vec<Box<dyn FrameSink + Send>> = vec![Box::new(PointsPly {
        dir: folder(dir, "frames")?,
    })];
    if let Some(loaded) = loaded
        .as_ref()
        .filter(|_| settings.outputs.surfaces.carried())
    {
        sinks.push(carried_sink(
            prep,
            dir,
            (source, &loaded.mesh),
            references.clone(),
            target.clone(),
        )?);
    }
    if settings.outputs.surfaces.rebuilt() {
        sinks.push(Box::new(RebuiltObj {
            dir: folder(dir, "meshes")?,
            method: settings.outputs.rebuilt_method,
            spacing,
            rest_volume: prep.geometry.source.volume,
            edge_weights: edge_weights.clone(),
            planes: loaded
                .as_ref()
                .filter(|_| settings.outputs.rebuilt_method == RebuiltMethod::Sharp)
                .map(|l| {
                    let source = prep.geometry.placement.world_to_sim.apply_mesh(&l.mesh);
                    Arc::new(SourcePlanes::new(&source, &prep.initial.x, spacing))
                }),
            body_volume: body_volume(prep),
            to_world,
            references,
            target,
        }));
    }
    if settings.outputs.volume {
        sinks.push(Box::new(VolumeVdb {
            dir: folder(dir, "volumes")?,
            method: settings.outputs.rebuilt_method,
            spacing,
            rest_volume: prep.geometry.source.volume,
            edge_weights: edge_weights.clone(),
            to_world,
        }));
    }
    let start = settings.shot.start_frame;
    if settings.outputs.surfaces.target_carried() {
        sinks.push(target_carried_sink(prep, dir, target_file)?);
    }
    if settings.outputs.usd != crate::io::usd::UsdFormat::None {
        sinks.push(Box::new(UsdSequence {
            dir: dir.to_path_buf(),
            format: settings.outputs.usd,
            start,
            count,
            fps,
            carried: settings.outputs.surfaces.carried(),
            target_weights: settings.outputs.surfaces.target_carried().then(|| {
                (1..=count)
                    .map(|f| crate::morph::output::target_weight(prep, f))
                    .collect()
            }),
            rebuilt: settings.outputs.surfaces.rebuilt(),
            volume: settings.outputs.volume,
            width: spacing * to_world.scale,
        }));
    }
    sinks.push(Box::new(PreviewGif {
        dir: dir.to_path_buf(),
        start,
        count,
        fps,
        radius: 0.5 * spacing * to_world.scale,
    }));
    Ok(sinks)
}

/// The target's carried surface's sink (`target` the last target's file).
fn target_carried_sink(
    prep: &Prepared,
    dir: &Path,
    target: &Path,
) -> Result<Box<dyn FrameSink + Send>, MorphError> {
    let placement = &prep.geometry.placement;
    Ok(Box::new(TargetCarriedObj {
        dir: dir.to_path_buf(),
        target: (
            target.to_path_buf(),
            crate::geometry::load_mesh(target)?.mesh,
        ),
        place: placement.target_to_world,
        to_sim: placement.world_to_sim,
        spacing: prep.model().grid.dx / prep.settings.body.particles_per_cell as f64,
        start: prep.settings.shot.start_frame,
        count: prep.frame_count(),
        fold_shares: Vec::new(),
    }))
}

/// The carried surface's sink: the source mesh (`source` its file) bound to the particles.
fn carried_sink(
    prep: &Prepared,
    dir: &Path,
    (source, mesh): (&Path, &crate::geometry::TriMesh),
    references: Option<Arc<(Reference, Reference)>>,
    target: Arc<crate::geometry::TriMesh>,
) -> Result<Box<dyn FrameSink + Send>, MorphError> {
    let spacing = prep.model().grid.dx / prep.settings.body.particles_per_cell as f64;
    let surface = CarriedSurface::bind(
        source,
        mesh,
        prep.geometry.placement.world_to_sim,
        &prep.initial.x,
        spacing,
    )
    .map_err(|e| {
        MorphError::Mesh(crate::geometry::MeshError::Unreadable {
            path: source.into(),
            reason: e.to_string(),
        })
    })?;
    let count = prep.frame_count();
    let fit = Some(CarriedFit {
        method: prep.settings.outputs.rebuilt_method,
        rest_volume: prep.geometry.source.volume,
        edge_weights: prep.geometry.source_edge_weights.as_slice().into(),
        strength: (1..=count)
            .map(|f| crate::morph::output::target_weight(prep, f))
            .collect(),
        rings: crate::geometry::fit::vertex_neighbours(surface.vertex_count(), &surface.triangles),
        body_volume: body_volume(prep),
        closed: is_closed(&surface),
    });
    Ok(Box::new(CarriedObj {
        dir: folder(dir, "carried")?,
        surface,
        rest: prep.initial.x.clone(),
        spacing,
        to_world: prep.geometry.placement.sim_to_world(),
        references,
        target,
        fit,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_named_by_their_number_and_sort_in_order() {
        assert_eq!(frame_name(1, 73), "frame_0001");
        assert_eq!(frame_name(1001, 1072), "frame_1001");
        // Past 9999 the width grows for every name, so they still sort as text.
        let files = frame_files("frames", "ply", 9998, 5);
        let names: Vec<String> = files.iter().map(|p| p.display().to_string()).collect();
        assert_eq!(names[0], "frames/frame_09998.ply");
        assert_eq!(names[4], "frames/frame_10002.ply");
        let mut sorted = names.clone();
        sorted.sort();
        assert_eq!(sorted, names);
    }
}
