//! `morph rope`: the rope active-damping comparison (uncontrolled, MPPI, gradient control).

use super::{choice, fail, name};
use morph::apps::rope::compare::RopeSettings;
use morph::apps::rope::scene::{Actuation, ClampMode};
use std::path::PathBuf;
use std::process::ExitCode;

/// The library's rope defaults: every default shown in `--help` comes from here.
fn d() -> RopeSettings {
    RopeSettings::default()
}

/// `--help` text with the library's default.
fn h(what: &str, default: impl std::fmt::Display) -> String {
    format!("{what} [default {default}]")
}

#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
pub struct RopeArgs {
    /// Output folder (written in the locked OUT.partial, put in place when complete).
    #[arg(short, long, default_value = "rope-out")]
    output: PathBuf,
    /// Replace an existing rope output folder (one holding a report.json).
    #[arg(long)]
    overwrite: bool,
    /// Print progress as JSON lines instead of a progress bar; a failure ends with an `error`
    /// event.
    #[arg(long)]
    json: bool,
    /// No progress output.
    #[arg(short, long)]
    quiet: bool,
    #[arg(long, help = h("Simulated steps (the control horizon), at least 1", d().rope.steps))]
    steps: Option<i64>,
    #[arg(long, help = h("Time step (s)", d().rope.dt))]
    dt: Option<f64>,
    #[arg(long, help = h("Grid cells along the rope (dx = rope length / cells), at least 4", d().rope.cells_along))]
    cells_along: Option<i64>,
    #[arg(long, value_parser = choice(&morph::engine::material::MaterialModel::ALL), help = h("Constitutive model of the rope", name(&d().rope.material)))]
    material: Option<morph::engine::material::MaterialModel>,
    #[arg(long, value_parser = choice(&morph::engine::integrator::IntegratorKind::ALL), help = h("Time integrator: rk4 (four evaluations a step, little numerical damping) or euler (the MLS-MPM step)", name(&d().rope.integrator)))]
    integrator: Option<morph::engine::integrator::IntegratorKind>,
    #[arg(long, help = h("Young's modulus (Pa)", d().rope.youngs_modulus))]
    youngs_modulus: Option<f64>,
    #[arg(long, value_parser = choice(&Actuation::ALL), help = h("What the controllers actuate: segment forces, the tip force, the clamp, or the clamp and the tip", name(&d().rope.actuation)))]
    actuation: Option<Actuation>,
    #[arg(long, value_parser = choice(&ClampMode::ALL), help = h("How the clamp is driven when it is actuated: a prescribed position offset or a prescribed velocity", name(&d().rope.clamp_mode)))]
    clamp_mode: Option<ClampMode>,
    #[arg(long, help = h("Steps per control interval", d().rope.control_interval))]
    control_interval: Option<i64>,
    #[arg(long, value_parser = choice(&morph::engine::mpm::Interpolation::ALL), help = h("Controls inside an interval: constant or linear", name(&d().rope.interpolation)))]
    interpolation: Option<morph::engine::mpm::Interpolation>,
    #[arg(long, help = h("Largest clamp offset per axis (m), clamp-mode position", d().rope.max_clamp_offset))]
    max_clamp_offset: Option<f64>,
    #[arg(long, help = h("Largest clamp speed per axis (m/s), clamp-mode velocity", d().rope.max_clamp_speed))]
    max_clamp_speed: Option<f64>,
    #[arg(long, help = h("Largest body-force acceleration per axis (m/s^2), of the tip or of each segment", d().rope.max_tip_acceleration))]
    max_tip_acceleration: Option<f64>,
    #[arg(long, help = h("Gradient controller: steps per inner batch (N)", d().gradient.batch_steps))]
    batch: Option<i64>,
    #[arg(long, help = h("Gradient controller: extra steps simulated and costed after each batch", d().gradient.lookahead_steps))]
    lookahead: Option<i64>,
    #[arg(long, help = h("Gradient controller: Adam iterations per batch", d().gradient.iterations))]
    iterations: Option<i64>,
    #[arg(long, help = h("Gradient controller: Adam step, as a fraction of each control's bound", d().gradient.learning_rate))]
    lr: Option<f64>,
    #[arg(long, help = h("MPPI: samples per update (K), at least 2", d().mppi.samples))]
    samples: Option<i64>,
    #[arg(long, help = h("MPPI: planning horizon (steps)", d().mppi.horizon_steps))]
    mppi_horizon: Option<i64>,
    #[arg(long, help = h("MPPI: steps committed per replanning", d().mppi.replan_steps))]
    replan: Option<i64>,
    #[arg(long, help = h("MPPI: updates per replanning", d().mppi.refinements))]
    refinements: Option<i64>,
    #[arg(long, help = h("MPPI: temperature, relative to the sampled costs' spread", d().mppi.lambda))]
    lambda: Option<f64>,
    #[arg(long, help = h("MPPI: noise standard deviation, as a fraction of the bound", d().mppi.noise))]
    noise: Option<f64>,
    #[arg(long, help = h("MPPI: random seed", d().mppi.seed))]
    seed: Option<u64>,
    #[arg(long, help = h("A PLY frame every this many steps (0: none)", d().frame_every))]
    frame_every: Option<i64>,
    #[arg(long, help = h("Low energy = this fraction of the uncontrolled peak kinetic energy", d().low_energy_fraction))]
    low_energy: Option<f64>,
}

