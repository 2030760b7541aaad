//! How much memory a morph may use, and how its segments' tapes fit in it.
//!
//! The tape of a segment's rollout is what grows with steps x particles; everything else (the
//! model, the loss grids, the controls of every segment, the optimizer's moments, a few
//! states) is fixed by the particle and node counts. A [`MemoryLimit`] caps the whole
//! process: what is left after the fixed part is the tape budget, and the segment keeps
//! checkpoints and recomputes instead of holding every step when its tape would not fit
//! ([`crate::engine::integrator::recompute`]). The budget never changes results, only memory and time.
//!
//! The plan is computed from the inputs and settings alone ([`fixed_bytes`]: counts times
//! bytes per particle and per node), never from the process's resident size, so the same
//! command is accepted or refused the same way on every run. It is checked twice: before
//! setup, on counts estimated from the shapes' volumes ([`check_before_setup`]: a limit too
//! small is refused before the fill allocates anything sized by the resolution), and after
//! setup on the exact counts. A limit above the machine's memory (or the container's, from
//! its cgroup) is refused.

use super::{MorphError, MorphSettings, Prepared};
use crate::engine::integrator::recompute::ChunkPlan;
use crate::engine::mpm::State;
use nalgebra::Matrix3;
use serde::Serialize;
use std::str::FromStr;

/// Frames the writer thread may hold queued before the optimizer waits for it (the plan
/// counts them; `output/writer.rs` sizes its channel with it).
pub const WRITE_QUEUE: usize = 4;

/// A cap on the process's peak memory.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MemoryLimit {
    /// A quarter of the machine's physical memory (farm nodes run several jobs), or
    /// [`FALLBACK_AUTO_BYTES`] where it cannot be read.
    #[default]
    Auto,
    Bytes(u64),
}

/// Memory the allocator holds beyond the tapes it was asked for, as a share of them: tapes
/// of tens of megabytes a step, freed and recomputed chunk after chunk, fragment the heap
/// (measured: 9% of the planned tape at 321,189 particles with glibc's allocator).
pub const ALLOCATOR_SLACK: f64 = 0.10;

/// The automatic limit where the machine's memory cannot be read.
pub const FALLBACK_AUTO_BYTES: u64 = 2 << 30;

/// The process before any morph data: code, libraries, worker stacks, the allocator's own
/// (measured: 12 MB resident after setting up an 1,088-particle morph; kept with margin).
pub const BASELINE_BYTES: u64 = 20 << 20;
/// Bytes per source particle besides the tapes and the working set: the initial state, its
/// mass and volume, the placed positions (measured: 190 bytes a particle over source and
/// target together at 348,424 particles each).
pub const SOURCE_PARTICLE_BYTES: u64 = 256;
/// Bytes per target particle: positions, while the target's masses are made.
pub const TARGET_PARTICLE_BYTES: u64 = 32;
/// Bytes per simulation grid node: the loss's target masses, the step's grid (mass,
/// momentum, velocity) and its adjoint in the reverse pass; 8 more per keyframe target.
pub const NODE_BYTES: u64 = 128;
/// Bytes per particle of one frame on its way to disk (its world copy and its state, for
/// the surfaces); the writer holds [`WRITE_QUEUE`] queued, one being
/// written and one being made.
pub const FRAME_PARTICLE_BYTES: u64 = 256;
/// Bytes per node of the finer loss grid: its target, the rollout's masses and adjoint; 8
/// more per keyframe target.
pub const FINE_NODE_BYTES: u64 = 24;

impl FromStr for MemoryLimit {
    type Err = String;

