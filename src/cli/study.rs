//! `morph study SOURCE TARGET -o DIR`: a grid of settings, each morph judged and timed.

use super::{choice, fail};
use clap::Args;
use morph::Preset;
use morph::apps::study::{self, StudyError, StudyEvent, StudyGrid};
use morph::engine::integrator::IntegratorKind;
use morph::engine::mpm::KernelKind;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub struct StudyArgs {
    /// Source mesh (OBJ or PLY).
    source: PathBuf,
    /// Target mesh (OBJ or PLY).
    target: PathBuf,
    /// Study folder: new, empty, or an earlier study's (which continues, skipping what it
    /// measured).
    #[arg(short, long, default_value = "study")]
    output: PathBuf,
    /// A small grid for a first look (about a minute): resolutions 16,24,32, both kernels,
    /// 3 and 6 iterations, a 4-segment draft chain. Without it: particle budgets
    /// 5000,15000,50000,150000, both kernels, 6 and 12 iterations, reach weights 0 and 10, the
    /// default 12-segment chain (32 runs; a night on 2 cores).
    #[arg(long)]
    quick: bool,
    /// Preset the other settings start from (default: draft with --quick, else default).
    #[arg(long, value_parser = choice(&Preset::ALL))]
    preset: Option<Preset>,
    /// Resolutions to run, comma separated (with --particles: both are run).
    #[arg(long, value_delimiter = ',')]
    resolutions: Option<Vec<usize>>,
    /// Particle budgets to run, comma separated: each picks the resolution that gives the
    /// source about that many particles (as `morph --particles`).
    #[arg(long, value_delimiter = ',')]
    particles: Option<Vec<usize>>,
    /// Particles per cell axis to run, comma separated.
    #[arg(long, value_delimiter = ',')]
    particles_per_cell: Option<Vec<usize>>,
    /// Kernels to run, comma separated.
    #[arg(long, value_delimiter = ',', value_parser = choice(&KernelKind::ALL))]
    kernels: Option<Vec<KernelKind>>,
    /// Integrators to run, comma separated.
    #[arg(long, value_delimiter = ',', value_parser = choice(&IntegratorKind::ALL))]
    integrators: Option<Vec<IntegratorKind>>,
    /// Optimizer iterations per segment, comma separated.
    #[arg(long, value_delimiter = ',')]
    iterations: Option<Vec<usize>>,
    /// Passes, comma separated.
    #[arg(long, value_delimiter = ',')]
    passes: Option<Vec<usize>>,
    /// Segments, comma separated.
    #[arg(long, value_delimiter = ',')]
    segments: Option<Vec<usize>>,
    /// Weights of the reach cost to run, comma separated (as `morph --reach-weight`).
    #[arg(long, value_delimiter = ',')]
    reach_weights: Option<Vec<f64>>,
    /// Print one JSON object per configuration instead of a line of text.
    #[arg(long)]
    json: bool,
}

impl StudyArgs {
    fn grid(&self) -> StudyGrid {
        let mut g = if self.quick {
            StudyGrid::quick()
        } else {
            StudyGrid::full()
        };
        if let Some(p) = self.preset {
            g.preset = p;
        }
        let set = |dst: &mut Vec<usize>, v: &Option<Vec<usize>>| {
            if let Some(v) = v {
                *dst = v.clone();
            }
        };
        // The detail axis is what was asked for, resolutions and budgets together.
        if self.resolutions.is_some() || self.particles.is_some() {
            g.resolutions = self.resolutions.clone().unwrap_or_default();
            g.particles = self.particles.clone().unwrap_or_default();
        }
        set(&mut g.particles_per_cell, &self.particles_per_cell);
        set(&mut g.iterations, &self.iterations);
        set(&mut g.passes, &self.passes);
        set(&mut g.segments, &self.segments);
        if let Some(k) = &self.kernels {
            g.kernels = k.clone();
        }
        if let Some(i) = &self.integrators {
            g.integrators = i.clone();
        }
        if let Some(w) = &self.reach_weights {
            g.reach_weights = w.clone();
        }
        g
    }
}

pub fn run(args: &StudyArgs) -> ExitCode {
    let grid = args.grid();
    // Every configuration's settings are checked before the first one runs.
    if let Err(e) = grid.validate().and_then(|()| {
        grid.configs()
            .iter()
            .try_for_each(|c| c.settings().validate())
    }) {
        return fail(args.json, 2, &e);
    }
    let json = args.json;
    let result = study::run(
        &args.source,
        &args.target,
        &grid,
        &args.output,
        |e| match e {
            StudyEvent::Skipped { index, of, id } if !json => {
                println!("[{}/{of}] {id}: measured earlier, kept", index + 1)
            }
            StudyEvent::Running { index, of, id } if !json => {
                eprintln!("[{}/{of}] {id} ...", index + 1)
            }
            StudyEvent::Measured { row, .. } if json => {
                println!("{}", serde_json::to_string(row).expect("plain data"))
            }
            StudyEvent::Measured { index, of, row } if row.error.is_some() => println!(
                "[{}/{of}] {}: failed after {:.1} s: {}",
                index + 1,
                row.id,
                row.wall_s,
                row.error.as_deref().unwrap_or_default()
            ),
            StudyEvent::Measured { index, of, row } => {
                if let Some(q) = &row.quality {
                    let motion = row.motion.map_or(String::new(), |m| {
                        format!(
                            ", pulse {:.2}, settle {:.2}, ease error {}",
                            m.pulse,
                            m.settle,
                            m.ease_error.map_or("-".into(), |e| format!("{e:.2}"))
                        )
                    });
                    println!(
                        "[{}/{of}] {}: IoU {:.3}, fill {:.3} (material {:.3}), surface gap {:.2}, reach {:.2}/{:.2}{motion}, {} particles, {:.1} s wall, {} evaluations",
                        index + 1,
                        row.id,
                        q.iou,
                        q.fill,
                        q.material_fill,
                        q.surface_gap,
                        q.reach_p99,
                        q.reach_max,
                        row.particles,
                        row.wall_s,
                        row.evaluations
                    )
                }
            }
            _ => {}
        },
    );
    match result {
        Ok(rows) => {
            let front: Vec<&str> = rows
                .iter()
                .filter(|r| r.pareto)
                .map(|r| r.id.as_str())
                .collect();
            let failed = rows.iter().filter(|r| r.error.is_some()).count();
            if !json {
                println!(
                    "wrote {}: {} configurations{}; Pareto front (IoU against wall time): {}",
                    args.output.display(),
                    rows.len(),
                    if failed > 0 {
                        format!(" ({failed} failed: see the error column)")
                    } else {
                        String::new()
                    },
                    front.join(", ")
                );
            }
            ExitCode::SUCCESS
        }
        Err(e @ StudyError::Folder(_)) => fail(json, 2, &e.to_string()),
        Err(e) => fail(json, 1, &e.to_string()),
    }
}
