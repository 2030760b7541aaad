//! The `morph` command line.

use clap::{Args, Parser, Subcommand};
use morph::geometry::TargetFit;
use morph::loss::MassLossKind;
use morph::morph::segment::Optimizer;
use morph::morph::settings::limits;
use morph::morph::{MorphError, MorphEvent, MorphSettings, Preset};
use morph::mpm::KernelKind;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicUsize;

const LONG_ABOUT: &str = "\
morph turns the shape in SOURCE into the shape in TARGET: SOURCE is filled with particles of an
elastic material, simulated with a differentiable Material Point Method, and steered by
optimized per-particle controls until it flows into TARGET. The result is a folder with a
frame sequence for Blender or Houdini.

SOURCE and TARGET are OBJ or PLY meshes in any units and position; open meshes (holes) are
accepted. TARGET is scaled to SOURCE's volume and centred on it unless --target-fit as-given.";

const AFTER_LONG_HELP: &str = "\
OUTPUT (folder -o, written in the locked OUT.partial and put in place when complete):
  frames/frame_0001.ply ...  binary PLY points per frame: x y z vx vy vz J, source units
  meshes/frame_0001.obj ...  closed surface per frame, source units
  final_mass.mgrid           final nodal mass grid; compare two with `morph compare`
  manifest.json              inputs with SHA-256, settings, placement, losses, timings, frames
  run.json                   what decides the result: tool version, input hashes, settings
  loss.png, preview.png      loss curves; a contact sheet of frames
  -o is checked before any work; --overwrite replaces only an earlier morph output; a second
  run on the same -o fails at once. Each completed segment is checkpointed in OUT.partial.

PRESETS (segments x steps, passes, iterations per segment):
{presets}
  Any of --segments --steps --passes --iterations overrides its preset value.

EXIT CODES:
  0    success (every written file checked finite)
  1    the run failed (bad mesh, simulation, writing, output folder in use)
  2    bad command line, option value or output folder (refused before any work)
  130  interrupted by SIGINT (Ctrl-C), 143 by SIGTERM: completed segments are kept in
       OUT.partial; the same command with --resume continues bit for bit

EXAMPLES:
  morph assets/sphere.obj assets/two-lobes.obj -o out
  morph sphere.obj bunny.obj -o bunny_morph --preset final --json > log.jsonl
  morph sphere.obj bunny.obj -o bunny_morph --preset final --resume   # after an interruption
  morph compare out/final_mass.mgrid golden/final_mass.mgrid --rtol 1e-6";

/// morph - turn one 3D shape into another with a differentiable Material Point Method.
#[derive(Parser, Debug)]
#[command(
    name = "morph",
    version,
    about,
    long_about = LONG_ABOUT,
    after_long_help = after_long_help(),
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

/// `--help` text for an option: what it does, its range, its default (read from the library's
/// default preset and limits, so the help cannot drift from what runs).
fn help(
    what: &str,
    range: Option<std::ops::RangeInclusive<usize>>,
    default: impl std::fmt::Display,
) -> String {
    match range {
        Some(r) => format!(
            "{what} [range {}-{}; default {default}]",
            r.start(),
            r.end()
        ),
        None => format!("{what} [default {default}]"),
    }
}

fn defaults() -> MorphSettings {
    MorphSettings::preset(Preset::Default)
}

const PRESETS: [(Preset, &str); 3] = [
    (Preset::Draft, "draft"),
    (Preset::Default, "default"),
    (Preset::Final, "final"),
];

/// A preset-dependent default, read from the library: "draft 6, default 12, final 40".
fn by_preset(value: impl Fn(&MorphSettings) -> usize) -> String {
    let parts: Vec<String> = PRESETS
        .iter()
        .map(|(p, name)| format!("{name} {}", value(&MorphSettings::preset(*p))))
        .collect();
    format!("by preset: {}", parts.join(", "))
}

