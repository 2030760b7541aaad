//! The library entry point ([`morph::run`] with a [`morph::Job`]): in-memory meshes, frames
//! in world units, cancel from the observer, and a frame sink of a program's own.

use morph::geometry::{assets, prepare_mesh};
use morph::{
    Frame, FrameRecord, FrameSink, Job, MeshSource, MorphError, MorphEvent, MorphSettings,
    Observer, Preset, SinkFrame,
};
use std::path::Path;

use crate::common;

/// A program's own output format: records each frame's time and its highest point.
#[derive(Default)]
struct TopSink {
    tops: Vec<(f64, f64)>,
}

impl FrameSink for TopSink {
    fn frame(&mut self, frame: &SinkFrame, _: &mut FrameRecord) -> Result<(), MorphError> {
        let top = frame.world.x.iter().map(|p| p.y).fold(f64::MIN, f64::max);
        self.tops.push((frame.time, top));
        Ok(())
    }
}

#[derive(Default)]
struct Watch {
    evaluations: usize,
    stop_after: Option<usize>,
    first_frame: Option<Vec<nalgebra::Vector3<f64>>>,
    frames: usize,
    sink: TopSink,
}

impl Observer for Watch {
    fn event(&mut self, e: &MorphEvent) {
        if matches!(e, MorphEvent::Iteration { .. }) {
            self.evaluations += 1;
        }
    }
    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        self.first_frame.get_or_insert(frame.world.x.clone());
        self.frames += 1;
        self.sink.frame(&frame.into(), &mut FrameRecord::default())
    }
    fn stop_requested(&self) -> usize {
        self.stop_after
            .map_or(0, |n| usize::from(self.evaluations >= n))
    }
}

fn job() -> Job {
    // A sphere of radius 3 centred at (10, 0, 0), in its own units: the world frame.
    let mut sphere = assets::uv_sphere(3.0, 12, 24, |_, _| 1.0);
    for v in &mut sphere.vertices {
        v.x += 10.0;
    }
    let sphere = prepare_mesh(Path::new("<sphere>"), sphere, vec![]).unwrap();
    let cube = prepare_mesh(Path::new("<cube>"), assets::cube(2.0, 2), vec![]).unwrap();
    let mut s = MorphSettings::preset(Preset::Draft);
    s.body.resolution = 12;
    s.method.segments = 2;
    s.method.optimizer.iterations = 2;
    Job {
        source: MeshSource::Memory {
            name: "<sphere>".into(),
            mesh: sphere,
        },
        targets: vec![MeshSource::Memory {
            name: "<cube>".into(),
            mesh: cube,
        }],
        settings: s,
    }
}

#[test]
fn in_memory_meshes_world_frames_and_cancel() {
    let job = job();
    let mut w = Watch::default();
    let (prep, result) = morph::run(&job, &mut w).unwrap();
    assert_eq!(w.frames, prep.frame_count());
    assert!(result.final_loss < result.initial_loss);
    // Frame 1 is the source in its own units: inside the sphere of radius 3 about (10, 0, 0).
    let first = w.first_frame.unwrap();
    assert!(
        first
            .iter()
            .all(|p| (p - nalgebra::Vector3::new(10.0, 0.0, 0.0)).norm() < 3.0)
    );
    // The sink saw every frame, at times step * dt that increase.
    assert_eq!(w.sink.tops.len(), w.frames);
    assert!(w.sink.tops.windows(2).all(|p| p[1].0 > p[0].0));
    assert_eq!(w.sink.tops[0].0, 0.0);

    let mut w = Watch {
        stop_after: Some(2),
        ..Watch::default()
    };
    match morph::run(&job, &mut w) {
        Err(MorphError::Interrupted { signal, .. }) => assert_eq!(signal, 1),
        other => panic!("expected a cancel, got {:?}", other.map(|r| r.1.final_loss)),
    }
    assert_eq!(w.evaluations, 2, "stopped at the evaluation it asked");
}

