//! `morph study`: what accuracy costs in time. Runs one morph per configuration of a grid of
//! settings and records, per configuration, wall and CPU seconds, peak memory, evaluations,
//! the final loss and the quality judge's verdict ([`crate::morph::quality`]), then marks the
//! Pareto front of quality against wall time. The front is on the judge's absolute IoU with
//! the target: `fill` is normalised by what a lattice fill at the run's own spacing reaches,
//! so it hides what a finer resolution buys (detail); the IoU shows it.
//!
//! Files in the study folder, rewritten (atomically) after every configuration, so an
//! interrupted study continues where it stopped and skips what it has measured:
//! `study.json` (every row), `study.csv` (the same as a table), `study.png` (IoU against wall
//! seconds, log axis, with the front).

use crate::engine::integrator::IntegratorKind;
use crate::engine::mpm::KernelKind;
use crate::morph::motion::MotionMeasures;
use crate::morph::quality::{Progress, Quality};
use crate::morph::usage;
use crate::morph::{Frame, Job, MeshSource, MorphError, MorphSettings, Observer, Preset};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The axes of a study: every combination is one configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyGrid {
    /// The preset the other settings start from.
    pub preset: Preset,
    /// Grid resolutions (cells along the longest side of the domain)...
    pub resolutions: Vec<usize>,
    /// ...and particle budgets (`--particles`: the resolution that gives the source about
    /// this many particles): together the detail axis.
    #[serde(default)]
    pub particles: Vec<usize>,
    pub particles_per_cell: Vec<usize>,
    pub kernels: Vec<KernelKind>,
    pub integrators: Vec<IntegratorKind>,
    pub iterations: Vec<usize>,
    pub passes: Vec<usize>,
    pub segments: Vec<usize>,
    /// Weights of the reach cost (`--reach-weight`).
    #[serde(default)]
    pub reach_weights: Vec<f64>,
}

impl StudyGrid {
    /// The full grid: 4 particle budgets (5,000 to 150,000) x 2 kernels x 2 iteration counts
    /// x the reach cost off and on = 32 configurations of the default chain (12 segments).
    /// On 2 cores it takes a night: the 150,000-particle runs are most of it.
    pub fn full() -> StudyGrid {
        StudyGrid {
            preset: Preset::Default,
            resolutions: Vec::new(),
            particles: vec![5_000, 15_000, 50_000, 150_000],
            particles_per_cell: vec![2],
            kernels: vec![KernelKind::Quadratic, KernelKind::Cubic],
            integrators: vec![IntegratorKind::Euler],
            iterations: vec![6, 12],
            passes: vec![1],
            segments: vec![12],
            reach_weights: vec![0.0, 10.0],
        }
    }

    /// A first look in about a minute: 3 resolutions x 2 kernels x 2 iteration counts, a
    /// four-segment chain.
    pub fn quick() -> StudyGrid {
        StudyGrid {
            preset: Preset::Draft,
            resolutions: vec![16, 24, 32],
            particles: Vec::new(),
            particles_per_cell: vec![2],
            kernels: vec![KernelKind::Quadratic, KernelKind::Cubic],
            integrators: vec![IntegratorKind::Euler],
            iterations: vec![3, 6],
            passes: vec![1],
            segments: vec![4],
            reach_weights: vec![0.0],
        }
    }