    /// `auto`, or a size: a number with an optional unit `K`, `M`, `G` or `T` (powers of
    /// 1024; `KB`, `MiB`... read the same), e.g. `150M`, `1.5G`, `4000000000`.
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("auto") {
            return Ok(MemoryLimit::Auto);
        }
        let split = t
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(t.len());
        let (number, unit) = t.split_at(split);
        let scale: u64 = match unit.trim().to_ascii_uppercase().as_str() {
            "" | "B" => 1,
            "K" | "KB" | "KIB" => 1 << 10,
            "M" | "MB" | "MIB" => 1 << 20,
            "G" | "GB" | "GIB" => 1 << 30,
            "T" | "TB" | "TIB" => 1 << 40,
            _ => return Err(format!("'{s}' is not a size: use e.g. 150M, 4G or auto")),
        };
        match number.parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 => Ok(MemoryLimit::Bytes((v * scale as f64) as u64)),
            _ => Err(format!("'{s}' is not a size: use e.g. 150M, 4G or auto")),
        }
    }
}

impl MemoryLimit {
    /// The limit in bytes: a quarter of the memory this process may use for `Auto`.
    pub fn bytes(self) -> u64 {
        match self {
            MemoryLimit::Bytes(b) => b,
            MemoryLimit::Auto => available_memory().map_or(FALLBACK_AUTO_BYTES, |m| m / 4),
        }
    }

    /// The limit, refused when it is more than the memory this process may use at all.
    pub fn checked_bytes(self) -> Result<u64, String> {
        let b = self.bytes();
        match available_memory() {
            Some(m) if b > m => Err(format!(
                "--memory-limit {} is more than the {} this machine (or its container) has; give at most {}, or auto",
                show_bytes(b),
                show_bytes(m),
                show_bytes(m)
            )),
            _ => Ok(b),
        }
    }
}

/// The memory this process may use: the machine's, or its container's where a cgroup
/// limits it to less.
pub fn available_memory() -> Option<u64> {
    let machine = physical_memory();
    let cgroup = cgroup_limit();
    match (machine, cgroup) {
        (Some(m), Some(c)) => Some(m.min(c)),
        (m, c) => m.or(c),
    }
}

/// The memory limit of this process's cgroup, when there is one: [`cgroup_limit_in`] on
/// this machine's `/sys/fs/cgroup` and `/proc/self/cgroup`.
pub fn cgroup_limit() -> Option<u64> {
    let own = crate::files::read_to_string(
        std::path::Path::new("/proc/self/cgroup"),
        crate::files::SMALL_FILE_BYTES,
    )
    .ok()?;
    cgroup_limit_in(std::path::Path::new("/sys/fs/cgroup"), &own)
}

/// The memory limit a process lives under, from the text of its `/proc/self/cgroup` and the
/// cgroup file system mounted at `root`: the smallest limit on the way from its own group up
/// to the root, as the kernel enforces every one of them (a farm slot's limit is often set on
/// a parent of the job's own group). Cgroup v2 (`0::/path`: `memory.max`, `max` for none) and
/// v1 (`N:memory:/path` or with `memory` among several controllers:
/// `memory/path/memory.limit_in_bytes`, a number near 2^63 for none) are both read; a group
/// whose file is missing (a container that shows the host's path) is passed over.
pub fn cgroup_limit_in(root: &std::path::Path, proc_self_cgroup: &str) -> Option<u64> {
    let read = |p: &std::path::Path| -> Option<u64> {
        let text = crate::files::read_to_string(p, crate::files::SMALL_FILE_BYTES).ok()?;
        let v: u64 = text.trim().parse().ok()?; // `max` does not parse: no limit
        (v < 1 << 60).then_some(v)
    };
    // Every group from `path` up to the root of `mount`, each with its limit file.
    let chain = |mount: std::path::PathBuf, path: &str, file: &str| -> Vec<std::path::PathBuf> {
        let mut dir = mount.join(path.trim_start_matches('/'));
        let mut files = vec![dir.join(file)];
        while dir != mount && dir.pop() {
            files.push(dir.join(file));
        }
        files
    };
    let mut files = Vec::new();
    for line in proc_self_cgroup.lines() {
        let mut parts = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(path)) = (parts.next(), parts.next(), parts.next())
        else {
            continue;
        };
        if controllers.is_empty() {
            files.extend(chain(root.to_path_buf(), path, "memory.max"));
        } else if controllers.split(',').any(|c| c == "memory") {
            files.extend(chain(root.join("memory"), path, "memory.limit_in_bytes"));
        }
    }
    files.iter().filter_map(|f| read(f)).min()
}

