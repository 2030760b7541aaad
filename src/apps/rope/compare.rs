//! `morph rope`: the uncontrolled rope, MPPI and the gradient controller on the same scene,
//! with the same control knots, bounds and cost. Writes (into the locked `OUT.partial`, put
//! in place when complete; see [`crate::io::outdir`]):
//!
//! ```text
//! OUT/report.json                    per method: final_energy, compute_s, energy per step, ...
//! OUT/energy.png                     KE against simulated time (3 runs) and compute time (2)
//! OUT/frames/<method>/frame_NNNN.ply binary PLY points x y z vx vy vz J id
//! ```

use super::ControllerRun;
use super::gradient::{GradientSettings, gradient_control};
use super::mppi::{MppiSettings, mppi_control};
use super::scene::{Rope, RopeConfig};
use super::{Committed, ControlEvent};
use crate::engine::integrator::{Controlled, IntegratorKind, Steps};
use crate::engine::material::MaterialModel;
use crate::engine::mpm::ControlParams;
use crate::engine::mpm::SimError;
use crate::engine::mpm::State;
use crate::io::frames::write_points_ply;
use crate::io::images::{PALETTE, Series, write_two_panels};
use crate::io::outdir;
use crate::io::write_atomically;
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum RopeError {
    #[error("{0}")]
    Settings(String),
    #[error("{0}")]
    Sim(#[from] SimError),
    #[error("{0}")]
    Output(String),
}

/// Everything `morph rope` needs.
#[derive(Clone, Debug, Serialize)]
pub struct RopeSettings {
    pub rope: RopeConfig,
    pub gradient: GradientSettings,
    pub mppi: MppiSettings,
    /// A PLY frame every this many steps (0: no frames).
    pub frame_every: usize,
    /// "Low energy" is this fraction of the uncontrolled run's peak kinetic energy (the report
    /// also gives the times for 5%, 1%, 0.5% and 0.2%).
    pub low_energy_fraction: f64,
}

impl Default for RopeSettings {
    fn default() -> Self {
        RopeSettings {
            rope: RopeConfig::default(),
            gradient: GradientSettings::default(),
            mppi: MppiSettings::default(),
            frame_every: 10,
            low_energy_fraction: 0.01,
        }
    }
}

/// One method's results.
#[derive(Clone, Debug, Serialize)]
pub struct MethodReport {
    /// Final kinetic energy (J): the mean over the last quarter of the run. A swinging body
    /// trades kinetic for potential energy twice a period, so one instant says little; the
    /// last quarter (0.5 s by default) spans a whole kinetic-energy cycle of the swing.
    pub final_energy: f64,
    /// Kinetic energy at the very last step (J).
    pub last_step_energy: f64,
    /// `1/2 sum m |v_p|^2` of the particle velocities at the last step (J): the motion's
    /// energy plus what sits in velocity modes the grid cannot see (see docs/control.md).
    pub last_step_particle_energy: f64,
    /// The cost both controllers minimize: dt * sum of kinetic energy over steps (J s).
    pub cost: f64,
    /// Wall seconds spent deciding the controls (0 for the uncontrolled run).
    pub compute_s: f64,
    /// RK4 steps simulated while deciding (machine-independent work).
    pub simulated_steps: usize,
    /// First simulated time after which the kinetic energy stays below the low-energy line
    /// (0 if it never rises above it, null if it ends above it).
    pub time_to_low_energy_s: Option<f64>,
    /// The same for other lines: (fraction of the uncontrolled peak, seconds).
    pub time_to_fraction_of_peak_s: Vec<(f64, Option<f64>)>,
    /// Kinetic energy at the end of every step of the final rollout.
    pub energy: Vec<f64>,
    /// For each step, the compute time at which the controller committed it.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub committed_at_s: Vec<f64>,
    /// (compute seconds, window cost) of every evaluation.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub evaluations: Vec<(f64, f64)>,
    /// Control knots per control, as [x, y, z].
    pub controls: Vec<Vec<[f64; 3]>>,
    pub frames: Vec<String>,
    /// Largest distance the clamp moved from its start (m).
    pub max_clamp_offset: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Ratios {
    /// gradient final energy / MPPI final energy.
    pub final_energy: f64,
    /// gradient compute / MPPI compute.
    pub compute: f64,
    /// MPPI time to low energy / gradient time to low energy.
    pub speedup_to_low_energy: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct RopeReport {
    pub tool: &'static str,
    pub version: &'static str,
    /// SHA-256 of the tool version and settings: what decides the run.
    pub run_id: String,
    /// Every other file of the output folder (relative, with `/`): what `--overwrite` may
    /// replace (see [`crate::io::outdir::check_owned`]); filled in when the folder is written.
    pub files: Vec<String>,
    pub integrator: IntegratorKind,
    pub material: MaterialModel,
    pub settings: RopeSettings,
    pub particles: usize,
    pub clamped_particles: usize,
    pub grid_cells: [usize; 3],
    pub dx: f64,
    pub wave_speed: f64,
    pub threads: usize,
    pub low_energy_threshold: f64,
    pub uncontrolled: MethodReport,
    pub mppi: MethodReport,
    pub gradient: MethodReport,
    pub ratios: Ratios,
}

/// What [`run_rope`] hands to its writer: the report and the frames of each method.
pub struct RopeResult {
    pub report: RopeReport,
    pub frames: [Vec<(usize, State)>; 3],
}

pub const METHODS: [&str; 3] = ["uncontrolled", "mppi", "gradient"];

/// States saved as frames, with the step each was taken after.
type Frames = Vec<(usize, State)>;

/// Replays `params` from the initial state: energy per step, frames and the clamp's travel.
fn replay<S: Controlled>(
    sys: &S,
    rope: &Rope,
    params: &ControlParams,
    frame_every: usize,
) -> Result<(Vec<f64>, Frames, f64, f64), SimError> {
    let model = sys.model();
    let steps = rope.config.steps;
    let mut s = rope.initial.clone();
    let clamp: Vec<usize> = (0..s.len()).filter(|&p| model.is_clamped(p)).collect();
    let start: Vec<_> = clamp.iter().map(|&p| s.x[p]).collect();
    let mut frames = Vec::new();
    if frame_every > 0 {
        frames.push((0, s.clone()));
    }
    let mut max_offset = 0.0f64;
    let mut particle_energy = 0.0;
    let energy = sys.run(&mut s, params, Steps::new(0, steps), None, &mut |k, st| {
        if k + 1 == steps {
            particle_energy = sys.particle_energy(st, params, k);
        }
        if let Some((&p, x0)) = clamp.first().zip(start.first()) {
            max_offset = max_offset.max((st.x[p] - x0).norm());
        }
        if frame_every > 0 && (k + 1) % frame_every == 0 {
            frames.push((k + 1, st.clone()));
        }
    })?;
    Ok((energy, frames, max_offset, particle_energy))
}

fn time_to_low(energy: &[f64], threshold: f64, dt: f64) -> Option<f64> {
    if energy.last().is_none_or(|&e| e > threshold) {
        return None;
    }
    let i = energy
        .iter()
        .rposition(|&e| e > threshold)
        .map_or(0, |i| i + 1);
    Some(i as f64 * dt)
}

fn method_report<S: Controlled>(
    sys: &S,
    rope: &Rope,
    params: &ControlParams,
    run: Option<&ControllerRun>,
    frame_every: usize,
) -> Result<(MethodReport, Frames), SimError> {
    let (energy, frames, max_clamp_offset, last_step_particle_energy) =
        replay(sys, rope, params, frame_every)?;
    let dt = sys.model().dt;
    let quarter = (energy.len() / 4).max(1);
    let tail = &energy[energy.len() - quarter..];
    let committed_at_s = run.map_or(Vec::new(), |r| {
        r.committed
            .iter()
            .map(|c: &Committed| c.compute_s)
            .collect()
    });
    if let Some(r) = run {
        // The replay must reproduce what the controller committed, bit for bit.
        let same = r.committed.len() == energy.len()
            && r.committed.iter().zip(&energy).all(|(c, e)| c.energy == *e);
        if !same {
            return Err(SimError::InvalidScene(
                "internal: the replayed rollout differs from the committed one".into(),
            ));
        }
    }
    Ok((
        MethodReport {
            final_energy: tail.iter().sum::<f64>() / tail.len() as f64,
            last_step_energy: *energy.last().unwrap_or(&0.0),
            last_step_particle_energy,
            cost: dt * energy.iter().sum::<f64>(),
            compute_s: run.map_or(0.0, |r| r.compute_s),
            simulated_steps: run.map_or(0, |r| r.simulated_steps),
            time_to_low_energy_s: None,
            time_to_fraction_of_peak_s: Vec::new(),
            energy,
            committed_at_s,
            evaluations: run.map_or(Vec::new(), |r| r.evaluations.clone()),
            controls: params
                .iter()
                .map(|k| k.iter().map(|v| [v[0], v[1], v[2]]).collect())
                .collect(),
            frames: Vec::new(),
            max_clamp_offset,
        },
        frames,
    ))
}

/// The most any count of a rope run may be (steps, samples, horizons, iterations...): far
/// beyond any useful run (the default is a few hundred steps), and small enough that what
/// is sized by it fits in memory. `cells_along` has its own, smaller bound.
pub const MAX_ROPE_COUNT: usize = 100_000;
/// The most cells along the rope.
pub const MAX_ROPE_CELLS: usize = 1_000;

impl RopeSettings {
    /// Checks every setting (scene, both controllers) and builds the scene.
    pub fn validate(&self) -> Result<Rope, RopeError> {
        let counts = [
            ("steps", self.rope.steps),
            ("control-interval", self.rope.control_interval),
            ("batch", self.gradient.batch_steps),
            ("iterations", self.gradient.iterations),
            ("lookahead", self.gradient.lookahead_steps),
            ("samples", self.mppi.samples),
            ("mppi-horizon", self.mppi.horizon_steps),
            ("replan", self.mppi.replan_steps),
            ("refinements", self.mppi.refinements),
            ("frame-every", self.frame_every),
        ];
        for (name, v) in counts {
            if v > MAX_ROPE_COUNT {
                return Err(RopeError::Settings(format!(
                    "--{name} must be at most {MAX_ROPE_COUNT}, got {v}"
                )));
            }
        }
        if self.rope.cells_along > MAX_ROPE_CELLS {
            return Err(RopeError::Settings(format!(
                "--cells-along must be at most {MAX_ROPE_CELLS}, got {}",
                self.rope.cells_along
            )));
        }
        let bad = |e: SimError| {
            RopeError::Settings(match e {
                SimError::InvalidScene(m) => m,
                other => other.to_string(),
            })
        };
        if !(self.low_energy_fraction.is_finite()
            && self.low_energy_fraction > 0.0
            && self.low_energy_fraction < 1.0)
        {
            return Err(RopeError::Settings(format!(
                "low-energy fraction must be in (0, 1), got {}",
                self.low_energy_fraction
            )));
        }
        let rope = self.rope.build().map_err(bad)?;
        let (steps, interval) = (self.rope.steps, self.rope.control_interval);
        self.gradient.validate(steps, interval).map_err(bad)?;
        self.mppi.validate(steps, interval).map_err(bad)?;
        Ok(rope)
    }
}

/// Runs the three methods on the rope.
pub fn run_rope(
    settings: &RopeSettings,
    mut on_event: impl FnMut(ControlEvent),
) -> Result<RopeResult, RopeError> {
    let rope = settings.validate()?;
    crate::engine::with_integrator!(&rope.engine, sys => compare_methods(sys, &rope, settings, &mut on_event))
}

/// The three methods with the integrator the settings chose.
fn compare_methods<S: Controlled>(
    sys: &S,
    rope: &Rope,
    settings: &RopeSettings,
    on_event: &mut dyn FnMut(ControlEvent),
) -> Result<RopeResult, RopeError> {
    let steps = settings.rope.steps;
    let every = settings.frame_every;
    let model = sys.model();

    let zero = model.controls().zero_params();
    let (mut uncontrolled, f0) = method_report(sys, rope, &zero, None, every)?;
    let mppi_run = mppi_control(sys, &rope.initial, &settings.mppi, steps, &mut *on_event)?;
    let (mut mppi, f1) = method_report(sys, rope, &mppi_run.params, Some(&mppi_run), every)?;
    let grad_run = gradient_control(
        sys,
        &rope.initial,
        &settings.gradient,
        steps,
        &mut *on_event,
    )?;
    let (mut gradient, f2) = method_report(sys, rope, &grad_run.params, Some(&grad_run), every)?;
    let sys = model;

    let peak = uncontrolled.energy.iter().copied().fold(0.0, f64::max);
    let threshold = settings.low_energy_fraction * peak;
    for m in [&mut uncontrolled, &mut mppi, &mut gradient] {
        m.time_to_low_energy_s = time_to_low(&m.energy, threshold, sys.dt);
        m.time_to_fraction_of_peak_s = [0.05, 0.01, 0.005, 0.002]
            .iter()
            .map(|&f| (f, time_to_low(&m.energy, f * peak, sys.dt)))
            .collect();
    }
    let ratios = Ratios {
        final_energy: gradient.final_energy / mppi.final_energy,
        compute: gradient.compute_s / mppi.compute_s,
        // A controller that never rises above the line counts as reaching it after one step.
        speedup_to_low_energy: match (mppi.time_to_low_energy_s, gradient.time_to_low_energy_s) {
            (Some(m), Some(g)) => Some(m / g.max(sys.dt)),
            _ => None,
        },
    };
    let report = RopeReport {
        tool: "morph rope",
        version: env!("CARGO_PKG_VERSION"),
        run_id: {
            use sha2::{Digest, Sha256};
            let decisive = serde_json::to_vec(&("morph rope", env!("CARGO_PKG_VERSION"), settings))
                .expect("plain data");
            Sha256::digest(&decisive)
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect()
        },
        files: Vec::new(),
        integrator: rope.engine.kind(),
        material: settings.rope.material,
        settings: settings.clone(),
        particles: sys.num_particles(),
        clamped_particles: (0..sys.num_particles())
            .filter(|&p| sys.is_clamped(p))
            .count(),
        grid_cells: sys.grid.cells,
        dx: sys.grid.dx,
        wave_speed: sys.stable_dt().1,
        threads: rayon::current_num_threads(),
        low_energy_threshold: threshold,
        uncontrolled,
        mppi,
        gradient,
        ratios,
    };
    Ok(RopeResult {
        report,
        frames: [f0, f1, f2],
    })
}

fn out_err(what: &str, path: &Path, e: impl std::fmt::Display) -> RopeError {
    RopeError::Output(format!("cannot write {what} '{}': {e}", path.display()))
}

/// Marks a staging folder as a rope run's (a morph's holds `run.json` and is never cleared).
const ROPE_MARKER: &str = "rope.json";
/// The names a rope run writes at the top of its folder.
const ROPE_NAMES: &[&str] = &["frames", "energy.png", "report.json"];

/// Runs [`run_rope`] and writes the folder `out`, guarded like a morph's
/// ([`crate::io::outdir`]): `-o` is checked before the run, an existing folder is replaced
/// only with `overwrite` and only when it holds a rope `report.json`, and the staging folder
/// is locked. A rope run is not resumable: a leftover staging folder of an earlier rope run
/// (marked by its `rope.json`) is scratch and is cleared; any other is refused.
pub fn rope_to_folder(
    settings: &RopeSettings,
    out: &Path,
    overwrite: bool,
    on_event: impl FnMut(ControlEvent),
) -> Result<RopeReport, RopeError> {
    settings.validate()?;
    let plan = outdir::plan(out, &[], overwrite, "report.json").map_err(RopeError::Settings)?;
    let mut staging = outdir::Staging::take(&plan, ROPE_MARKER, ROPE_NAMES)
        .map_err(|e| RopeError::Output(e.to_string()))?;
    staging.clear().map_err(RopeError::Output)?;
    let marker = staging.dir.join(ROPE_MARKER);
    write_atomically(&marker, |w| w.write_all(b"{\"tool\": \"morph rope\"}\n"))
        .map_err(|e| out_err("run marker", &marker, e))?;
    let written = run_rope(settings, on_event).and_then(|mut result| {
        write_folder(&mut result, &staging.dir)?;
        Ok(result.report)
    });
    match written {
        Ok(report) => {
            let _ = std::fs::remove_file(&marker);
            staging.commit(&plan).map_err(RopeError::Output)?;
            Ok(report)
        }
        Err(e) => {
            staging.discard();
            Err(e)
        }
    }
}

fn write_folder(result: &mut RopeResult, dir: &Path) -> Result<(), RopeError> {
    let report = &mut result.report;
    let frames = &result.frames;
    let reports = [
        &mut report.uncontrolled,
        &mut report.mppi,
        &mut report.gradient,
    ];
    for ((name, m), fr) in METHODS.iter().zip(reports).zip(frames) {
        if fr.is_empty() {
            continue;
        }
        let sub: PathBuf = dir.join("frames").join(name);
        std::fs::create_dir_all(&sub).map_err(|e| out_err("folder", &sub, e))?;
        // Zero-padded to the width the count needs, so names sort in frame order.
        let width = fr.len().saturating_sub(1).to_string().len().max(4);
        for (i, (_, s)) in fr.iter().enumerate() {
            let rel = format!("frames/{name}/frame_{i:0width$}.ply");
            let path = dir.join(&rel);
            let j: Vec<f64> = s.f.iter().map(|f| f.determinant()).collect();
            write_points_ply(&path, &s.x, &s.v, &j).map_err(|e| out_err("frame", &path, e))?;
            m.frames.push(rel);
        }
    }
    let dt = report.settings.rope.dt;
    let by_time = |m: &MethodReport| -> Vec<(f64, f64)> {
        m.energy
            .iter()
            .enumerate()
            .map(|(k, e)| ((k + 1) as f64 * dt, *e))
            .collect()
    };
    let by_compute = |m: &MethodReport| -> Vec<(f64, f64)> {
        m.committed_at_s
            .iter()
            .zip(&m.energy)
            .map(|(c, e)| (*c, *e))
            .collect()
    };
    let series = |name: &str, k: usize, pts: Vec<(f64, f64)>| Series {
        name: name.to_uppercase(),
        color: PALETTE[k],
        points: pts,
    };
    let left = [
        series("uncontrolled", 0, by_time(&report.uncontrolled)),
        series("mppi", 1, by_time(&report.mppi)),
        series("gradient", 2, by_time(&report.gradient)),
    ];
    let right = [
        series("mppi", 1, by_compute(&report.mppi)),
        series("gradient", 2, by_compute(&report.gradient)),
    ];
    let png = dir.join("energy.png");
    write_two_panels(
        &png,
        ("KINETIC ENERGY VS SIM TIME S", &left),
        ("KINETIC ENERGY VS COMPUTE S", &right),
    )
    .map_err(|e| out_err("plot", &png, e))?;
    let json = dir.join("report.json");
    report.files = crate::io::outdir::list_files(dir, &["report.json", ROPE_MARKER])
        .map_err(|e| out_err("folder listing", dir, e))?;
    let text = serde_json::to_string_pretty(report).map_err(|e| out_err("report", &json, e))?;
    write_atomically(&json, |w| std::io::Write::write_all(w, text.as_bytes()))
        .map_err(|e| out_err("report", &json, e))?;
    Ok(())
}

/// The summary table `morph rope` prints.
pub fn table(report: &RopeReport) -> String {
    let mut s = String::new();
    s.push_str(&format!(
        "rope: {} particles ({} clamped), grid {}x{}x{}, dx {:.4} m, dt {} s, {} steps ({:.2} s), RK4, {} threads\nlow energy: below {:.3e} J ({} of the uncontrolled peak)\n\n",
        report.particles,
        report.clamped_particles,
        report.grid_cells[0],
        report.grid_cells[1],
        report.grid_cells[2],
        report.dx,
        report.settings.rope.dt,
        report.settings.rope.steps,
        report.settings.rope.steps as f64 * report.settings.rope.dt,
        report.threads,
        report.low_energy_threshold,
        report.settings.low_energy_fraction,
    ));
    s.push_str("| method | final KE, mean of last 25% (J) | KE at last step (J) | cost (J s) | time to low energy (s) | compute (s) | steps simulated |\n|---|---|---|---|---|---|---|\n");
    for (name, m) in [
        ("uncontrolled", &report.uncontrolled),
        ("mppi", &report.mppi),
        ("gradient", &report.gradient),
    ] {
        s.push_str(&format!(
            "| {name} | {:.4e} | {:.4e} | {:.4e} | {} | {:.2} | {} |\n",
            m.final_energy,
            m.last_step_energy,
            m.cost,
            m.time_to_low_energy_s
                .map_or("never".to_string(), |t| format!("{t:.3}")),
            m.compute_s,
            m.simulated_steps,
        ));
    }
    let r = &report.ratios;
    s.push_str(&format!(
        "\ngradient vs MPPI: final energy x{:.3}, compute x{:.4}, low energy {} sooner\n",
        r.final_energy,
        r.compute,
        r.speedup_to_low_energy
            .map_or("n/a".to_string(), |x| format!("{x:.2}x")),
    ));
    s
}