fn after_long_help() -> String {
    let presets: Vec<String> = PRESETS
        .iter()
        .map(|(p, name)| {
            let s = MorphSettings::preset(*p);
            format!(
                "  {name:<8}{:>3} x {}, {} pass(es), {}",
                s.segments, s.steps_per_segment, s.passes, s.optimizer.iterations
            )
        })
        .collect();
    AFTER_LONG_HELP.replace("{presets}", &presets.join("\n"))
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
    /// Output folder (a new folder, an empty one, or an earlier morph output with --overwrite).
    #[arg(short, long, default_value = "morph-out")]
    output: PathBuf,
    /// Replace the output folder if it holds an earlier morph output (nothing else is ever
    /// replaced); also starts over from an interrupted run's OUT.partial.
    #[arg(long)]
    overwrite: bool,
    /// Continue an interrupted run (same inputs and settings) from OUT.partial; starts afresh
    /// when there is nothing to continue, and does nothing when OUT is already complete.
    #[arg(long)]
    resume: bool,
    /// Effort preset; the options below override its values.
    #[arg(long, value_enum, default_value_t = Preset::Default)]
    preset: Preset,
    #[arg(long, help = help("Grid cells across the domain's longest side", Some(limits::RESOLUTION), defaults().resolution))]
    resolution: Option<usize>,
    #[arg(long, help = help("Segments in the chain", Some(limits::SEGMENTS), by_preset(|s| s.segments)))]
    segments: Option<usize>,
    #[arg(long, help = help("Simulation steps per segment (dt 1/120 s at the reference resolution)", Some(limits::STEPS), defaults().steps_per_segment))]
    steps: Option<usize>,
    #[arg(long, help = format!("Steps between control layers in a segment [range 1 to --steps; default {}]", defaults().control_stride))]
    control_stride: Option<usize>,
    #[arg(long, help = help("Passes over the chain (later passes refine the earlier controls)", Some(limits::PASSES), by_preset(|s| s.passes)))]
    passes: Option<usize>,
    #[arg(long, help = help("Optimizer evaluations per segment (Adam) or per control layer (line search)", Some(limits::ITERATIONS), by_preset(|s| s.optimizer.iterations)))]
    iterations: Option<usize>,
    /// Optimizer [default adam].
    #[arg(long, value_enum)]
    optimizer: Option<Optimizer>,
    #[arg(long, help = help("Step size (Adam: per control entry; line search: initial normalized step), > 0", None, format!("{} (line search 0.1)", defaults().optimizer.learning_rate)))]
    learning_rate: Option<f64>,
    /// Mass loss on the grid.
    #[arg(long, value_enum, default_value_t = MassLossKind::Log)]
    loss: MassLossKind,
    #[arg(long, help = help("Weight of the kinetic energy left at each segment's end, >= 0", None, defaults().arrival_weight))]
    arrival_weight: Option<f64>,
    /// How the target is placed.
    #[arg(long, value_enum, default_value_t = TargetFit::MatchVolume)]
    target_fit: TargetFit,
    #[arg(long, help = help("Particles per cell along each axis (k^3 per cell)", Some(limits::PARTICLES_PER_CELL), defaults().particles_per_cell))]
    particles_per_cell: Option<usize>,
    #[arg(long, help = help("Random particle offsets, in particle spacings, 0 to 1", None, defaults().jitter))]
    jitter: Option<f64>,
    /// Seed for the jitter.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, help = help("Export every n-th simulation step as a frame", Some(limits::FRAME_EVERY), defaults().frame_every))]
    frame_every: Option<usize>,
    /// Skip the per-frame surface meshes (points only).
    #[arg(long)]
    no_surfaces: bool,
    /// Print one JSON object per event on stdout (for farm logs) instead of progress bars;
    /// a failure ends the stream with an `error` event.
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
        #[arg(long, default_value_t = defaults().resolution as u16,
              value_parser = clap::value_parser!(u16).range(*limits::RESOLUTION.start() as i64..=*limits::RESOLUTION.end() as i64),
              help = help("Grid cells across the domain's longest side", Some(limits::RESOLUTION), defaults().resolution))]
        resolution: u16,
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
        /// Replace existing files of the same names.
        #[arg(long)]
        overwrite: bool,
    },
}

/// Prints a failure: one line `morph: error: ...` on stderr and, in `--json` mode, an `error`
/// event as the last line on stdout.
fn fail(json: bool, code: u8, message: &str) -> ExitCode {
    eprintln!("morph: error: {message}");
    if json {
        println!(
            "{}",
            serde_json::json!({ "event": "error", "message": message, "exit_code": code })
        );
    }
    ExitCode::from(code)
}

/// A command-line parse error as one line (clap's message spans several with usage notes).
fn parse_error(e: clap::Error, json: bool) -> ExitCode {
    use clap::error::ErrorKind;
    if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) {
        let _ = e.print();
        return ExitCode::SUCCESS;
    }
    let text = e.render().to_string();
    let mut parts = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.starts_with("Usage:") || line.starts_with("For more information") {
            break;
        }
        if !line.is_empty() {
            parts.push(line.trim_start_matches("error:").trim().to_string());
        }
    }
    let message = format!("{} (see morph --help)", parts.join(" "));
    fail(json, 2, &message)
}

