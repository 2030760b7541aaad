//! The `morph` command line.

use clap::{Parser, Subcommand};
use morph::mpm::KernelKind;
use std::process::ExitCode;

/// morph - turn one 3D shape into another with a differentiable Material Point Method.
#[derive(Parser, Debug)]
#[command(name = "morph", version, about, long_about = None)]
struct Cli {
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
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
        Command::Bench {
            steps,
            repeats,
            thread_counts,
            kernels,
        } => {
            if steps == 0 || thread_counts.contains(&0) {
                eprintln!("morph: error: --steps and --thread-counts must be positive");
                return ExitCode::from(2);
            }
            morph::bench::run(steps, repeats, &thread_counts, &kernels)
        }
        Command::BenchGeometry {
            meshes,
            resolutions,
            repeats,
        } => morph::bench::geometry::run(&meshes, &resolutions, repeats),
        Command::Inspect { mesh, resolution } => morph::geometry::inspect(&mesh, resolution)
            .map_err(anyhow::Error::from)
            .and_then(|report| {
                for w in &report.warnings {
                    eprintln!("morph: warning: {w}");
                }
                println!("{}", serde_json::to_string_pretty(&report)?);
                Ok(())
            }),
        Command::Assets { output } => morph::geometry::assets::write_builtin(&output)
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