/// Bytes of everything but the tapes for a morph of `particles` source particles,
/// `targets` target particles (all targets), `nodes` grid nodes and `keyframes` targets
/// before the last, under `settings`, with a segment's path targets when its path weight is
/// on (see the constants above and `working_bytes`).
pub fn fixed_bytes(
    settings: &MorphSettings,
    particles: u64,
    targets: u64,
    nodes: u64,
    keyframes: u64,
) -> u64 {
    let fine_nodes = if settings.method.fine_weight > 0.0 {
        nodes * (super::FINE_REFINE as u64).pow(3)
    } else {
        0
    };
    // A segment's path points (one target per frame inside it) and a look-ahead window's
    // (its segments' frames, and a target at each segment end but the last, plus the
    // window's own, with its fine target beside the segment's), over the longest window.
    let window = settings.method.lookahead as u64 + 1;
    let path_points = if settings.method.path_weight > 0.0 {
        let longest = settings
            .timing()
            .segment_steps
            .into_iter()
            .max()
            .unwrap_or(0);
        window * (longest / settings.shot.frame_every.max(1)) as u64
    } else {
        0
    } + 2 * (window - 1);
    BASELINE_BYTES
        + particles * SOURCE_PARTICLE_BYTES
        + targets * TARGET_PARTICLE_BYTES
        + nodes * (NODE_BYTES + 8 * keyframes + 8 * path_points)
        + fine_nodes * (FINE_NODE_BYTES + 8 * keyframes + 8 * (window - 1).min(1))
        + working_bytes(settings, particles as usize)
        + (WRITE_QUEUE as u64 + 2) * particles * FRAME_PARTICLE_BYTES
        + coarse_level_bytes(settings, particles, targets, nodes, keyframes)
}

/// Bytes a coarser level keeps while the finer one runs (`settings.method.levels > 1`): its own
/// setup, the controls it found for every segment, and the map carrying them up (a
/// quadratic B-spline stencil of coarse particles per fine particle). A level has an eighth
/// of the particles and nodes of the one above.
fn coarse_level_bytes(
    settings: &MorphSettings,
    particles: u64,
    targets: u64,
    nodes: u64,
    keyframes: u64,
) -> u64 {
    if settings.method.levels <= 1 {
        return 0;
    }
    let mut below = settings.clone();
    below.method.levels -= 1;
    below.method.passes = 1;
    let (n, t, g) = (
        particles.div_ceil(8),
        targets.div_ceil(8),
        nodes.div_ceil(8),
    );
    let layers: u64 = segment_layers(settings).map(|l| l as u64).sum();
    let prolongation = particles * 27 * 16;
    fixed_bytes(&below, n, t, g, keyframes)
        + layers * n * size_of::<Matrix3<f64>>() as u64
        + prolongation
}

/// The control layers of each segment of the shot `s` makes.
fn segment_layers(s: &MorphSettings) -> impl Iterator<Item = usize> {
    let stride = s.method.control_stride.max(1);
    s.timing()
        .segment_steps
        .into_iter()
        .map(move |k| k.div_ceil(stride))
}

/// Estimated bytes the run needs besides the tapes and the setup: the controls of the
/// passes before the last (kept for the next) and the optimizer's copies of one segment's,
/// Adam's moments and saved values, and the states a segment holds at once (start, the one
/// advancing, last, best, adjoints, the reverse step's scratch).
fn working_bytes(s: &MorphSettings, n: usize) -> u64 {
    let layers = segment_layers(s).max().unwrap_or(0);
    let layer = n * size_of::<Matrix3<f64>>();
    let kept = if s.method.passes > 1 {
        s.method.segments
    } else {
        0
    };
    let controls = (kept + 6) * layers * layer;
    let free = layers * 9 * n;
    let adam = 5 * free * size_of::<f64>();
    (controls + adam + 6 * State::bytes_for(n)) as u64
}