/// A memory budget changes memory and time, never results: the smallest tape budget (every
/// segment recorded in chunks and recomputed in reverse) gives bitwise the morph of the whole
/// tape, frames included, with both optimizers.
#[test]
fn a_memory_budget_never_changes_the_morph() {
    use morph::segment::Optimizer;
    let mesh = |name: &str, m| prepare_mesh(Path::new(name), m, Vec::new()).unwrap();
    let src = mesh("sphere", assets::uv_sphere(1.0, 16, 32, |_, _| 1.0));
    let tgt = mesh("lobes", assets::two_lobes(24, 32));
    for kind in Optimizer::ALL {
        let mut s = MorphSettings::preset(Preset::Draft);
        s.body.resolution = 16;
        s.method.segments = 2;
        s.method.optimizer.kind = kind;
        s.method.optimizer.iterations = 3;
        s.method.optimizer.learning_rate = kind.default_learning_rate();
        let run = |budget: usize| {
            let mut prep = morph::Prepared::from_meshes(
                &s.clone().checked().unwrap(),
                (&src, Path::new("sphere")),
                &[(&tgt, Path::new("lobes"))],
            )
            .unwrap();
            prep.tape_budget = budget;
            let mut frames = FrameStates::default();
            let result = morph::run_prepared(&prep, None, &mut frames).unwrap();
            let chunked =
                prep.segment_chunk_plan() != morph::engine::integrator::recompute::ChunkPlan::WHOLE;
            (result.final_state, frames.0, chunked)
        };
        let (whole, whole_frames, chunked) = run(usize::MAX);
        assert!(!chunked);
        let (small, small_frames, chunked) = run(0);
        assert!(chunked, "{kind:?}: the smallest budget records chunks");
        assert!(whole == small, "{kind:?}: final states differ");
        assert!(whole_frames == small_frames, "{kind:?}: frames differ");
    }
}

/// Every frame's simulation state.
#[derive(Default)]
struct FrameStates(Vec<morph::engine::mpm::State>);

impl Observer for FrameStates {
    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        self.0.push(frame.state.clone());
        Ok(())
    }
}

/// The library does the keyframes the command line does: a `Job` through two targets, each
/// at its frame, ends on bitwise the nodal masses the CLI writes for the same morph.
#[test]
fn a_keyframed_job_matches_the_command_line_bitwise() {
    use common::cli::{ok, root, scratch_in};
    use morph::io::massgrid::MassGrid;
    let asset = |n: &str| root().join("assets").join(n);
    let out = scratch_in("library", "keyframes");
    let r = common::cli::morph(&[
        asset("sphere.obj").to_str().unwrap(),
        asset("cube.obj").to_str().unwrap(),
        asset("two-lobes.obj").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--preset",
        "draft",
        "--resolution",
        "12",
        "--frames",
        "25",
        "--at",
        "10,19",
        "--surface",
        "none",
        "--quiet",
    ]);
    ok(&r);
    let cli = MassGrid::read(&out.join("final_mass.mgrid")).unwrap();

    let mut settings = MorphSettings::preset(Preset::Draft);
    settings.body.resolution = 12;
    settings.shot.frames = Some(25);
    settings.shot.at = vec![10, 19];
    let job = Job {
        source: MeshSource::File(asset("sphere.obj")),
        targets: vec![
            MeshSource::File(asset("cube.obj")),
            MeshSource::File(asset("two-lobes.obj")),
        ],
        settings,
    };
    let (prep, result) = morph::run(&job, &mut Watch::default()).unwrap();
    assert_eq!(prep.schedule.steps.len(), 2, "two keyframes");
    let mass = prep.model().mass_grid(&result.final_state.x).unwrap();
    assert!(
        mass == cli.values,
        "the library's final masses differ from the CLI's"
    );
}

/// The controls' continuity weighs a jump of plastic flow by the elastic energy it stores:
/// ten times the shear modulus, ten times the weight (the presets' material: the setting's
/// own weight, to the bit), and none on the held segments at any stiffness.
#[test]
fn the_continuity_weight_follows_the_stiffness() {
    let mut job = job();
    job.settings.method.control_smoothing = 3.0e4;
    job.settings.method.segments = 10;
    let soft = job.prepare().unwrap();
    assert_eq!(
        job.settings.body.material.mu,
        morph::settings::TUNED_SHEAR_MODULUS
    );
    assert_eq!(soft.segment_smoothing(0), 3.0e4);
    job.settings.body.material.mu *= 10.0;
    let stiff = job.prepare().unwrap();
    assert!((stiff.segment_smoothing(0) / soft.segment_smoothing(0) - 10.0).abs() < 1e-12);
    let last = job.settings.method.segments - 1;
    assert_eq!(stiff.segment_smoothing(last), 0.0);
}
