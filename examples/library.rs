//! Driving a morph through the library, as a farm script or a DCC plugin would: meshes made
//! in memory (no files), frames received in world units, and a cancel from the observer.
//!
//! `cargo run --release --example library`

use morph::geometry::{assets, prepare_mesh};
use morph::{Frame, Job, MeshSource, MorphError, MorphEvent, MorphSettings, Observer, Preset};
use std::path::Path;

/// Receives progress and frames; asks to stop after `budget` optimizer evaluations.
struct Watcher {
    evaluations: usize,
    budget: usize,
    frames: Vec<f64>,
}

impl Observer for Watcher {
    fn event(&mut self, event: &MorphEvent) {
        if let MorphEvent::Iteration { loss, .. } = event {
            self.evaluations += 1;
            println!("evaluation {:3}: loss {loss:.4e}", self.evaluations);
        }
    }

    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        // World units: the source mesh's own coordinates.
        let top = frame.world.x.iter().map(|p| p.y).fold(f64::MIN, f64::max);
        println!(
            "frame {} (t = {:.3} s): {} points, top at y = {top:.3}",
            frame.index,
            frame.time,
            frame.world.x.len()
        );
        self.frames.push(top);
        Ok(())
    }

    fn stop_requested(&self) -> usize {
        usize::from(self.evaluations >= self.budget)
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Two meshes built in memory, checked and repaired as a loaded file would be.
    let sphere = prepare_mesh(
        Path::new("<sphere>"),
        assets::uv_sphere(1.0, 16, 32, |_, _| 1.0),
        vec![],
    )?;
    let cube = prepare_mesh(Path::new("<cube>"), assets::cube(2.0, 4), vec![])?;
    let mut settings = MorphSettings::preset(Preset::Draft);
    settings.body.resolution = 16;
    settings.method.segments = 2;
    settings.method.optimizer.iterations = 3;
    let job = Job {
        source: MeshSource::Memory {
            name: "<sphere>".into(),
            mesh: sphere,
        },
        targets: vec![MeshSource::Memory {
            name: "<cube>".into(),
            mesh: cube,
        }],
        settings,
    };
    let mut watcher = Watcher {
        evaluations: 0,
        budget: 4,
        frames: Vec::new(),
    };
    match morph::run(&job, &mut watcher) {
        Err(MorphError::Interrupted { .. }) => println!(
            "cancelled by the observer after {} evaluations and {} frames",
            watcher.evaluations,
            watcher.frames.len()
        ),
        Ok((_, result)) => println!("finished: loss {:.4e}", result.final_loss),
        Err(e) => return Err(e.into()),
    }
    Ok(())
}