/// What a morph's memory is sized by: its counts (exact after setup, estimated from the
/// shapes' volumes before), its grid's spacing, its carried surface and its frames.
#[derive(Clone, Copy, Debug)]
pub struct Counts {
    pub particles: u64,
    /// Particles of every target together.
    pub targets: u64,
    pub nodes: u64,
    pub keyframes: u64,
    /// The grid's spacing (simulation units): with the material it sets the substeps.
    pub dx: f64,
    pub source_vertices: u64,
    pub frames: u64,
}

/// The least memory a morph needs, in bytes: to run (the fixed part and the tape under the
/// chunks of the smallest peak: what
/// [`Prepared::plan_memory`] refuses below) and to write its USD file, which is built once
/// every frame is on disk, from all of them at once, beside the fixed part (the tapes are gone
/// by then). The same formula before setup, on estimated counts, and after, on exact ones, so
/// a refusal gives one figure for one morph.
pub fn least_bytes(settings: &MorphSettings, c: &Counts) -> (u64, u64) {
    let n = c.particles as usize;
    let material = settings.body.material.build();
    let shot = settings.timing();
    let substeps = match settings.method.dt {
        Some(_) => 1,
        None => {
            let (bound, _) = crate::engine::material::stable_dt(
                material.wave_modulus(),
                settings.body.material.density,
                c.dx,
            );
            super::substeps_for(shot.step, 0.5 * bound).unwrap_or(1)
        }
    };
    let window = settings.method.lookahead + 1;
    let steps = (0..shot.segment_steps.len())
        .map(|k| {
            shot.segment_steps[k..(k + window).min(shot.segment_steps.len())]
                .iter()
                .sum::<usize>()
        })
        .max()
        .unwrap_or(0)
        * substeps;
    let gradient = n * size_of::<Matrix3<f64>>();
    let step = gradient
        + match settings.method.integrator {
            crate::engine::integrator::IntegratorKind::Euler => {
                crate::engine::mpm::StepTape::bytes_for(
                    n,
                    c.nodes as usize,
                    material.kept_per_particle(),
                )
            }
            crate::engine::integrator::IntegratorKind::Rk4 => {
                n * (4 * State::ODE_BYTES_PER_PARTICLE + size_of::<Matrix3<f64>>())
            }
        };
    let fixed = fixed_bytes(settings, c.particles, c.targets, c.nodes, c.keyframes)
        + (settings.method.control_stride * substeps * gradient) as u64;
    // The chunks with the smallest peak (what the plan takes when nothing fits).
    let least = ChunkPlan::within(
        0,
        steps,
        step,
        State::bytes_for(n),
        settings.method.control_stride * substeps,
    );
    let tape = least.peak_bytes(
        steps,
        step,
        State::bytes_for(n),
        settings.method.control_stride * substeps,
    ) as f64;
    let run = fixed + (tape * (1.0 + ALLOCATOR_SLACK)) as u64;
    let usd = usd_bytes(settings, c.particles, c.frames, c.source_vertices);
    let writers = fixed + (usd as f64 * (1.0 + USD_WRITER_SHARE) * (1.0 + ALLOCATOR_SLACK)) as u64;
    (run, if usd > 0 { writers } else { 0 })
}

/// Refuses `limit` when it is below what the morph needs at least ([`least_bytes`] on
/// `counts`), with one figure: the larger need, and what to change. `before_setup`: the
/// counts are estimates (the check that keeps setup itself within the limit).
pub fn check_least(
    settings: &MorphSettings,
    counts: &Counts,
    limit: MemoryLimit,
) -> Result<(), MorphError> {
    let limit_bytes = limit.checked_bytes().map_err(MorphError::Settings)?;
    let (run, writers) = least_bytes(settings, counts);
    let need = run.max(writers);
    if need <= limit_bytes {
        return Ok(());
    }
    let shown = show_bytes(need.div_ceil(1 << 20) * (1 << 20));
    let n = counts.particles;
    Err(MorphError::Settings(if writers > run {
        format!(
            "--memory-limit {} is below the {shown} this morph needs at least (about {n} particles; most of it its USD file, {} frames held at once while it is written); raise it, write fewer frames, or pass --usd none",
            show_bytes(limit_bytes),
            counts.frames
        )
    } else {
        format!(
            "--memory-limit {} is below the {shown} this morph needs at least (about {n} particles); raise it, or lower --resolution or --particles",
            show_bytes(limit_bytes)
        )
    }))
}

