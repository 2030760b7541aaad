//! The `morph` command line.

use clap::{Args, Parser, Subcommand};
use morph::geometry::TargetFit;
use morph::loss::MassLossKind;
use morph::morph::segment::Optimizer;
use morph::morph::{MorphError, MorphEvent, MorphSettings, Preset};
use morph::mpm::KernelKind;
use std::path::PathBuf;
use std::process::ExitCode;

const LONG_ABOUT: &str = "\
morph turns the shape in SOURCE into the shape in TARGET: SOURCE is filled with particles of an
elastic material, simulated with a differentiable Material Point Method, and steered by
optimized per-particle controls until it flows into TARGET. The result is a folder with a
frame sequence for Blender or Houdini.

SOURCE and TARGET are OBJ or PLY meshes in any units and position; open meshes (holes) are
accepted. TARGET is scaled to SOURCE's volume and centred on it unless --target-fit as-given.";

const AFTER_LONG_HELP: &str = "\
OUTPUT (folder -o, written as OUT.partial and renamed when complete):
  frames/frame_0001.ply ...  binary PLY points per frame: x y z vx vy vz J, source units
  meshes/frame_0001.obj ...  closed surface per frame, source units
  final_mass.mgrid           final nodal mass grid; compare two with `morph compare`
  manifest.json              inputs with SHA-256, settings, placement, losses, timings, frames
  loss.png, preview.png      loss curves; a contact sheet of frames

PRESETS (segments x 30 steps, passes, iterations per segment):
  draft    6 x 30, 1 pass, 10      a quick look (sphere to spot in well under 2 minutes)
  default 12 x 30, 2 passes, 12
  final   40 x 30, 3 passes, 25    the reference chain length
  Any of --segments --steps --passes --iterations overrides its preset value.

EXIT CODES:
  0  success            1  the run failed (bad mesh, simulation, writing)
  2  bad command line or option value

EXAMPLES:
  morph assets/sphere.obj assets/two-lobes.obj -o out
  morph sphere.obj bunny.obj -o bunny_morph --preset final --json > log.jsonl
  morph compare out/final_mass.mgrid golden/final_mass.mgrid --rtol 1e-6";

/// morph - turn one 3D shape into another with a differentiable Material Point Method.
#[derive(Parser, Debug)]
#[command(
    name = "morph",
    version,
    about,
    long_about = LONG_ABOUT,
    after_long_help = AFTER_LONG_HELP,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    allow_negative_numbers = true
)]
struct Cli {
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    morph: MorphArgs,
}

/// The main job: `morph SOURCE TARGET [options]`.
#[derive(Args, Debug)]
struct MorphArgs {
    /// Mesh to start from (OBJ or PLY).
    #[arg(required = true)]
    source: Option<PathBuf>,
    /// Mesh to become (OBJ or PLY).
    #[arg(required = true)]
    target: Option<PathBuf>,
    /// Output folder.
    #[arg(short, long, default_value = "morph-out")]
    output: PathBuf,
    /// Replace the output folder if it exists.
    #[arg(long)]
    overwrite: bool,
    /// Effort preset; the options below override its values.
    #[arg(long, value_enum, default_value_t = Preset::Default)]
    preset: Preset,
    /// Grid cells across the domain's longest side.
    #[arg(long)]
    resolution: Option<usize>,
    /// Segments in the chain.
    #[arg(long)]
    segments: Option<usize>,
    /// Simulation steps per segment (dt 1/120 s at the reference resolution).
    #[arg(long)]
    steps: Option<usize>,
    /// Steps between control layers in a segment.
    #[arg(long)]
    control_stride: Option<usize>,
    /// Passes over the chain (later passes refine the earlier controls).
    #[arg(long)]
    passes: Option<usize>,
    /// Optimizer evaluations per segment (Adam) or per control layer (line search).
    #[arg(long)]
    iterations: Option<usize>,
    /// Optimizer.
    #[arg(long, value_enum)]
    optimizer: Option<Optimizer>,
    /// Step size (Adam: per control entry; line search: initial normalized step).
    #[arg(long)]
    learning_rate: Option<f64>,
    /// Mass loss on the grid.
    #[arg(long, value_enum, default_value_t = MassLossKind::Log)]
    loss: MassLossKind,
    /// Weight of the kinetic energy left at each segment's end.
    #[arg(long)]
    arrival_weight: Option<f64>,
    /// How the target is placed.
    #[arg(long, value_enum, default_value_t = TargetFit::MatchVolume)]
    target_fit: TargetFit,
    /// Particles per cell along each axis (k^3 per cell).
    #[arg(long)]
    particles_per_cell: Option<usize>,
    /// Random particle offsets, in particle spacings (0..1).
    #[arg(long)]
    jitter: Option<f64>,
    /// Seed for the jitter.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Export every n-th simulation step as a frame.
    #[arg(long)]
    frame_every: Option<usize>,
    /// Skip the per-frame surface meshes (points only).
    #[arg(long)]
    no_surfaces: bool,
    /// Print one JSON object per event on stdout (for farm logs) instead of progress bars.
    #[arg(long)]
    json: bool,
    /// Print nothing but errors.
    #[arg(long, short)]
    quiet: bool,
}

