//! The `morph` command line: parses, calls the library, reports. One file per subcommand;
//! every default and range is read from the library, never restated here.

/// `println!` that ignores a closed stdout: a morph run ignores SIGPIPE (to keep its work and
/// say why it stopped), and a line nobody reads must not end it in a panic.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

mod assets;
mod bench;
mod compare;
mod farm;
mod inspect;
mod liken;
mod morph;
mod rope;
mod study;

use ::morph::{MorphSettings, Preset};
use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// morph - turn one 3D shape into another with a differentiable Material Point Method.
#[derive(Parser, Debug)]
#[command(
    name = "morph",
    version,
    about,
    long_about = morph::LONG_ABOUT,
    after_long_help = morph::after_long_help(),
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    allow_negative_numbers = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    morph: morph::MorphArgs,
    /// Worker threads [range 1-1024, at most the machine's cores are used; default: all
    /// cores]. Results are identical for any count.
    #[arg(long, global = true, help_heading = morph::RUN)]
    threads: Option<usize>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Time the engine on the reference workload; prints one JSON line per configuration.
    ///
    /// Workload: a ball of radius 8 cells in a 32^3 grid, 2x2x2 particles per cell (about
    /// 17,000 particles), fixed-corotated material (lam 58333, mu 38888.9), density 40,
    /// drag 0.5, dt 1/120, f64, deforming under controls. Reports (a) forward steps and (b)
    /// forward + reverse steps, for each kernel and thread count, best of --repeats runs.
    Bench(bench::BenchArgs),
    /// Time mesh loading, voxelization and surface extraction; one JSON line per case.
    ///
    /// Every .obj/.ply in --meshes is placed alone in a domain of each --resolutions cells
    /// across and filled with 2x2x2 particles per cell; reports times, particle count and
    /// the particle volume in the mesh's own units. Then times surface extraction of
    /// particle balls of about 17k and 100k particles.
    BenchGeometry(bench::BenchGeometryArgs),
    /// Run the hard cases (docs/engine.md, "Hard cases"); one JSON line per case.
    ///
    /// Stiff materials, thin features, far-apart shapes, extreme units, topology changes,
    /// huge steps, long chains and horizons: each must stay finite, inside the grid, with
    /// 0 < J <= 3 and a bounded speed on every frame, or be refused with a one-line error.
    /// Then the gradient norm of one segment against its length (30 to 1000 steps). With
    /// --long, also a 300,000-particle morph within 4 GB. Exit 1 when a case fails.
    BenchHardCases(bench::BenchHardCasesArgs),
    /// Physical accuracy against a known answer: a free elastic bar's first axial period.
    ///
    /// The bar (1 m, E 1e5 Pa, nu 0.3, rho 1000, two cells thick) rings for two periods from
    /// its mode shape; one JSON line per grid spacing (8, 16, 32 cells along), time step (1/2,
    /// 1/4, 1/8 of the elastic bound), kernel and integrator with the period's error against
    /// 2 L / sqrt(E / rho) and the energy kept, then the observed orders of convergence.
    BenchAccuracy,
    /// Check a mesh before a run: topology, inside volume and particle count, as JSON.
    ///
    /// Loads MESH (OBJ or PLY) with the same validation as a morph, measures its inside
    /// (winding number > 1/2, so open meshes work) and fills it with particles as a source at
    /// --resolution. Warnings (open mesh, flipped faces, missing .mtl, a mesh that could not be
    /// a source) go to stderr.
    Inspect(inspect::InspectArgs),
    /// Compare two nodal mass grids (final_mass.mgrid); exit 0 if equal within tolerance.
    ///
    /// Equal means |a - b| <= atol + rtol * |b| at every node (b is the reference). Prints the
    /// node count, max and mean absolute difference as JSON, and the first node holding a
    /// non-finite value. Exit 0: equal; 1: different, incompatible grids (shape, origin,
    /// spacing) or a non-finite value; 2: unreadable file or bad option.
    Compare(compare::CompareArgs),
    /// The last frame's silhouettes and tips against the target, recomputed from a morph's
    /// written files, as JSON.
    ///
    /// The surface's last frame (the rebuilt one, or --surface carried) and the target mesh
    /// placed by the manifest's `target` map, seen along x, y and z (silhouette IoU), and the
    /// distance from the target's extremities (its 3% of vertices farthest along each axis
    /// direction) to the surface, 90th percentile, as a share of the target's size. Exit 0:
    /// printed; 1: an unreadable folder or file.
    Liken(liken::LikenArgs),
    /// Active damping of a swinging rope: uncontrolled vs MPPI vs gradient control (RK4 by
    /// default, or --integrator euler).
    ///
    /// A rope (fixed-corotated unless --material says otherwise) clamped at its top is released at rest, tilted from the
    /// vertical, under gravity; the controllers push its segments (default), push its tip, or
    /// move the clamp, to remove its kinetic energy. Prints a table and writes
    /// OUT/report.json, OUT/energy.png and OUT/frames/<method>/*.ply. Exit 0: ok; 1: the run
    /// failed; 2: bad option. Scene details: docs/control.md.
    Rope(Box<rope::RopeArgs>),
    /// Write the built-in meshes (sphere, torus, cube, two lobes) as OBJ into a folder.
    Assets(assets::AssetsArgs),
    /// What accuracy costs in time: morph SOURCE into TARGET once per configuration of a
    /// grid of settings, and record per configuration the wall and CPU seconds, peak memory,
    /// evaluations and the quality judge's verdict (fill, surface gap, ejected share, J).
    ///
    /// Writes DIR/study.json, DIR/study.csv and DIR/study.png (the judge's IoU with the target
    /// against wall seconds, with the Pareto front), after every configuration; run it again on the same DIR to continue
    /// an interrupted study. A configuration whose morph fails is recorded with its error and
    /// the study goes on. Exit 0: ok; 1: cannot write; 2: bad option or folder. Details:
    /// docs/accuracy.md.
    Study(study::StudyArgs),
    /// Write a render-farm job template that runs a morph: `morph farm-template openjd
    /// [--template FILE] SOURCE TARGET [morph options]`.
    ///
    /// Open Job Description (JSON): the resolved scene embedded (the same morph bit for bit),
    /// run with --resume (a re-queued task continues, never starts over) and --progress openjd;
    /// the output folder and the morph executable are job parameters. Exit 0: written; 2: bad
    /// option, or the file exists (pass --overwrite).
    FarmTemplate(farm::FarmTemplateArgs),
}