/// Refuses `limit` before setup when the morph, on counts estimated from the shapes' volumes
/// ([`crate::geometry::MorphGeometry::estimate`]) at `resolution`, would not fit in it: setup
/// itself then never allocates past the limit, and the figure is the whole run's.
pub fn check_before_setup(
    settings: &MorphSettings,
    estimate: &crate::geometry::SizeEstimate,
    (keyframes, source_vertices): (usize, usize),
    limit: MemoryLimit,
) -> Result<(), MorphError> {
    let counts = Counts {
        particles: estimate.source_particles.ceil() as u64,
        targets: estimate.target_particles.ceil() as u64,
        nodes: estimate.nodes as u64,
        keyframes: keyframes as u64,
        dx: estimate.dx,
        source_vertices: source_vertices as u64,
        frames: settings.timing().frame_count() as u64,
    };
    check_least(settings, &counts, limit)
}

/// How a morph's memory is planned (written to the manifest).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct MemoryPlan {
    /// The cap, in bytes.
    pub limit: u64,
    /// Estimated bytes of everything but the tapes.
    pub fixed: u64,
    /// Bytes the tape of one rollout may hold.
    pub tape_budget: u64,
    /// Steps per recomputed chunk (`null`: the whole tape is kept, nothing recomputed).
    pub chunk_steps: Option<usize>,
    /// Estimated peak bytes of the tapes under this plan.
    pub tape_peak: u64,
    /// Bytes one step's tape holds.
    pub step_tape_bytes: u64,
}

impl Prepared {
    /// Plans the tapes of this morph within `limit` and sets [`Prepared::tape_budget`]. A
    /// limit below what the morph needs with one-step chunks is an error that says how much
    /// it needs.
    pub fn plan_memory(&mut self, limit: MemoryLimit) -> Result<MemoryPlan, MorphError> {
        let n = self.initial.len();
        let state = State::bytes_for(n);
        let step = crate::morph::prepare::sim::with_sim!(&self.engine, sim => super::segment::step_bytes(sim, n));
        let steps = self.max_sim_segment_steps();
        let fixed = fixed_bytes(
            &self.settings,
            n as u64,
            (self.geometry.target.positions.len()
                + self
                    .geometry
                    .keyframes
                    .iter()
                    .map(|k| k.particles.positions.len())
                    .sum::<usize>()) as u64,
            self.model().grid.node_count() as u64,
            self.geometry.keyframes.len() as u64,
        );
        // The reverse pass gathers one control layer's step gradients at a time.
        let fixed = fixed + (self.sim_control_stride() * n * size_of::<Matrix3<f64>>()) as u64;
        let limit_bytes = limit.checked_bytes().map_err(MorphError::Settings)?;
        let tape_budget =
            (limit_bytes.saturating_sub(fixed) as f64 / (1.0 + ALLOCATOR_SLACK)) as usize;
        let stride = self.sim_control_stride();
        let plan = self.chunk_plan_within(tape_budget);
        let peak = plan.peak_bytes(steps, step, state, stride);
        if peak > tape_budget {
            let need = fixed as f64 + peak as f64 * (1.0 + ALLOCATOR_SLACK);
            return Err(MorphError::Settings(format!(
                "--memory-limit {} is below the {} this morph needs at least ({n} particles); raise it, or lower --resolution or --particles",
                show_bytes(limit_bytes),
                show_bytes((need as u64).div_ceil(1 << 20) * (1 << 20)),
            )));
        }
        self.tape_budget = tape_budget;
        // A coarser level runs before this one and its tapes are gone when this one's are
        // made: the same budget holds it (its steps are an eighth the size).
        let mut level = self.coarse.as_deref_mut();
        while let Some(c) = level {
            c.tape_budget = tape_budget;
            level = c.coarse.as_deref_mut();
        }
        Ok(MemoryPlan {
            limit: limit_bytes,
            fixed,
            tape_budget: tape_budget as u64,
            chunk_steps: (plan != ChunkPlan::WHOLE).then_some(plan.interval),
            tape_peak: peak as u64,
            step_tape_bytes: step as u64,
        })
    }

