//! Scratch: optimizer tuning on one segment chain (not part of the product).
use morph::morph::{MorphSettings, Prepared, Preset, run, segment::Optimizer};
use std::path::Path;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let tgt = args
        .get(1)
        .cloned()
        .unwrap_or("assets/two-lobes.obj".into());
    let kind = if args.get(2).map(|s| s.as_str()) == Some("ls") {
        Optimizer::LineSearch
    } else {
        Optimizer::Adam
    };
    let lr: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0.02);
    let segs: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(2);
    let iters: usize = args.get(5).and_then(|s| s.parse().ok()).unwrap_or(10);
    let aw: f64 = args.get(6).and_then(|s| s.parse().ok()).unwrap_or(0.01);
    let mut s = MorphSettings::preset(Preset::Draft);
    s.segments = segs;
    s.passes = 1;
    s.optimizer.kind = kind;
    s.optimizer.learning_rate = lr;
    s.optimizer.iterations = iters;
    s.arrival_weight = aw;
    let prep = Prepared::new(&s, Path::new("assets/sphere.obj"), Path::new(&tgt)).unwrap();
    eprintln!("particles {} dt {}", prep.initial.len(), prep.sim.dt);
    let r = run(
        &prep,
        |e| {
            if let morph::morph::MorphEvent::Segment { .. } = e {
                eprintln!("{}", serde_json::to_string(e).unwrap());
            }
        },
        |_, _, _| Ok(()),
    )
    .unwrap();
    let m = morph::morph::metrics::fill_metrics(
        &prep.sim.grid,
        prep.geometry.source.volume.cbrt(),
        &prep.geometry.target.positions,
        &r.final_state.x,
    );
    eprintln!(
        "initial {:.4} final {:.4} ({:.1}%) in {:.1}s; fill {:?}",
        r.initial_loss,
        r.final_loss,
        100.0 * r.final_loss / r.initial_loss,
        r.seconds,
        m
    );
}