pub fn main() -> ExitCode {
    // A reader that stops early (`morph bench | head`) ends the process quietly, as for any
    // Unix tool, instead of a panic on the failed write.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of one signal before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let json = std::env::args_os().any(|a| a == "--json");
    let args = main_job_args(std::env::args_os().collect());
    if args.len() == 3 && args[1] == "help" && args[2] == "method" {
        say!("{}", ::morph::settings::knobs::help_text());
        return ExitCode::SUCCESS;
    }
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => return parse_error(e, json),
    };
    let mut threads = cli.threads;
    if let Some(t) = threads {
        let r = ::morph::settings::limits::THREADS;
        if !r.contains(&t) {
            return fail(
                json,
                2,
                &format!(
                    "--threads must be between {} and {}, got {t}",
                    r.start(),
                    r.end()
                ),
            );
        }
        // More workers than cores only wait on each other (1000 on 2 cores: 60x slower);
        // the results are the same for any count.
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        if t > cores {
            // The morph's --quiet holds every warning back, this one too.
            let quiet = cli.command.is_none() && cli.morph.quiet();
            if !quiet {
                eprintln!(
                    "morph: warning: --threads {t} is more than this machine's {cores} cores; using {cores}"
                );
            }
            threads = Some(cores);
        }
    }
    // The whole command runs on a worker of its own pool (0 threads: one per core). Parallel
    // loops started from a pool's worker run without handing every job across from an outside
    // thread, which measured about a quarter faster per step than running from `main`
    // against the global pool.
    let pool = match rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
    {
        Ok(pool) => pool,
        Err(e) => return fail(json, 1, &format!("cannot start worker threads: {e}")),
    };
    pool.install(|| dispatch(&cli))
}

/// The command line with the main job's knob options read as `--set` (a subcommand's
/// arguments are left as they are).
fn main_job_args(args: Vec<std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let mut rest = args.iter().skip(1);
    let first = loop {
        match rest.next().and_then(|a| a.to_str()) {
            Some("--threads") => {
                rest.next();
            }
            Some(a) if a.starts_with("--threads=") => {}
            other => break other,
        }
    };
    let subcommand =
        first.is_some_and(|a| a == "help" || <Command as clap::Subcommand>::has_subcommand(a));
    if subcommand {
        args
    } else {
        morph::knob_options_as_set(args)
    }
}

fn dispatch(cli: &Cli) -> ExitCode {
    match &cli.command {
        None => morph::run(&cli.morph),
        Some(Command::Bench(args)) => bench::run(args),
        Some(Command::BenchGeometry(args)) => bench::run_geometry(args),
        Some(Command::BenchHardCases(args)) => bench::run_hard_cases(args),
        Some(Command::BenchAccuracy) => report(::morph::apps::bench::physics::run()),
        Some(Command::Inspect(args)) => inspect::run(args),
        Some(Command::Compare(args)) => compare::run(args),
        Some(Command::Liken(args)) => liken::run(args),
        Some(Command::Rope(args)) => rope::run(args),
        Some(Command::Assets(args)) => assets::run(args),
        Some(Command::FarmTemplate(args)) => farm::run(args),
        Some(Command::Study(args)) => study::run(args),
    }
}

/// Prints a failure: one line `morph: error: ...` on stderr and, in `--json` mode, an `error`
/// event as the last line on stdout.
fn fail(json: bool, code: u8, message: &str) -> ExitCode {
    eprintln!("morph: error: {message}");
    if json {
        say!(
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

/// A value parser for one of the library's enums, offering its values by their serde names
/// (the library knows nothing of clap).
fn choice<T>(all: &[T]) -> impl clap::builder::TypedValueParser<Value = T>
where
    T: serde::Serialize + serde::de::DeserializeOwned + Clone + Send + Sync + 'static,
{
    use clap::builder::TypedValueParser;
    let names: Vec<String> = all.iter().map(name).collect();
    clap::builder::PossibleValuesParser::new(names).map(|s| {
        serde_json::from_value(serde_json::Value::String(s)).expect("one of the listed names")
    })
}

/// A value's name as the command line spells it: its serde name.
fn name<T: serde::Serialize>(value: &T) -> String {
    ::morph::settings::knobs::name_of(value)
}

/// The library's default settings.
fn defaults() -> MorphSettings {
    MorphSettings::preset(Preset::Default)
}

/// Prints the result of a subcommand that only fails at run time (exit 1).
fn report(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(false, 1, &format!("{e:#}")),
    }
}
