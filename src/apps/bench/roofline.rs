//! `morph bench stages`: where a step's time goes, and how far each stage is from what this
//! machine could do. Times every stage of the Euler step and its reverse pass on the
//! reference workload (cubic, f64) at each thread count, measures the machine's memory
//! bandwidth (a STREAM triad) and its floating-point peak as this build compiles (independent
//! multiply-add chains), and sets each stage against its roofline bound
//! `max(bytes / bandwidth, flops / peak)` from the bytes and flops one particle-step of it
//! needs ([`stage_costs`]).

use super::ball_workload;
use crate::engine::Engine;
use crate::engine::integrator::IntegratorKind;
use crate::engine::mpm::profile::{Stage, StageClock};
use crate::engine::mpm::{KernelKind, SimError};
use nalgebra::Vector3;
use rayon::prelude::*;
use serde_json::json;
use std::sync::Arc;
use std::time::Instant;

/// Work one particle-step of a stage needs: floating-point operations (a division or square
/// root counts one) and the compulsory memory traffic in bytes (every array the stage reads or
/// writes, once; nodal arrays charged per particle through the nodes-per-particle ratio).
#[derive(Clone, Copy, Debug)]
pub struct StageCost {
    pub stage: Stage,
    pub flops: f64,
    pub bytes: f64,
}

/// Flops of one 3x3 SVD (`material/svd.rs`): `F^T F` 45, about 9 Jacobi rotations of about 40
/// each near F = I, `F V` 45 and three Givens rotations of about 30.
const SVD_FLOPS: f64 = 540.0;
/// Flops of an SVD from the eigen-decomposition the forward pass kept: `F V` 45, sorting and
/// three Givens rotations.
const SVD_FROM_KEPT_FLOPS: f64 = 145.0;
/// Flops of the stencil weights of one particle (cubic): per axis 4 weights, 4 derivatives,
/// 4 offsets.
const STENCIL_FLOPS: f64 = 105.0;

/// Per particle-step costs of each stage, counted from the code for the cubic kernel (64
/// nodes a stencil) without controls, on a grid with `nodes_per_particle` nodes per
/// particle. Counts are within about 20%: they set the scale of the bound, not its digits.
pub fn stage_costs(nodes_per_particle: f64) -> Vec<StageCost> {
    let npp = nodes_per_particle;
    let c = |stage, flops, bytes| StageCost {
        stage,
        flops,
        bytes,
    };
    vec![
        // Reads x (24), writes and re-reads the block of each particle (12), writes the order (4).
        c(Stage::Bins, 12.0, 40.0),
        // Reads F, C (72 each), mass and volume; writes Fe and A (72 each) and, taped, the
        // eigen-decomposition behind the SVD (96). SVD, R = U V^T (45), cofactor and J (32),
        // P (36), A = m C + k P Fe^T (72).
        c(Stage::Stress, SVD_FLOPS + 185.0, 400.0),
        // Reads x, v, A, m (128); zeroes and writes the nodes (2 x 32 a node). Per node 15
        // flops (weight, mass, affine momentum), per row and column 6-7.
        c(
            Stage::P2g,
            STENCIL_FLOPS + 64.0 * 15.0 + 136.0,
            128.0 + 64.0 * npp,
        ),
        // Per node: read mass and momentum (32), write v (24), copy the mass (16); 4 flops.
        c(Stage::Grid, 4.0 * npp, 72.0 * npp),
        // Copies x, v, C, F (192), the order (4), A (72): read and write; the grid mass and
        // velocity (32 a node), read and write.
        c(Stage::Tape, 0.0, 2.0 * 268.0 + 64.0 * npp),
        // Reads x, Fe (96) and v on the nodes (24 a node); writes x, v, C, F (192). Per node
        // 12 flops, per row 20, then F' = (I + dt C) Fe (63).
        c(
            Stage::G2p,
            STENCIL_FLOPS + 64.0 * 12.0 + 16.0 * 20.0 + 52.0 + 78.0,
            288.0 + 24.0 * npp,
        ),
        // Fe from F (144); the grid velocity copied (48 a node).
        c(Stage::RevSetup, 0.0, 144.0 + 48.0 * npp),
        // Reads Fe, C', the four state adjoints, x, v' (480 with the writes of dFe and dx);
        // zeroes and scatters the velocity adjoint (48 a node), reads v (24 a node). P2
        // reverse 132 flops; per node 22, per row 13, per plane 12 (sums taken axis by axis).
        c(
            Stage::RevG2p,
            132.0 + STENCIL_FLOPS + 64.0 * 22.0 + 16.0 * 13.0 + 66.0,
            480.0 + 72.0 * npp,
        ),
        // Per node: mass, v, dv read (56), node adjoint written (32); 10 flops.
        c(Stage::RevGrid, 10.0 * npp, 88.0 * npp),
        // Reads x, v, m, A, Fe, dFe, dx (320 with dx written) and the kept eigen-decomposition
        // (96); writes dv, dC, dF, dFc (240); reads the node adjoints (32 a node). Per node 29
        // flops, per row 31, per plane 30; then the SVD finished from what was kept, the
        // stress differential (about 420) and the affine reverse (126).
        c(
            Stage::RevP2gStress,
            STENCIL_FLOPS
                + 64.0 * 29.0
                + 16.0 * 31.0
                + 4.0 * 30.0
                + SVD_FROM_KEPT_FLOPS
                + 420.0
                + 126.0,
            656.0 + 32.0 * npp,
        ),
    ]
}