    /// How each segment's rollout is cut into chunks under [`Prepared::tape_budget`] (what
    /// [`crate::morph::segment::Segment::chunk_plan`] decides for this morph's segments).
    pub fn segment_chunk_plan(&self) -> ChunkPlan {
        self.chunk_plan_within(self.tape_budget)
    }

    fn chunk_plan_within(&self, budget: usize) -> ChunkPlan {
        let n = self.initial.len();
        let step = crate::morph::prepare::sim::with_sim!(&self.engine, sim => super::segment::step_bytes(sim, n));
        ChunkPlan::within(
            budget,
            self.max_sim_segment_steps(),
            step,
            State::bytes_for(n),
            self.sim_control_stride(),
        )
    }
}

/// Bytes one particle of one frame takes in the USD layer while it is written: points,
/// velocities (f32 x 3 each), `J` (f32) and a share of the time-sample map.
pub const USD_PARTICLE_BYTES: u64 = 32;
/// Rebuilt-surface vertices a plan allows for, times the particle count to the power 2/3
/// (the surface of a body of that many particles). Measured: 20.9 on sphere -> cube at 4,224
/// particles, 21.3 at 17,256, 23.9 on sphere -> two-lobes at 11,752; kept with margin for
/// thin parts, which have more surface for their volume.
pub const REBUILT_VERTICES_PER_AREA: f64 = 32.0;
/// Bytes one rebuilt vertex of one frame takes in the USD layer: its point (f32 x 3) and,
/// at two triangles a vertex, their indices and counts (i32).
pub const USD_REBUILT_VERTEX_BYTES: u64 = 48;
/// Bytes one carried vertex of one frame takes while the USD layer is made: its f64
/// position (for the velocities' differences) and its point and velocity (f32 x 3 each).
pub const USD_CARRIED_VERTEX_BYTES: u64 = 48;

/// What the USD crate writer holds beside the layer while it encodes it, as a share of the
/// layer (measured: up to a third, on 121 frames of 4,224 particles).
pub const USD_WRITER_SHARE: f64 = 0.5;

/// Estimated bytes of the USD layer of `frames` frames of `particles` particles, with the
/// surfaces `settings` asks for (`source_vertices`: the carried surface's), all held at once
/// while the file is written ([`crate::io::usd`]); 0 when no USD file is written.
pub fn usd_bytes(
    settings: &MorphSettings,
    particles: u64,
    frames: u64,
    source_vertices: u64,
) -> u64 {
    if settings.outputs.usd == crate::io::usd::UsdFormat::None {
        return 0;
    }
    let carried = settings.outputs.surfaces.carried();
    let rebuilt = settings.outputs.surfaces.rebuilt();
    let rebuilt_vertices =
        (REBUILT_VERTICES_PER_AREA * (particles as f64).powf(2.0 / 3.0)).ceil() as u64;
    let per_frame = particles * USD_PARTICLE_BYTES
        + if carried {
            source_vertices * USD_CARRIED_VERTEX_BYTES
        } else {
            0
        }
        + if rebuilt {
            rebuilt_vertices * USD_REBUILT_VERTEX_BYTES
        } else {
            0
        };
    frames * per_frame
}

impl Prepared {
    /// What this morph's memory is sized by ([`Counts`]), exactly.
    pub fn memory_counts(&self, source_vertices: usize) -> Counts {
        let g = &self.geometry;
        Counts {
            particles: self.initial.len() as u64,
            targets: (g.target.positions.len()
                + g.keyframes
                    .iter()
                    .map(|k| k.particles.positions.len())
                    .sum::<usize>()) as u64,
            nodes: self.model().grid.node_count() as u64,
            keyframes: g.keyframes.len() as u64,
            dx: self.model().grid.dx,
            source_vertices: source_vertices as u64,
            frames: self.frame_count() as u64,
        }
    }
}

