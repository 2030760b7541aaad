//! `morph bench` and `morph bench-geometry`: figures as JSON lines.

use super::fail;
use clap::Args;
use morph::engine::integrator::IntegratorKind;
use morph::engine::mpm::KernelKind;
use morph::gpu::{DeviceKind, Precision};
use morph::settings::limits;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: Option<BenchWhat>,
    #[command(flatten)]
    run: EngineRuns,
    /// Kernels to measure, comma separated.
    #[arg(long, value_delimiter = ',', value_parser = super::choice(&KernelKind::ALL),
          default_values = KernelKind::ALL.map(|k| super::name(&k)))]
    kernels: Vec<KernelKind>,
    /// Integrators to measure, comma separated (rk4 costs four evaluations a step).
    #[arg(long, value_delimiter = ',', value_parser = super::choice(&IntegratorKind::ALL),
          default_values = [super::name(&IntegratorKind::Euler)])]
    integrators: Vec<IntegratorKind>,
    /// Where the engine runs: the CPU, or the GPU (the Euler step in f64; the thread counts
    /// do not apply there).
    #[arg(long, value_parser = super::choice(&[DeviceKind::Cpu, DeviceKind::Gpu]),
          default_value = super::name(&DeviceKind::Cpu))]
    device: DeviceKind,
    /// The GPU device's precision (f64, or f32 for consumer GPUs).
    #[arg(long, value_parser = super::choice(&Precision::ALL),
          default_value = super::name(&Precision::F64))]
    precision: Precision,
}

/// What `morph bench` measures besides the engine.
#[derive(clap::Subcommand, Debug)]
pub enum BenchWhat {
    /// Whole morphs at fixed settings (sphere -> spot at the default preset, sphere ->
    /// stanford-bunny at final), every output written: one JSON line each with wall time,
    /// optimizer evaluations and the quality judge's IoU and fill. Minutes.
    Morph(BenchMorphArgs),
    /// Per-stage times of the Euler step and its reverse (cubic reference workload) at each
    /// thread count, this machine's bandwidth and peak, and each stage against its roofline
    /// bound: JSON lines on stdout, a markdown table on stderr.
    Stages(BenchStagesArgs),
}

/// How the engine benchmarks run the reference workload.
#[derive(Args, Debug)]
pub struct EngineRuns {
    /// Steps per run.
    #[arg(long, default_value_t = 30)]
    steps: usize,
    /// Runs per configuration: `morph bench` reports the fastest, `morph bench stages` the
    /// mean stage times (after one untimed run).
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Thread counts to measure, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2])]
    thread_counts: Vec<usize>,
    /// The ball's radius in cells: 8 is the reference workload (about 17,000 particles), 21
    /// about 310,000 (the grid grows with it; the effects' costs stay on the reference ball)
    /// [range 2-100].
    #[arg(long, default_value_t = morph::apps::bench::REFERENCE_RADIUS)]
    ball_radius: f64,
}

impl EngineRuns {
    /// The one-line refusal of a zero count.
    fn invalid(&self) -> Option<ExitCode> {
        if !(2.0..=100.0).contains(&self.ball_radius) {
            return Some(fail(
                false,
                2,
                &format!(
                    "--ball-radius must be 2 to 100 cells, got {}",
                    self.ball_radius
                ),
            ));
        }
        (self.steps == 0 || self.repeats == 0 || self.thread_counts.contains(&0)).then(|| {
            fail(
                false,
                2,
                "--steps, --repeats and --thread-counts must be positive",
            )
        })
    }
}

#[derive(Args, Debug)]
pub struct BenchStagesArgs {
    #[command(flatten)]
    run: EngineRuns,
}

#[derive(Args, Debug)]
pub struct BenchMorphArgs {
    /// Folder of the shared test meshes.
    #[arg(long, default_value = "../shared/meshes")]
    meshes: PathBuf,
    /// Only these cases, comma separated (spot-default, bunny-final).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
}

pub fn run(a: &BenchArgs) -> ExitCode {
    if let Some(BenchWhat::Morph(m)) = &a.what {
        let known: Vec<&str> = morph::apps::bench::morph::CASES
            .iter()
            .map(|c| c.name)
            .collect();
        if let Some(bad) = m.only.iter().find(|o| !known.contains(&o.as_str())) {
            return fail(
                false,
                2,
                &format!("--only: no case '{bad}' (the cases: {})", known.join(", ")),
            );
        }
        return super::report(morph::apps::bench::morph::run(&m.meshes, &m.only));
    }
    if let Some(BenchWhat::Stages(st)) = &a.what {
        let r = &st.run;
        if let Some(code) = r.invalid() {
            return code;
        }
        return super::report(morph::apps::bench::roofline::run(
            r.ball_radius,
            r.steps,
            r.repeats,
            &r.thread_counts,
        ));
    }
    let r = &a.run;
    if let Some(code) = r.invalid() {
        return code;
    }
    if a.device == DeviceKind::Gpu {
        if a.integrators != [IntegratorKind::Euler] {
            return fail(false, 2, "--device gpu runs the Euler integrator only");
        }
        return super::report(morph::apps::bench::run_on_device(
            r.ball_radius,
            r.steps,
            r.repeats,
            &a.kernels,
            a.precision,
        ));
    }
    if a.precision != Precision::F64 {
        return fail(
            false,
            2,
            "--precision f32 is the GPU device's: add --device gpu",
        );
    }
    super::report(morph::apps::bench::run(
        r.ball_radius,
        r.steps,
        r.repeats,
        &r.thread_counts,
        &a.kernels,
        &a.integrators,
    ))
}

#[derive(Args, Debug)]
pub struct BenchGeometryArgs {
    /// Folder of meshes.
    #[arg(long, default_value = "../shared/meshes")]
    meshes: PathBuf,
    /// Resolutions (cells across the domain), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [32usize, 64])]
    resolutions: Vec<usize>,
    /// Runs per case; the fastest is reported.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
}

pub fn run_geometry(a: &BenchGeometryArgs) -> ExitCode {
    if let Some(r) = a
        .resolutions
        .iter()
        .find(|r| !limits::RESOLUTION.contains(r))
    {
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
    if a.repeats == 0 {
        return fail(false, 2, "--repeats must be at least 1");
    }
    super::report(morph::apps::bench::geometry::run(
        &a.meshes,
        &a.resolutions,
        a.repeats,
    ))
}

#[derive(Args, Debug)]
pub struct BenchHardCasesArgs {
    /// Folder of the shared test meshes (the bunny).
    #[arg(long, default_value = "../shared/meshes")]
    meshes: PathBuf,
    /// Also the long cases (minutes each).
    #[arg(long)]
    long: bool,
}

pub fn run_hard_cases(a: &BenchHardCasesArgs) -> ExitCode {
    super::report(morph::apps::bench::hard_cases::run(&a.meshes, a.long))
}