fn main() -> ExitCode {
    let json = std::env::args_os().any(|a| a == "--json");
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return parse_error(e, json),
    };
    if let Some(t) = cli.threads {
        if t == 0 || t > 1024 {
            return fail(
                json,
                2,
                &format!("--threads must be between 1 and 1024, got {t}"),
            );
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
        {
            return fail(json, 1, &format!("cannot start {t} threads: {e}"));
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
            if steps == 0 || repeats == 0 || thread_counts.contains(&0) {
                return fail(
                    false,
                    2,
                    "--steps, --repeats and --thread-counts must be positive",
                );
            }
            morph::bench::run(steps, repeats, &thread_counts, &kernels)
        }
        Some(Command::BenchGeometry {
            meshes,
            resolutions,
            repeats,
        }) => {
            if let Some(r) = resolutions.iter().find(|r| !limits::RESOLUTION.contains(r)) {
                return fail(
                    false,
                    2,
                    &format!(
                        "--resolutions must each be between {} and {}, got {r}",
                        limits::RESOLUTION.start(),
                        limits::RESOLUTION.end()
                    ),
                );
            }
            if repeats == 0 {
                return fail(false, 2, "--repeats must be at least 1");
            }
            morph::bench::geometry::run(&meshes, &resolutions, repeats)
        }
        Some(Command::Inspect { mesh, resolution }) => {
            match morph::geometry::inspect(&mesh, resolution as usize) {
                Ok(report) => {
                    for w in &report.warnings {
                        eprintln!("morph: warning: {w}");
                    }
                    println!(
                        "{}",
                        serde_json::to_string_pretty(&report).expect("plain report")
                    );
                    Ok(())
                }
                Err(e @ morph::geometry::MeshError::BadOption(_)) => {
                    return fail(false, 2, &e.to_string());
                }
                Err(e) => Err(e.into()),
            }
        }
        Some(Command::Compare { a, b, rtol, atol }) => return compare(&a, &b, rtol, atol),
        Some(Command::Rope(args)) => return run_rope(&args),
        Some(Command::Assets { output, overwrite }) => {
            morph::geometry::assets::write_builtin(&output, overwrite)
                .map(|paths| {
                    for p in paths {
                        println!("{}", p.display());
                    }
                })
                .map_err(|e| {
                    anyhow::anyhow!("cannot write assets into '{}': {e}", output.display())
                })
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(false, 1, &format!("{e:#}")),
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
            if let Some(n) = &c.non_finite {
                eprintln!(
                    "morph: error: non-finite mass at node {:?} (index {}): {} vs {} ({} such nodes)",
                    n.node, n.index, n.a, n.b, n.count
                );
            }
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
            eprintln!("morph: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// SIGINT and SIGTERM set `stop` to the signal's number: the run stops at its next
/// evaluation and keeps its checkpoint. A second signal while stopping exits at once.
fn stop_on_signals() -> std::io::Result<Arc<AtomicUsize>> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let stop = Arc::new(AtomicUsize::new(0));
    let stopping = Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [SIGINT, SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 128 + sig, Arc::clone(&stopping))?;
        signal_hook::flag::register(sig, Arc::clone(&stopping))?;
        signal_hook::flag::register_usize(sig, Arc::clone(&stop), sig as usize)?;
    }
    Ok(stop)
}

fn signal_name(signal: usize) -> &'static str {
    match signal as i32 {
        signal_hook::consts::SIGINT => "SIGINT",
        signal_hook::consts::SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}

/// `morph SOURCE TARGET`: progress bars on a terminal, JSON lines with --json.
fn run_morph(args: &MorphArgs) -> ExitCode {
    use indicatif::{ProgressBar, ProgressStyle};
    use std::io::IsTerminal;
    let (Some(source), Some(target)) = (&args.source, &args.target) else {
        return fail(
            args.json,
            2,
            "give a SOURCE and a TARGET mesh (see morph --help)",
        );
    };
    let settings = args.settings();
    if let Err(e) = settings.validate() {
        return fail(args.json, 2, &e);
    }
    let stop = match stop_on_signals() {
        Ok(s) => s,
        Err(e) => return fail(args.json, 1, &format!("cannot watch for signals: {e}")),
    };
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
    let request = morph::morph::output::OutputRequest {
        out: &args.output,
        overwrite: args.overwrite,
        resume: args.resume,
        stop: Some(&stop),
    };
    let result =
        morph::morph::output::morph_to_folder(&settings, source, target, &request, on_event);
    bar.finish_and_clear();
    match result {
        Ok(summary) => {
            if args.json {
                println!(
                    "{}",
                    serde_json::json!({ "event": "written", "summary": summary })
                );
            } else if !args.quiet {
                if summary.already_complete {
                    println!(
                        "{} is already complete for these inputs and settings; nothing to do",
                        summary.output.display()
                    );
                    return ExitCode::SUCCESS;
                }
                if let Some(from) = &summary.resumed_from {
                    println!("resumed from the checkpoint ({from})");
                }
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
        Err(MorphError::Interrupted { signal, kept }) => {
            let code = (128 + signal).min(255) as u8;
            let staging = morph::io::outdir::partial_dir(&args.output);
            let message = if kept {
                format!(
                    "interrupted by {}: completed segments are kept in '{}'; run the same command with --resume to continue",
                    signal_name(signal),
                    staging.display()
                )
            } else {
                format!(
                    "interrupted by {} before any segment completed; nothing was kept",
                    signal_name(signal)
                )
            };
            eprintln!("morph: {message}");
            if args.json {
                println!(
                    "{}",
                    serde_json::json!({ "event": "interrupted", "signal": signal_name(signal), "message": message, "exit_code": code })
                );
            }
            ExitCode::from(code)
        }
        Err(e) => {
            let code = match e {
                MorphError::Settings(_)
                | MorphError::Mesh(morph::geometry::MeshError::BadOption(_)) => 2,
                _ => 1,
            };
            fail(args.json, code, &e.to_string())
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
