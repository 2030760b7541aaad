use morph::control::rope::RopeConfig;
use morph::ode::Rk4Tape;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[1].parse().unwrap();
    let lr: f64 = args[2].parse().unwrap();
    let iters: usize = args[3].parse().unwrap();
    let rope = RopeConfig::default().build().unwrap();
    let sys = &rope.system;
    let mut params = sys.controls.zero_params();
    let bound = sys.controls.effects[0].bound;
    let (mut m1, mut m2) = (params.clone(), params.clone());
    for it in 0..iters {
        let mut s = rope.initial.clone();
        let mut tape = Rk4Tape::default();
        let e = sys
            .run(&mut s, &params, 0, n, Some(&mut tape), |_, _| {})
            .unwrap();
        let cost: f64 = sys.dt * e.iter().sum::<f64>();
        let g = sys.kinetic_cost_gradient(&tape, &params, &s, sys.dt, None);
        let gn: f64 = g.params[0]
            .iter()
            .map(|v| v.norm_squared())
            .sum::<f64>()
            .sqrt();
        println!(
            "it {it} cost {cost:.6e} |g| {gn:.3e} final KE {:.4e}",
            e[n - 1]
        );
        let t = (it + 1) as i32;
        for j in 0..params[0].len() {
            let gj = g.params[0][j];
            m1[0][j] = 0.9 * m1[0][j] + 0.1 * gj;
            m2[0][j] = 0.999 * m2[0][j] + 0.001 * gj.component_mul(&gj);
            for c in 0..2 {
                let mh = m1[0][j][c] / (1.0 - 0.9f64.powi(t));
                let vh = m2[0][j][c] / (1.0 - 0.999f64.powi(t));
                params[0][j][c] -= lr * bound[c] * mh / (vh.sqrt() + 1e-12);
            }
        }
        sys.controls.project(&mut params);
    }
}