/// This machine's limits on `threads` threads: STREAM-triad bandwidth (bytes/s) and the
/// multiply-add peak as this build compiles (flops/s), each the best of `repeats`.
pub fn machine_limits(threads: usize, repeats: usize) -> (f64, f64) {
    const N: usize = 1 << 23; // 64 MB an array: far beyond the caches
    let mut a = vec![0.0f64; N];
    let b = vec![1.0f64; N];
    let c = vec![2.0f64; N];
    let mut bandwidth: f64 = 0.0;
    // The first pass is not timed: it pays for mapping the output array's pages.
    for pass in 0..=repeats.max(1) {
        let t0 = Instant::now();
        a.par_chunks_mut(1 << 14)
            .zip(b.par_chunks(1 << 14).zip(c.par_chunks(1 << 14)))
            .with_min_len(N / (1 << 14) / threads.max(1) / 4)
            .for_each(|(a, (b, c))| {
                for ((a, b), c) in a.iter_mut().zip(b).zip(c) {
                    *a = b + 3.0 * c;
                }
            });
        std::hint::black_box(&a);
        if pass > 0 {
            bandwidth = bandwidth.max(24.0 * N as f64 / t0.elapsed().as_secs_f64());
        }
    }
    // 32 independent chains of `acc = acc * m + a` per thread: 2 flops each.
    const ITERS: usize = 4_000_000;
    let chains = |seed: f64| {
        let (m, add) = (
            std::hint::black_box(0.999_999_9),
            std::hint::black_box(1e-9),
        );
        let mut acc = [seed; 32];
        for _ in 0..ITERS {
            for x in acc.iter_mut() {
                *x = *x * m + add;
            }
        }
        acc.iter().sum::<f64>()
    };
    let mut peak: f64 = 0.0;
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let s: f64 = (0..threads.max(1))
            .into_par_iter()
            .map(|t| chains(1.0 + t as f64))
            .sum();
        std::hint::black_box(s);
        let flops = (threads.max(1) * ITERS * 32 * 2) as f64;
        peak = peak.max(flops / t0.elapsed().as_secs_f64());
    }
    (bandwidth, peak)
}

/// Seconds per step of each stage, in [`Stage::ALL`] order.
type StageTimes = Vec<(Stage, f64)>;

/// One thread count's measurements: threads, bandwidth (bytes/s), peak (flops/s), stages.
struct Measured {
    threads: usize,
    bandwidth: f64,
    peak: f64,
    stages: StageTimes,
}

/// Seconds per step of each stage over `repeats` forward + reverse runs of `steps` steps on
/// the current thread pool (after one untimed run).
fn stage_seconds(
    radius: f64,
    steps: usize,
    repeats: usize,
) -> Result<(usize, usize, StageTimes), SimError> {
    let mut w = ball_workload(radius, KernelKind::Cubic, IntegratorKind::Euler, steps)?;
    let clock = Arc::new(StageClock::default());
    let Engine::Euler(sim) = &mut w.engine else {
        unreachable!("the Euler workload")
    };
    sim.clock = Some(clock.clone());
    let (particles, nodes) = (sim.num_particles(), sim.grid.node_count());
    std::hint::black_box(w.run_forward_reverse(steps)?);
    clock.reset();
    for _ in 0..repeats.max(1) {
        std::hint::black_box(w.run_forward_reverse(steps)?);
    }
    let per_step = (steps * repeats.max(1)) as f64;
    let secs = clock
        .seconds()
        .into_iter()
        .map(|(s, t)| (s, t / per_step))
        .collect();
    Ok((particles, nodes, secs))
}

/// The share of `threads` threads a scatter's tile phase over `bins` keeps busy: the
/// particles over `threads`, against the longest thread's load when the blocks are shared
/// out largest first to the least loaded thread (rayon's work stealing does about as well; a
/// block is never split). 1 on one thread.
pub fn scatter_efficiency(bins: &crate::engine::mpm::grid::Bins, threads: usize) -> f64 {
    let mut sizes: Vec<usize> = bins.blocks.iter().map(|b| b.particle_count()).collect();
    sizes.sort_unstable_by(|a, b| b.cmp(a));
    let mut load = vec![0usize; threads.max(1)];
    for size in sizes {
        let least = load.iter_mut().min().expect("at least one thread");
        *least += size;
    }
    let span = load.into_iter().max().unwrap_or(0);
    let particles = bins.order.len();
    if span == 0 {
        1.0
    } else {
        particles as f64 / threads.max(1) as f64 / span as f64
    }
}