impl MorphArgs {
    fn settings(&self) -> MorphSettings {
        let mut s = MorphSettings::preset(self.preset);
        let set = |dst: &mut usize, v: Option<usize>| {
            if let Some(v) = v {
                *dst = v;
            }
        };
        set(&mut s.resolution, self.resolution);
        set(&mut s.segments, self.segments);
        set(&mut s.steps_per_segment, self.steps);
        set(&mut s.control_stride, self.control_stride);
        set(&mut s.passes, self.passes);
        set(&mut s.optimizer.iterations, self.iterations);
        set(&mut s.particles_per_cell, self.particles_per_cell);
        set(&mut s.frame_every, self.frame_every);
        if let Some(o) = self.optimizer {
            s.optimizer.kind = o;
            if o == Optimizer::LineSearch && self.learning_rate.is_none() {
                s.optimizer.learning_rate = 0.1; // the reference step
            }
        }
        if let Some(lr) = self.learning_rate {
            s.optimizer.learning_rate = lr;
        }
        if let Some(w) = self.arrival_weight {
            s.arrival_weight = w;
        }
        if let Some(j) = self.jitter {
            s.jitter = j;
        }
        s.seed = self.seed;
        s.loss = self.loss;
        s.target_fit = self.target_fit;
        s.surfaces = !self.no_surfaces;
        s
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Time the engine on the reference workload; prints one JSON line per configuration.
    ///
    /// Workload: a ball of radius 8 cells in a 32^3 grid, 2x2x2 particles per cell (about
    /// 17,000 particles), fixed-corotated material (lam 58333, mu 38888.9), density 40,
    /// drag 0.5, dt 1/120, f64, deforming under controls. Reports (a) forward steps and (b)
    /// forward + reverse steps, for each kernel and thread count, best of --repeats runs.
    Bench {
        /// Steps per run.
        #[arg(long, default_value_t = 30)]
        steps: usize,
        /// Runs per configuration; the fastest is reported.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Thread counts to measure, comma separated.
        #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2])]
        thread_counts: Vec<usize>,
        /// Kernels to measure, comma separated.
        #[arg(long, value_delimiter = ',', default_values = ["quadratic", "cubic"])]
        kernels: Vec<KernelKind>,
    },
    /// Time mesh loading, voxelization and surface extraction; one JSON line per case.
    ///
    /// Every .obj/.ply in --meshes is placed alone in a domain of each --resolutions cells
    /// across and filled with 2x2x2 particles per cell; reports times, particle count and
    /// the particle volume in the mesh's own units. Then times surface extraction of
    /// particle balls of about 17k and 100k particles.
    BenchGeometry {
        /// Folder of meshes.
        #[arg(long, default_value = "../shared/meshes")]
        meshes: std::path::PathBuf,
        /// Resolutions (cells across the domain), comma separated.
        #[arg(long, value_delimiter = ',', default_values_t = [32usize, 64])]
        resolutions: Vec<usize>,
        /// Runs per case; the fastest is reported.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
    },
    /// Check a mesh before a run: topology, inside volume and particle count, as JSON.
    ///
    /// Loads MESH (OBJ or PLY) with the same validation as a morph, measures its inside
    /// (winding number > 1/2, so open meshes work) and fills it with particles as a source at
    /// --resolution. Warnings (open mesh, flipped faces, missing .mtl) go to stderr.
    Inspect {
        /// The mesh file.
        mesh: std::path::PathBuf,
        /// Grid cells across the domain's longest side.
        #[arg(long, default_value_t = 32)]
        resolution: usize,
    },
    /// Compare two nodal mass grids (final_mass.mgrid); exit 0 if equal within tolerance.
    ///
    /// Equal means |a - b| <= atol + rtol * |b| at every node (b is the reference). Prints the
    /// node count, max and mean absolute difference as JSON. Exit 0: equal; 1: different or
    /// incompatible grids (shape, origin, spacing); 2: unreadable file or bad option.
    Compare {
        /// The grid to check.
        a: PathBuf,
        /// The reference grid.
        b: PathBuf,
        /// Relative tolerance.
        #[arg(long, default_value_t = 1e-5)]
        rtol: f64,
        /// Absolute tolerance.
        #[arg(long, default_value_t = 1e-8)]
        atol: f64,
    },
    /// Active damping of a swinging rope: uncontrolled vs MPPI vs gradient control (RK4).
    ///
    /// A fixed-corotated rope clamped at one end is released horizontal under gravity; the
    /// controllers move the clamp (and/or push the tip) to remove its kinetic energy. Prints
    /// a table and writes OUT/report.json, OUT/energy.png and OUT/frames/<method>/*.ply.
    /// Exit 0: ok; 1: the run failed; 2: bad option. Scene details: docs/control.md.
    Rope(Box<RopeArgs>),
    /// Write the built-in meshes (sphere, torus, cube, two lobes) as OBJ into a folder.
    Assets {
        /// Destination folder.
        #[arg(short, long, default_value = "assets")]
        output: std::path::PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(t) = cli.threads {
        if t == 0 || t > 1024 {
            eprintln!("morph: error: --threads must be between 1 and 1024, got {t}");
            return ExitCode::from(2);
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
        {
            eprintln!("morph: error: cannot start {t} threads: {e}");
            return ExitCode::from(2);
        }
    }
    let result = match cli.command {
        None => return run_morph(&cli.morph),
        Some(Command::Bench {
            steps,
            repeats,
            thread_counts,
            kernels,
        }) => {
            if steps == 0 || thread_counts.contains(&0) {
                eprintln!("morph: error: --steps and --thread-counts must be positive");
                return ExitCode::from(2);
            }
            morph::bench::run(steps, repeats, &thread_counts, &kernels)
        }
        Some(Command::BenchGeometry {
            meshes,
            resolutions,
            repeats,
        }) => morph::bench::geometry::run(&meshes, &resolutions, repeats),
        Some(Command::Inspect { mesh, resolution }) => morph::geometry::inspect(&mesh, resolution)
            .map_err(anyhow::Error::from)
            .and_then(|report| {
                for w in &report.warnings {
                    eprintln!("morph: warning: {w}");
                }
                println!("{}", serde_json::to_string_pretty(&report)?);
                Ok(())
            }),
        Some(Command::Compare { a, b, rtol, atol }) => return compare(&a, &b, rtol, atol),
        Some(Command::Rope(args)) => return run_rope(&args),
        Some(Command::Assets { output }) => morph::geometry::assets::write_builtin(&output)
            .map(|paths| {
                for p in paths {
                    println!("{}", p.display());
                }
            })
            .map_err(|e| anyhow::anyhow!("cannot write assets into '{}': {e}", output.display())),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("morph: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn compare(a: &std::path::Path, b: &std::path::Path, rtol: f64, atol: f64) -> ExitCode {
    use morph::io::massgrid::{MassGrid, compare};
    if !(rtol.is_finite() && rtol >= 0.0 && atol.is_finite() && atol >= 0.0) {
        eprintln!("morph: error: --rtol and --atol must be finite and >= 0");
        return ExitCode::from(2);
    }
    let (ga, gb) = match (MassGrid::read(a), MassGrid::read(b)) {
        (Ok(x), Ok(y)) => (x, y),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("morph: error: {e}");
            return ExitCode::from(2);
        }
    };
    match compare(&ga, &gb, rtol, atol) {
        Ok(c) => {
            println!("{}", serde_json::to_string(&c).expect("plain struct"));
            if c.within_tolerance {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        Err(e) => {
            println!(
                "{}",
                serde_json::json!({ "within_tolerance": false, "error": e })
            );
            eprintln!("morph: {e}");
            ExitCode::FAILURE
        }
    }
}

/// `morph SOURCE TARGET`: progress bars on a terminal, JSON lines with --json.
fn run_morph(args: &MorphArgs) -> ExitCode {
    use indicatif::{ProgressBar, ProgressStyle};
    use std::io::IsTerminal;
    let (Some(source), Some(target)) = (&args.source, &args.target) else {
        eprintln!("morph: error: give a SOURCE and a TARGET mesh (see morph --help)");
        return ExitCode::from(2);
    };
    let settings = args.settings();
    if let Err(e) = settings.validate() {
        eprintln!("morph: error: {e}");
        return ExitCode::from(2);
    }
    let show_bar = !args.quiet && !args.json && std::io::stderr().is_terminal();
    let bar = ProgressBar::hidden();
    let mut last_loss = f64::NAN;
    let on_event = |e: &MorphEvent| {
        if args.json {
            println!("{}", serde_json::to_string(e).expect("plain event"));
            return;
        }
        match e {
            MorphEvent::Setup {
                particles,
                grid_cells,
                segments,
                passes,
                iterations,
                warnings,
                ..
            } => {
                if !args.quiet {
                    for w in warnings {
                        eprintln!("morph: warning: {w}");
                    }
                }
                if show_bar {
                    bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                    bar.set_length((segments * passes * iterations) as u64);
                    bar.set_style(
                        ProgressStyle::with_template(
                            "{elapsed_precise} [{bar:30}] {pos}/{len} evaluations  {msg}",
                        )
                        .expect("valid template")
                        .progress_chars("=> "),
                    );
                    bar.println(format!(
                        "morph: {particles} particles on a {}x{}x{} grid, {segments} segments x {passes} passes",
                        grid_cells[0], grid_cells[1], grid_cells[2]
                    ));
                }
            }
            MorphEvent::Iteration {
                pass,
                segment,
                loss,
                ..
            } => {
                if loss.is_finite() {
                    last_loss = *loss;
                }
                bar.inc(1);
                bar.set_message(format!(
                    "pass {}  segment {}  loss {last_loss:.4e}",
                    pass + 1,
                    segment + 1
                ));
            }
            MorphEvent::Segment { .. } | MorphEvent::Done { .. } => {}
        }
    };
    let result = morph::morph::output::morph_to_folder(
        &settings,
        source,
        target,
        &args.output,
        args.overwrite,
        on_event,
    );
    bar.finish_and_clear();
    match result {
        Ok(summary) => {
            if args.json {
                println!(
                    "{}",
                    serde_json::json!({ "event": "written", "summary": summary })
                );
            } else if !args.quiet {
                println!(
                    "wrote {}: {} frames of {} particles; loss {:.4e} -> {:.4e}; target cells filled {:.1}%, particles outside {:.2}% (ejected {:.2}%); {:.1} s",
                    summary.output.display(),
                    summary.frames,
                    summary.particles,
                    summary.initial_loss,
                    summary.final_loss,
                    100.0 * summary.fill.target_cells_filled,
                    100.0 * summary.fill.particles_outside,
                    100.0 * summary.fill.particles_ejected,
                    summary.seconds
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("morph: error: {e}");
            match e {
                MorphError::Settings(_) => ExitCode::from(2),
                _ => ExitCode::FAILURE,
            }
        }
    }
}

#[derive(clap::Args, Debug)]
#[command(allow_negative_numbers = true)]
struct RopeArgs {
    /// Output folder (written as OUT.partial, renamed when complete).
    #[arg(short, long, default_value = "rope-out")]
    output: PathBuf,
    /// Replace an existing output folder.
    #[arg(long)]
    overwrite: bool,
    /// Print progress as JSON lines instead of a progress bar.
    #[arg(long)]
    json: bool,
    /// No progress output.
    #[arg(short, long)]
    quiet: bool,
    /// Simulated steps (the control horizon).
    #[arg(long, default_value_t = 1000)]
    steps: i64,
    /// Time step (s).
    #[arg(long, default_value_t = 2.0e-3)]
    dt: f64,
    /// Grid cells along the rope (dx = 0.5 m / cells).
    #[arg(long, default_value_t = 16)]
    cells_along: i64,
    /// Young's modulus (Pa).
    #[arg(long, default_value_t = 1.0e5)]
    youngs_modulus: f64,
    /// What the controllers move.
    #[arg(long, value_enum, default_value = "segments")]
    actuation: morph::control::rope::Actuation,
    /// Steps per control interval.
    #[arg(long, default_value_t = 10)]
    control_interval: i64,
    /// Controls inside an interval: constant or linear.
    #[arg(long, value_enum, default_value = "linear")]
    interpolation: morph::ode::Interpolation,
    /// Largest clamp speed per axis (m/s).
    #[arg(long, default_value_t = 0.3)]
    max_clamp_speed: f64,
    /// Largest tip acceleration per axis (m/s^2).
    #[arg(long, default_value_t = 5.0)]
    max_tip_acceleration: f64,
    /// Gradient controller: steps per inner batch (N).
    #[arg(long, default_value_t = 50)]
    batch: i64,
    /// Gradient controller: extra steps simulated and costed after each batch.
    #[arg(long, default_value_t = 50)]
    lookahead: i64,
    /// Gradient controller: Adam iterations per batch.
    #[arg(long, default_value_t = 5)]
    iterations: i64,
    /// Gradient controller: Adam step, as a fraction of each control's bound.
    #[arg(long, default_value_t = 0.3)]
    lr: f64,
    /// MPPI: samples per update (K).
    #[arg(long, default_value_t = 256)]
    samples: i64,
    /// MPPI: planning horizon (steps).
    #[arg(long, default_value_t = 50)]
    mppi_horizon: i64,
    /// MPPI: steps committed per replanning.
    #[arg(long, default_value_t = 10)]
    replan: i64,
    /// MPPI: updates per replanning.
    #[arg(long, default_value_t = 1)]
    refinements: i64,
    /// MPPI: temperature, relative to the sampled costs' spread.
    #[arg(long, default_value_t = 0.1)]
    lambda: f64,
    /// MPPI: noise standard deviation, as a fraction of the bound.
    #[arg(long, default_value_t = 0.6)]
    noise: f64,
    /// MPPI: random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// A PLY frame every this many steps (0: none).
    #[arg(long, default_value_t = 10)]
    frame_every: i64,
    /// Low energy = this fraction of the uncontrolled peak kinetic energy.
    #[arg(long, default_value_t = 0.01)]
    low_energy: f64,
}

/// A count option: must be >= `min`.
fn count(name: &str, v: i64, min: i64) -> Result<usize, String> {
    if v < min {
        Err(format!("--{name} must be at least {min}, got {v}"))
    } else {
        Ok(v as usize)
    }
}

fn rope_settings(a: &RopeArgs) -> Result<morph::control::compare::RopeSettings, String> {
    use morph::control::compare::RopeSettings;
    let mut s = RopeSettings::default();
    s.rope.steps = count("steps", a.steps, 1)?;
    s.rope.dt = a.dt;
    s.rope.cells_along = count("cells-along", a.cells_along, 4)?;
    s.rope.youngs_modulus = a.youngs_modulus;
    s.rope.actuation = a.actuation;
    s.rope.control_interval = count("control-interval", a.control_interval, 1)?;
    s.rope.interpolation = a.interpolation;
    s.rope.max_clamp_speed = a.max_clamp_speed;
    s.rope.max_tip_acceleration = a.max_tip_acceleration;
    s.gradient.batch_steps = count("batch", a.batch, 1)?;
    s.gradient.iterations = count("iterations", a.iterations, 1)?;
    s.gradient.lookahead_steps = count("lookahead", a.lookahead, 0)?;
    s.gradient.learning_rate = a.lr;
    s.mppi.samples = count("samples", a.samples, 2)?;
    s.mppi.horizon_steps = count("mppi-horizon", a.mppi_horizon, 1)?;
    s.mppi.replan_steps = count("replan", a.replan, 1)?;
    s.mppi.refinements = count("refinements", a.refinements, 1)?;
    s.mppi.lambda = a.lambda;
    s.mppi.noise = a.noise;
    s.mppi.seed = a.seed;
    s.frame_every = count("frame-every", a.frame_every, 0)?;
    s.low_energy_fraction = a.low_energy;
    Ok(s)
}

fn run_rope(args: &RopeArgs) -> ExitCode {
    use morph::control::ControlEvent;
    use morph::control::compare::{RopeError, rope_to_folder, table};
    let settings = match rope_settings(args) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("morph: error: {e}");
            return ExitCode::from(2);
        }
    };
    if let Err(e) = settings.validate() {
        eprintln!("morph: error: {e}");
        return ExitCode::from(2);
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
            eprintln!("morph: error: {e}");
            ExitCode::from(if matches!(e, RopeError::Settings(_)) {
                2
            } else {
                1
            })
        }
    }
}
