//! The library entry point: in-memory meshes, frames in world units, cancel from the observer.

use morph::geometry::{assets, prepare_mesh};
use morph::morph::{MorphError, MorphEvent, MorphSettings, Observer, Prepared, Preset};
use morph::mpm::State;
use std::path::Path;

struct Watch<'a> {
    prep: &'a Prepared,
    evaluations: usize,
    stop_after: Option<usize>,
    first_frame: Option<Vec<nalgebra::Vector3<f64>>>,
    frames: usize,
}

impl Observer for Watch<'_> {
    fn event(&mut self, e: &MorphEvent) {
        if matches!(e, MorphEvent::Iteration { .. }) {
            self.evaluations += 1;
        }
    }
    fn frame(&mut self, _i: usize, _step: usize, state: &State) -> Result<(), MorphError> {
        let f = self.prep.world_frame(state);
        self.first_frame.get_or_insert(f.x);
        self.frames += 1;
        Ok(())
    }
    fn stop_requested(&self) -> usize {
        self.stop_after
            .map_or(0, |n| usize::from(self.evaluations >= n))
    }
}

fn prepared() -> Prepared {
    // A sphere of radius 3 centred at (10, 0, 0), in its own units: the world frame.
    let mut sphere = assets::uv_sphere(3.0, 12, 24, |_, _| 1.0);
    for v in &mut sphere.vertices {
        v.x += 10.0;
    }
    let sphere = prepare_mesh(Path::new("<sphere>"), sphere, vec![]).unwrap();
    let cube = prepare_mesh(Path::new("<cube>"), assets::cube(2.0, 2), vec![]).unwrap();
    let mut s = MorphSettings::preset(Preset::Draft);
    s.resolution = 12;
    s.segments = 2;
    s.optimizer.iterations = 2;
    Prepared::from_meshes(
        &s,
        (&sphere, Path::new("<sphere>")),
        (&cube, Path::new("<cube>")),
    )
    .unwrap()
}

#[test]
fn in_memory_meshes_world_frames_and_cancel() {
    let prep = prepared();
    let mut w = Watch {
        prep: &prep,
        evaluations: 0,
        stop_after: None,
        first_frame: None,
        frames: 0,
    };
    let result = morph::morph::run(&prep, None, &mut w).unwrap();
    assert_eq!(w.frames, prep.frame_count());
    assert!(result.final_loss < result.initial_loss);
    // Frame 1 is the source in its own units: inside the sphere of radius 3 about (10, 0, 0).
    let first = w.first_frame.unwrap();
    assert!(
        first
            .iter()
            .all(|p| (p - nalgebra::Vector3::new(10.0, 0.0, 0.0)).norm() < 3.0)
    );

    let mut w = Watch {
        prep: &prep,
        evaluations: 0,
        stop_after: Some(2),
        first_frame: None,
        frames: 0,
    };
    match morph::morph::run(&prep, None, &mut w) {
        Err(MorphError::Interrupted { signal, .. }) => assert_eq!(signal, 1),
        other => panic!("expected a cancel, got {:?}", other.map(|r| r.final_loss)),
    }
    assert_eq!(w.evaluations, 2, "stopped at the evaluation it asked");
}