/// Runs the stage timings and roofline at each thread count on a ball of `radius` cells
/// ([`super::REFERENCE_RADIUS`] is the reference): JSON lines on stdout, a markdown table on
/// stderr.
pub fn run(radius: f64, steps: usize, repeats: usize, threads: &[usize]) -> anyhow::Result<()> {
    // The parallelism the scatters offer: non-empty 4^3-cell blocks (each a task of the
    // tile phase), and how well they can share out among more threads than this machine has
    // (the model's input for a larger machine, docs/engine.md): the reference ball and a
    // ball of about 300,000 particles.
    for ball in [super::REFERENCE_RADIUS, 21.0] {
        let grid = super::ball_grid(ball);
        let (x, _) = crate::engine::scene::ball_particles(&grid, Vector3::zeros(), ball, 2);
        let bins = crate::engine::mpm::grid::Bins::build(&grid, &x, 4, 0)?;
        let blocks = bins.blocks.len();
        let efficiency: serde_json::Map<String, serde_json::Value> = [1, 2, 4, 8, 16, 32]
            .iter()
            .map(|&t| (t.to_string(), json!(scatter_efficiency(&bins, t))))
            .collect();
        println!(
            "{}",
            json!({"bench": "blocks", "particles": x.len(), "blocks": blocks,
                   "scatter_efficiency_by_threads": efficiency})
        );
    }
    let mut table: Vec<Measured> = Vec::new();
    let mut sizes = (0, 0);
    for &t in threads {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build()?;
        let (bandwidth, peak) = pool.install(|| machine_limits(t, repeats));
        println!(
            "{}",
            json!({"bench": "machine", "threads": t, "stream_triad_gb_s": bandwidth * 1e-9,
                   "peak_gflops": peak * 1e-9})
        );
        let (particles, nodes, secs) = pool.install(|| stage_seconds(radius, steps, repeats))?;
        sizes = (particles, nodes);
        let costs = stage_costs(nodes as f64 / particles as f64);
        for ((stage, s), cost) in secs.iter().zip(&costs) {
            let n = particles as f64;
            let bound = (cost.bytes * n / bandwidth).max(cost.flops * n / peak);
            println!(
                "{}",
                json!({
                    "bench": "stage", "stage": stage.name(), "threads": t, "kernel": "cubic",
                    "particles": particles, "ms_per_step": s * 1e3,
                    "flops_per_particle_step": cost.flops, "bytes_per_particle_step": cost.bytes,
                    "gflops": cost.flops * n / s * 1e-9, "gb_s": cost.bytes * n / s * 1e-9,
                    "roofline_ms": bound * 1e3, "of_roofline": bound / s,
                    "limit": if cost.bytes * n / bandwidth >= cost.flops * n / peak { "memory" } else { "compute" },
                })
            );
        }
        table.push(Measured {
            threads: t,
            bandwidth,
            peak,
            stages: secs,
        });
    }
    // The human-readable table: every thread count side by side.
    let (particles, nodes) = sizes;
    let costs = stage_costs(nodes as f64 / particles as f64);
    let n = particles as f64;
    let mut out = String::new();
    let head: Vec<String> = table
        .iter()
        .map(|m| format!("ms ({} thr)", m.threads))
        .collect();
    out += &format!(
        "| stage | flops/p | bytes/p | {} | bound ms ({} thr) | of bound |\n",
        head.join(" | "),
        table.last().map_or(1, |m| m.threads)
    );
    out += &format!("|{}\n", "---|".repeat(5 + table.len()));
    let mut totals = vec![0.0; table.len()];
    let mut total_bound = 0.0;
    for (k, cost) in costs.iter().enumerate() {
        let times: Vec<String> = table
            .iter()
            .enumerate()
            .map(|(i, m)| {
                totals[i] += m.stages[k].1;
                format!("{:.2}", m.stages[k].1 * 1e3)
            })
            .collect();
        let last = table.last().expect("a thread count");
        let bound = (cost.bytes * n / last.bandwidth).max(cost.flops * n / last.peak);
        total_bound += bound;
        out += &format!(
            "| {} | {:.0} | {:.0} | {} | {:.3} | {:.0}% |\n",
            cost.stage.name(),
            cost.flops,
            cost.bytes,
            times.join(" | "),
            bound * 1e3,
            100.0 * bound / last.stages[k].1
        );
    }
    let totals: Vec<String> = totals.iter().map(|s| format!("{:.2}", s * 1e3)).collect();
    out += &format!(
        "| all | | | {} | {:.3} | |\n",
        totals.join(" | "),
        total_bound * 1e3
    );
    eprint!("{out}");
    Ok(())
}
