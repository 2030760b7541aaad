use morph::control::compare::RopeSettings;
use morph::control::gradient::gradient_control;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mut s = RopeSettings::default();
    s.gradient.batch_steps = a[1].parse().unwrap();
    s.gradient.learning_rate = a[2].parse().unwrap();
    s.gradient.iterations = a[3].parse().unwrap();
    let rope = s.rope.build().unwrap();
    let sys = &rope.system;
    let r = gradient_control(sys, &rope.initial, &s.gradient, s.rope.steps, |_| {}).unwrap();
    let zero = sys.controls.zero_params();
    for (name, p) in [("uncontrolled", &zero), ("gradient", &r.params)] {
        let mut st = rope.initial.clone();
        let mut out = vec![];
        sys.run(&mut st, p, 0, s.rope.steps, None, |k, st| {
            if (k + 1) % 100 == 0 {
                let v = sys.control_values(p, k, 1.0);
                out.push(format!("{:.2e}/{:.2e}", sys.kinetic_energy(st, &v), sys.grid_kinetic_energy(st, &v).unwrap()));
            }
        }).unwrap();
        println!("{name}: particle/grid KE every 100 steps: {}", out.join(" "));
    }
}