/// A size as people read it: `150 MB`, `4.0 GB` (powers of 1024).
pub fn show_bytes(b: u64) -> String {
    let b = b as f64;
    if b >= (1u64 << 30) as f64 {
        format!("{:.1} GB", b / (1u64 << 30) as f64)
    } else {
        format!("{:.0} MB", b / (1u64 << 20) as f64)
    }
}

/// The process's resident memory now (Linux; `None` elsewhere). Read from `/proc` rather
/// than through a crate: one line of one file.
pub fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

/// The machine's physical memory (Linux; `None` elsewhere).
pub fn physical_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cgroup file system under a fresh folder: `(path, content)` files.
    fn fixture(name: &str, files: &[(&str, &str)]) -> std::path::PathBuf {
        let root = std::env::temp_dir().join(format!("morph-cgroup-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        for (path, content) in files {
            let p = root.join(path);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, content).unwrap();
        }
        root
    }

    #[test]
    fn cgroup_v2_limits_are_read_up_the_tree() {
        let root = fixture(
            "v2",
            &[
                ("memory.max", "max\n"),
                ("farm/memory.max", "8589934592\n"),
                ("farm/job7/memory.max", "max\n"),
            ],
        );
        // The job's own group has none; its slot (the parent) has 8 GiB.
        assert_eq!(cgroup_limit_in(&root, "0::/farm/job7\n"), Some(8 << 30));
        // A tighter limit on the job's own group wins.
        std::fs::write(root.join("farm/job7/memory.max"), "1073741824\n").unwrap();
        assert_eq!(cgroup_limit_in(&root, "0::/farm/job7\n"), Some(1 << 30));
        // No limit anywhere.
        assert_eq!(cgroup_limit_in(&root, "0::/\n"), None);
        // A path the mount does not show (a container without its own namespace): skipped.
        assert_eq!(cgroup_limit_in(&root, "0::/elsewhere/x\n"), None);
        std::fs::remove_dir_all(root).unwrap();
    }

    #[test]
    fn cgroup_v1_limits_are_read_for_the_memory_controller() {
        let unlimited = "9223372036854771712\n";
        let root = fixture(
            "v1",
            &[
                ("memory/memory.limit_in_bytes", unlimited),
                ("memory/docker/abc/memory.limit_in_bytes", "536870912\n"),
                ("cpu/docker/abc/cpu.shares", "1024\n"),
            ],
        );
        let own = "11:cpu,cpuacct:/docker/abc\n4:memory:/docker/abc\n1:name=systemd:/docker/abc\n";
        assert_eq!(cgroup_limit_in(&root, own), Some(512 << 20));
        // `memory` among several controllers on one line.
        let joint = "4:cpuacct,memory:/docker/abc\n";
        assert_eq!(cgroup_limit_in(&root, joint), Some(512 << 20));
        // v1's "no limit" (a number near 2^63) is none.
        assert_eq!(cgroup_limit_in(&root, "4:memory:/\n"), None);
        // The machine this runs on: whatever it has, a limit is a positive size.
        assert!(cgroup_limit().is_none_or(|b| b > 0));
        std::fs::remove_dir_all(root).unwrap();
    }

    #[test]
    fn sizes_parse_with_units() {
        let b = |s: &str| s.parse::<MemoryLimit>().unwrap();
        assert_eq!(b("auto"), MemoryLimit::Auto);
        assert_eq!(b("150M"), MemoryLimit::Bytes(150 << 20));
        assert_eq!(b("4G"), MemoryLimit::Bytes(4 << 30));
        assert_eq!(b("1.5GB"), MemoryLimit::Bytes(3 << 29));
        assert_eq!(b("2048"), MemoryLimit::Bytes(2048));
        for bad in ["", "M", "-1G", "12Q", "0", "nan"] {
            assert!(bad.parse::<MemoryLimit>().is_err(), "{bad}");
        }
    }
}
