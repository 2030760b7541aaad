use morph::control::compare::RopeSettings;
use morph::control::mppi::mppi_control;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mut s = RopeSettings::default();
    s.mppi.samples = a[1].parse().unwrap();
    s.mppi.horizon_steps = a[2].parse().unwrap();
    s.mppi.lambda = a[3].parse().unwrap();
    s.mppi.noise = a[4].parse().unwrap();
    s.mppi.replan_steps = a[5].parse().unwrap();
    if std::env::var("SEG").is_ok() {
        s.rope.actuation = morph::control::rope::Actuation::Segments;
    }
    let rope = s.rope.build().unwrap();
    let r = mppi_control(&rope.system, &rope.initial, &s.mppi, s.rope.steps, |_| {}).unwrap();
    let e: Vec<f64> = r.committed.iter().map(|c| c.energy).collect();
    let n = e.len();
    let tail: f64 = e[3 * n / 4..].iter().sum::<f64>() / (n / 4) as f64;
    let t_low = e.iter().rposition(|&x| x > 0.01165).map_or(0, |i| i + 1) as f64 * 0.002;
    println!(
        "K {} H {} lam {} noise {} R {}: last {:.3e} tail {:.3e} cost {:.4e} t_low {:.3} compute {:.2}",
        a[1],
        a[2],
        a[3],
        a[4],
        a[5],
        e[n - 1],
        tail,
        0.002 * e.iter().sum::<f64>(),
        t_low,
        r.compute_s
    );
}