/// A count option: must be >= `min` and at most the library's bound.
fn count(name: &str, v: i64, min: i64) -> Result<usize, String> {
    use morph::apps::rope::compare::{MAX_ROPE_CELLS, MAX_ROPE_COUNT};
    let max = if name == "cells-along" {
        MAX_ROPE_CELLS
    } else {
        MAX_ROPE_COUNT
    };
    if v < min {
        Err(format!("--{name} must be at least {min}, got {v}"))
    } else if v as u64 > max as u64 {
        Err(format!("--{name} must be at most {max}, got {v}"))
    } else {
        Ok(v as usize)
    }
}

/// The library's defaults with the options given on the command line.
fn rope_settings(a: &RopeArgs) -> Result<RopeSettings, String> {
    let mut s = RopeSettings::default();
    let counts: [(&str, Option<i64>, i64, &mut usize); 10] = [
        ("steps", a.steps, 1, &mut s.rope.steps),
        ("cells-along", a.cells_along, 4, &mut s.rope.cells_along),
        (
            "control-interval",
            a.control_interval,
            1,
            &mut s.rope.control_interval,
        ),
        ("batch", a.batch, 1, &mut s.gradient.batch_steps),
        ("iterations", a.iterations, 1, &mut s.gradient.iterations),
        ("lookahead", a.lookahead, 0, &mut s.gradient.lookahead_steps),
        ("samples", a.samples, 2, &mut s.mppi.samples),
        ("mppi-horizon", a.mppi_horizon, 1, &mut s.mppi.horizon_steps),
        ("replan", a.replan, 1, &mut s.mppi.replan_steps),
        ("refinements", a.refinements, 1, &mut s.mppi.refinements),
    ];
    for (name, given, min, dst) in counts {
        if let Some(v) = given {
            *dst = count(name, v, min)?;
        }
    }
    if let Some(v) = a.frame_every {
        s.frame_every = count("frame-every", v, 0)?;
    }
    let numbers: [(Option<f64>, &mut f64); 9] = [
        (a.dt, &mut s.rope.dt),
        (a.youngs_modulus, &mut s.rope.youngs_modulus),
        (a.max_clamp_offset, &mut s.rope.max_clamp_offset),
        (a.max_clamp_speed, &mut s.rope.max_clamp_speed),
        (a.max_tip_acceleration, &mut s.rope.max_tip_acceleration),
        (a.lr, &mut s.gradient.learning_rate),
        (a.lambda, &mut s.mppi.lambda),
        (a.noise, &mut s.mppi.noise),
        (a.low_energy, &mut s.low_energy_fraction),
    ];
    for (given, dst) in numbers {
        if let Some(v) = given {
            *dst = v;
        }
    }
    if let Some(v) = a.actuation {
        s.rope.actuation = v;
    }
    if let Some(v) = a.clamp_mode {
        s.rope.clamp_mode = v;
    }
    if let Some(v) = a.interpolation {
        s.rope.interpolation = v;
    }
    if let Some(v) = a.material {
        s.rope.material = v;
    }
    if let Some(v) = a.integrator {
        s.rope.integrator = v;
    }
    if let Some(v) = a.seed {
        s.mppi.seed = v;
    }
    Ok(s)
}

pub fn run(args: &RopeArgs) -> ExitCode {
    use morph::apps::rope::ControlEvent;
    use morph::apps::rope::compare::{RopeError, rope_to_folder, table};
    let settings = match rope_settings(args) {
        Ok(s) => s,
        Err(e) => return fail(args.json, 2, &e),
    };
    if let Err(e) = settings.validate() {
        return fail(args.json, 2, &e.to_string());
    }
    let show = !args.quiet && !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let bar = show.then(|| {
        let b = indicatif::ProgressBar::new((2 * settings.rope.steps) as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {msg}")
                .expect("valid template"),
        );
        b
    });
    let steps = settings.rope.steps as u64;
    let on_event = |e: ControlEvent| {
        if let (true, Ok(line)) = (args.json, serde_json::to_string(&e)) {
            println!("{line}");
        }
        if let Some(b) = &bar {
            let ControlEvent::Window {
                method, step, cost, ..
            } = &e;
            let offset = if *method == "gradient" { steps } else { 0 };
            b.set_position(offset + *step as u64);
            b.set_message(format!("{method} step {step} cost {cost:.3e}"));
        }
    };
    match rope_to_folder(&settings, &args.output, args.overwrite, on_event) {
        Ok(report) => {
            if let Some(b) = &bar {
                b.finish_and_clear();
            }
            if args.json {
                println!(
                    "{}",
                    serde_json::json!({"event": "written", "output": args.output, "ratios": report.ratios})
                );
            } else if !args.quiet {
                print!("{}", table(&report));
                println!("wrote {}", args.output.display());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            if let Some(b) = &bar {
                b.finish_and_clear();
            }
            let code = if matches!(e, RopeError::Settings(_)) {
                2
            } else {
                1
            };
            fail(args.json, code, &e.to_string())
        }
    }
}