    /// Every configuration, with its settings.
    pub fn configs(&self) -> Vec<StudyConfig> {
        let mut out = Vec::new();
        let details = (self.resolutions.iter().map(|&r| (r, None)))
            .chain(self.particles.iter().map(|&n| (0, Some(n))));
        for (resolution, particles) in details {
            for &ppc in &self.particles_per_cell {
                for &kernel in &self.kernels {
                    for &integrator in &self.integrators {
                        for &iterations in &self.iterations {
                            for &passes in &self.passes {
                                for &segments in &self.segments {
                                    for &reach_weight in &self.reach_weights {
                                        out.push(StudyConfig {
                                            preset: self.preset,
                                            resolution,
                                            particles,
                                            particles_per_cell: ppc,
                                            kernel,
                                            integrator,
                                            iterations,
                                            passes,
                                            segments,
                                            reach_weight,
                                        });
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// Every axis has at least one value.
    pub fn validate(&self) -> Result<(), String> {
        let lens = [
            (
                "resolutions or --particles",
                self.resolutions.len() + self.particles.len(),
            ),
            ("particles-per-cell", self.particles_per_cell.len()),
            ("kernels", self.kernels.len()),
            ("integrators", self.integrators.len()),
            ("iterations", self.iterations.len()),
            ("passes", self.passes.len()),
            ("segments", self.segments.len()),
            ("reach-weights", self.reach_weights.len()),
        ];
        match lens.iter().find(|(_, n)| *n == 0) {
            Some((axis, _)) => Err(format!("--{axis} needs at least one value")),
            None => Ok(()),
        }
    }
}

/// One configuration of a study.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyConfig {
    pub preset: Preset,
    /// The grid resolution, unless a particle budget picks it (then 0).
    pub resolution: usize,
    /// The particle budget that picks the resolution, if any.
    #[serde(default)]
    pub particles: Option<usize>,
    pub particles_per_cell: usize,
    pub kernel: KernelKind,
    pub integrator: IntegratorKind,
    pub iterations: usize,
    pub passes: usize,
    pub segments: usize,
    #[serde(default)]
    pub reach_weight: f64,
}

impl StudyConfig {
    /// A name that identifies the configuration (rows are matched by it when a study
    /// continues; a study made before the budget and reach axes keeps its names).
    pub fn id(&self) -> String {
        let name = |v: &dyn erased::Named| v.name();
        let detail = match self.particles {
            Some(n) => format!("n{n}"),
            None => format!("r{}", self.resolution),
        };
        let reach = if self.reach_weight != 0.0 {
            format!("-rw{}", self.reach_weight)
        } else {
            String::new()
        };
        format!(
            "{}-{detail}-ppc{}-{}-{}-it{}-p{}-s{}{reach}",
            name(&self.preset),
            self.particles_per_cell,
            name(&self.kernel),
            name(&self.integrator),
            self.iterations,
            self.passes,
            self.segments
        )
    }

    /// The morph settings this configuration runs (no surfaces: the study judges particles).
    pub fn settings(&self) -> MorphSettings {
        let mut s = MorphSettings::preset(self.preset);
        // A resolution replaces the preset's particle budget (`final` has one), as it does on
        // the command line.
        (s.body.resolution, s.body.particles) = match self.particles {
            Some(n) => (s.body.resolution, Some(n)),
            None => (self.resolution, None),
        };
        s.body.particles_per_cell = self.particles_per_cell;
        s.method.reach_weight = self.reach_weight;
        s.method.kernel = self.kernel;
        s.method.integrator = self.integrator;
        s.method.optimizer.iterations = self.iterations;
        s.method.passes = self.passes;
        s.method.segments = self.segments;
        s.outputs.surfaces = crate::morph::settings::Surfaces::None;
        s
    }
}

/// Serde names of the settings' enums, for ids.
mod erased {
    pub trait Named {
        fn name(&self) -> String;
    }
    impl<T: serde::Serialize> Named for T {
        fn name(&self) -> String {
            serde_json::to_value(self)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default()
        }
    }
}

/// One measured configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyRow {
    pub id: String,
    pub config: StudyConfig,
    pub particles: usize,
    pub wall_s: f64,
    /// CPU seconds of the process (all threads) during the run; absent where the platform
    /// does not say.
    pub cpu_s: Option<f64>,
    /// Peak resident memory during the run (MB); absent where the platform does not say.
    pub peak_mb: Option<f64>,
    pub evaluations: usize,
    /// Absent when the run failed.
    pub final_loss: Option<f64>,
    /// Absent when the run failed.
    pub quality: Option<Quality>,
    /// The grid resolution the run used (a particle budget picks it).
    #[serde(default)]
    pub resolution: usize,
    /// The motion measures of its frames against the target (pulse, dip, wobble, settle,
    /// ease error; docs/morph.md, "Motion"), as a run's manifest reports them; absent when
    /// the run failed.
    #[serde(default)]
    pub motion: Option<MotionMeasures>,
    /// Why the run failed (the study records it and goes on).
    #[serde(default)]
    pub error: Option<String>,
    /// On the Pareto front of IoU with the target against wall seconds.
    pub pareto: bool,
}

/// The CSV columns, in order.
pub const CSV_COLUMNS: [&str; 34] = [
    "id",
    "preset",
    "resolution",
    "particle_budget",
    "particles_per_cell",
    "kernel",
    "integrator",
    "iterations",
    "passes",
    "segments",
    "reach_weight",
    "particles",
    "wall_s",
    "cpu_s",
    "peak_mb",
    "evaluations",
    "final_loss",
    "fill",
    "material_fill",
    "iou",
    "ejected",
    "surface_gap",
    "reach_p99",
    "reach_max",
    "perfect_reach_p99",
    "min_j",
    "max_j",
    "pulse",
    "dip",
    "wobble",
    "settle",
    "ease_error",
    "pareto",
    "error",
];

impl StudyRow {
    fn csv(&self) -> String {
        let c = &self.config;
        let q = self.quality.as_ref();
        let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
        let quality = |f: fn(&Quality) -> f64| opt(q.map(f));
        let motion = |f: fn(&MotionMeasures) -> Option<f64>| opt(self.motion.as_ref().and_then(f));
        let name = |v: &dyn erased::Named| v.name();
        [
            self.id.clone(),
            name(&c.preset),
            self.resolution.max(c.resolution).to_string(),
            c.particles.map_or(String::new(), |n| n.to_string()),
            c.particles_per_cell.to_string(),
            name(&c.kernel),
            name(&c.integrator),
            c.iterations.to_string(),
            c.passes.to_string(),
            c.segments.to_string(),
            format!("{}", c.reach_weight),
            self.particles.to_string(),
            format!("{}", self.wall_s),
            opt(self.cpu_s),
            opt(self.peak_mb),
            self.evaluations.to_string(),
            opt(self.final_loss),
            quality(|q| q.fill),
            quality(|q| q.material_fill),
            quality(|q| q.iou),
            quality(|q| q.ejected),
            quality(|q| q.surface_gap),
            quality(|q| q.reach_p99),
            quality(|q| q.reach_max),
            quality(|q| q.perfect_reach_p99),
            quality(|q| q.min_j),
            quality(|q| q.max_j),
            motion(|m| Some(m.pulse)),
            motion(|m| Some(m.dip)),
            motion(|m| Some(m.wobble)),
            motion(|m| Some(m.settle)),
            motion(|m| m.ease_error),
            self.pareto.to_string(),
            // One line a row: commas and line breaks in a message would split it.
            self.error
                .as_deref()
                .unwrap_or("")
                .replace([',', '\n'], ";"),
        ]
        .join(",")
    }
}

/// Marks the rows no other row beats on both IoU (higher) and wall seconds (lower).
pub fn mark_pareto(rows: &mut [StudyRow]) {
    let points: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.wall_s, r.quality.map_or(f64::NEG_INFINITY, |q| q.iou)))
        .collect();
    for (i, r) in rows.iter_mut().enumerate() {
        let (t, q) = points[i];
        if r.quality.is_none() {
            r.pareto = false;
            continue;
        }
        r.pareto = !points
            .iter()
            .enumerate()
            .any(|(j, &(tj, qj))| j != i && tj <= t && qj >= q && (tj < t || qj > q));
    }
}

/// What a study reports as it goes.
pub enum StudyEvent<'a> {
    /// A configuration measured earlier, kept.
    Skipped {
        index: usize,
        of: usize,
        id: &'a str,
    },
    /// A configuration about to run.
    Running {
        index: usize,
        of: usize,
        id: &'a str,
    },
    /// A configuration measured now.
    Measured {
        index: usize,
        of: usize,
        row: &'a StudyRow,
    },
}

/// Why a study stopped.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error("{0}")]
    Folder(String),
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

pub const STUDY_JSON: &str = "study.json";
pub const STUDY_CSV: &str = "study.csv";
pub const STUDY_PNG: &str = "study.png";

/// A mesh a study morphs, by path and content.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StudyInput {
    pub path: String,
    pub sha256: String,
}

/// `study.json`: which meshes the study morphs (by content) and every row measured so far.
#[derive(Serialize, Deserialize)]
struct StudyFile {
    tool: String,
    version: String,
    /// The source, then the target.
    inputs: Vec<StudyInput>,
    rows: Vec<StudyRow>,
}

/// The source and target as a study records them.
fn study_inputs(source: &Path, target: &Path) -> Result<Vec<StudyInput>, StudyError> {
    [source, target]
        .iter()
        .map(|p| {
            let sha256 = crate::io::sha256_file(p, crate::files::MESH_BYTES).map_err(|e| {
                StudyError::Folder(format!("cannot read mesh '{}': {e}", p.display()))
            })?;
            Ok(StudyInput {
                path: p.display().to_string(),
                sha256,
            })
        })
        .collect()
}

/// The study folder: new, empty, or an earlier study of the same meshes (holding its
/// `study.json`). Anything else is refused, so a study never writes into a folder it did
/// not make, and never keeps rows measured on other meshes.
fn open_folder(dir: &Path, inputs: &[StudyInput]) -> Result<Vec<StudyRow>, StudyError> {
    let bad = |m: String| Err(StudyError::Folder(m));
    if dir.is_symlink() || dir.is_file() {
        return bad(format!(
            "'{}' is not a folder; choose another -o",
            dir.display()
        ));
    }
    let json = dir.join(STUDY_JSON);
    if json.is_file() {
        let bytes =
            crate::files::read(&json, crate::files::SMALL_FILE_BYTES).map_err(|source| {
                StudyError::Write {
                    path: json.clone(),
                    source,
                }
            })?;
        let file: StudyFile = match serde_json::from_slice(&bytes) {
            Ok(f) => f,
            Err(e) => {
                let e = crate::files::short_message(&e.to_string());
                return bad(format!(
                    "'{}' is not a study this morph can continue ({e}; studies before morph 0.3.0 did not record their meshes); choose another -o",
                    json.display()
                ));
            }
        };
        for (which, (was, now)) in ["source", "target"]
            .iter()
            .zip(file.inputs.iter().zip(inputs))
        {
            if was.sha256 != now.sha256 {
                return bad(format!(
                    "'{}' is a study of another {which} mesh ('{}', not the content of '{}'); its rows do not apply: choose another -o",
                    dir.display(),
                    was.path,
                    now.path
                ));
            }
        }
        if file.inputs.len() != inputs.len() {
            return bad(format!(
                "'{}' records {} meshes, not a source and a target; choose another -o",
                json.display(),
                file.inputs.len()
            ));
        }
        return Ok(file.rows);
    }
    if dir.exists() {
        let entries = std::fs::read_dir(dir).map_err(|source| StudyError::Write {
            path: dir.into(),
            source,
        })?;
        if entries.count() > 0 {
            return bad(format!(
                "'{}' is not empty and holds no {STUDY_JSON}; a study writes only into a new or empty folder, or continues its own",
                dir.display()
            ));
        }
    }
    std::fs::create_dir_all(dir).map_err(|source| StudyError::Write {
        path: dir.into(),
        source,
    })?;
    Ok(Vec::new())
}

fn write_files(dir: &Path, inputs: &[StudyInput], rows: &[StudyRow]) -> Result<(), StudyError> {
    let err = |path: PathBuf| move |source| StudyError::Write { path, source };
    let file = StudyFile {
        tool: "morph study".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        inputs: inputs.to_vec(),
        rows: rows.to_vec(),
    };
    let json = serde_json::to_vec_pretty(&file).expect("plain data");
    let path = dir.join(STUDY_JSON);
    crate::io::write_atomically(&path, |w| std::io::Write::write_all(w, &json))
        .map_err(err(path.clone()))?;
    let mut csv = CSV_COLUMNS.join(",");
    csv.push('\n');
    for r in rows {
        csv.push_str(&r.csv());
        csv.push('\n');
    }
    let path = dir.join(STUDY_CSV);
    crate::io::write_atomically(&path, |w| std::io::Write::write_all(w, csv.as_bytes()))
        .map_err(err(path.clone()))?;
    let points: Vec<(f64, f64, bool)> = rows
        .iter()
        .filter_map(|r| Some((r.wall_s, r.quality?.iou, r.pareto)))
        .collect();
    let path = dir.join(STUDY_PNG);
    crate::io::images::write_front_plot(&path, &points).map_err(err(path.clone()))?;
    Ok(())
}

/// What a study keeps of each frame: the rms speed and the progress toward the target, from
/// which the motion measures are computed as a run's manifest computes them (the study
/// writes no files of a run).
#[derive(Default)]
struct MotionRecorder {
    progress: Option<Progress>,
    /// Per frame index: rms speed (world units) and IoU with the target's inside.
    frames: Vec<(f64, f64)>,
}

impl Observer for MotionRecorder {
    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        let progress = self.progress.get_or_insert_with(|| {
            (frame.prep.progress_judges().pop()).expect("a morph has a final target")
        });
        let iou = progress.iou(&frame.state.x);
        // A later pass writes its frames again: the last one counts.
        self.frames.truncate(frame.index);
        self.frames.push((frame.world.rms_speed(), iou));
        Ok(())
    }
}

/// Runs the study of `source` -> `target` over `grid` in folder `dir`, continuing an earlier
/// study there. Returns every row, the Pareto front marked.
pub fn run(
    source: &Path,
    target: &Path,
    grid: &StudyGrid,
    dir: &Path,
    mut on_event: impl FnMut(StudyEvent),
) -> Result<Vec<StudyRow>, StudyError> {
    grid.validate().map_err(StudyError::Folder)?;
    let inputs = study_inputs(source, target)?;
    let mut rows = open_folder(dir, &inputs)?;
    let configs = grid.configs();
    let of = configs.len();
    for (index, config) in configs.iter().enumerate() {
        let id = config.id();
        if rows.iter().any(|r| r.id == id) {
            on_event(StudyEvent::Skipped { index, of, id: &id });
            continue;
        }
        on_event(StudyEvent::Running { index, of, id: &id });
        let row = measure(source, target, config);
        rows.push(row);
        mark_pareto(&mut rows);
        write_files(dir, &inputs, &rows)?;
        let row = rows.last().expect("just pushed");
        on_event(StudyEvent::Measured { index, of, row });
    }
    mark_pareto(&mut rows);
    write_files(dir, &inputs, &rows)?;
    Ok(rows)
}

/// Runs one configuration and measures it; a run that fails is recorded with its error.
pub fn measure(source: &Path, target: &Path, config: &StudyConfig) -> StudyRow {
    let job = Job {
        source: MeshSource::File(source.into()),
        targets: vec![MeshSource::File(target.into())],
        settings: config.settings(),
    };
    usage::reset_peak();
    let cpu0 = usage::cpu_seconds();
    let clock = Instant::now();
    let mut recorder = MotionRecorder::default();
    let outcome = job.run(&mut recorder);
    let wall_s = clock.elapsed().as_secs_f64();
    let cpu_s = cpu0.zip(usage::cpu_seconds()).map(|(a, b)| b - a);
    let peak_mb = usage::peak_mb();
    let mut row = StudyRow {
        id: config.id(),
        config: *config,
        particles: 0,
        wall_s,
        cpu_s,
        peak_mb,
        evaluations: 0,
        final_loss: None,
        quality: None,
        resolution: 0,
        motion: None,
        error: None,
        pareto: false,
    };
    match outcome {
        Ok((prep, result)) => {
            row.particles = prep.initial.len();
            row.evaluations = result.segments.iter().map(|s| s.evaluations).sum();
            row.final_loss = Some(result.final_loss);
            row.quality = Some(prep.quality(&result.final_state));
            row.resolution = prep.settings.body.resolution;
            let n = prep.frame_count();
            if recorder.frames.len() == n {
                let (speeds, ious): (Vec<f64>, Vec<f64>) = recorder.frames.into_iter().unzip();
                let arrive = *prep
                    .settings
                    .shot
                    .at
                    .last()
                    .expect("a morph has a final target");
                row.motion =
                    Some(prep.motion_of(&speeds, &ious, prep.settings.shot.begin, n, arrive));
            }
        }
        Err(e) => row.error = Some(e.to_string()),
    }
    row
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_resolution_row_runs_that_resolution_on_any_preset() {
        for preset in Preset::ALL {
            let grid = StudyGrid {
                preset,
                resolutions: vec![20],
                particles: vec![3000],
                ..StudyGrid::quick()
            };
            for c in grid.configs() {
                let s = c.settings();
                match c.particles {
                    None => assert_eq!(
                        (s.body.resolution, s.body.particles),
                        (20, None),
                        "{preset:?}"
                    ),
                    Some(n) => assert_eq!(s.body.particles, Some(n), "{preset:?}"),
                }
            }
        }
    }
}
