//! The hard cases: morphs that break simulators (stiff materials, thin features, far-apart
//! shapes, extreme units, topology changes, huge steps, long chains and horizons, many
//! particles). Each either stays numerically stable, by the bounds below on every written
//! frame, or is refused with a one-line error that says why. `tests/integration/hard_cases.rs` runs the
//! fast ones; `morph bench-hard-cases` runs them all and prints one JSON line per case.

use crate::geometry::assets::{cube, torus, two_lobes, uv_sphere};
use crate::geometry::{LoadedMesh, TargetFit, TriMesh, load_mesh, prepare_mesh};
use crate::morph::memory::{MemoryLimit, resident_bytes};
use crate::morph::{self, Frame, MorphError, MorphSettings, Observer, Prepared, Preset};
use nalgebra::Vector3;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The largest volume ratio `J` a stable morph may reach (the volume cost keeps it near 1;
/// an element three times its rest volume is a failure of the method, not a morph).
pub const J_MAX: f64 = 3.0;

/// The largest root-mean-square particle speed, in domain lengths per second: a morph moves
/// the body within its domain over a fraction of a second; faster is an explosion.
pub const MAX_RMS_SPEED: f64 = 4.0;

/// What a case is expected to do.
#[derive(Clone, Debug, PartialEq)]
pub enum Expect {
    /// Run to the end within the bounds.
    Stable,
    /// Be refused, with a message holding this text.
    Refused(&'static str),
}

/// One hard case: two meshes in memory and the settings of the morph between them.
pub struct Case {
    pub name: &'static str,
    pub source: TriMesh,
    pub target: TriMesh,
    pub settings: MorphSettings,
    pub expect: Expect,
    /// Taking minutes: run by `morph bench-hard-cases`, not by the test suite.
    pub long: bool,
    pub memory_limit: MemoryLimit,
}

/// What a case measured on every written frame.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Measured {
    pub particles: usize,
    /// Simulation steps per morph step, the simulation's time step and the elastic bound.
    pub substeps: usize,
    pub dt: f64,
    pub stable_dt: f64,
    pub frames: usize,
    /// Frames with a NaN or an infinity in any particle field.
    pub non_finite_frames: usize,
    /// Particles outside the grid, summed over frames.
    pub outside: usize,
    pub min_j: f64,
    pub max_j: f64,
    /// Largest root-mean-square particle speed over the frames, in domain lengths per second.
    pub max_rms_speed: f64,
    /// The kinetic energy of the last frame over the largest of any frame.
    pub last_over_peak_energy: f64,
    pub initial_loss: f64,
    pub final_loss: f64,
    /// Largest displacement of any particle from where it started, over the frames, in cells.
    pub max_displacement_cells: f64,
    /// Each segment's first and last gradient norm (the first pass's).
    pub grad_norms: Vec<(f64, f64)>,
    /// Adam steps rejected (the step blew up and was halved).
    pub rejected_steps: usize,
    pub warnings: Vec<String>,
}

/// A case's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct Outcome {
    pub case: String,
    /// `ok`, `refused` or `failed`.
    pub verdict: String,
    /// The one-line error of a refused or failed run.
    pub error: Option<String>,
    pub measured: Option<Measured>,
    pub seconds: f64,
    /// Resident memory after the run (the process's peak is what `/usr/bin/time -v` reports).
    pub resident_mb: Option<f64>,
}

impl Outcome {
    /// Whether the case did what it was expected to (the reason when not).
    pub fn check(&self, expect: &Expect) -> Result<(), String> {
        match (expect, &self.error, &self.measured) {
            (Expect::Refused(text), Some(e), _) if e.contains(text) && !e.contains('\n') => Ok(()),
            (Expect::Refused(text), e, _) => Err(format!(
                "{}: expected a one-line refusal mentioning {text:?}, got {e:?}",
                self.case
            )),
            (Expect::Stable, Some(e), _) => Err(format!("{}: failed: {e}", self.case)),
            (Expect::Stable, None, Some(m)) => check_bounds(&self.case, m),
            (Expect::Stable, None, None) => Err(format!("{}: nothing measured", self.case)),
        }
    }
}

/// The stability bounds on what a run measured.
pub fn check_bounds(case: &str, m: &Measured) -> Result<(), String> {
    let fail = |why: String| Err(format!("{case}: {why}"));
    if m.frames == 0 {
        return fail("no frame written".into());
    }
    if m.non_finite_frames > 0 {
        return fail(format!(
            "{} frames hold NaN or infinity",
            m.non_finite_frames
        ));
    }
    if m.outside > 0 {
        return fail(format!("{} particle-frames outside the grid", m.outside));
    }
    if !(m.min_j > 0.0 && m.max_j <= J_MAX) {
        return fail(format!(
            "J ranges over [{}, {}], outside (0, {J_MAX}]",
            m.min_j, m.max_j
        ));
    }
    if m.max_rms_speed.is_nan() || m.max_rms_speed > MAX_RMS_SPEED {
        return fail(format!(
            "rms speed reached {} domain lengths per second (bound {MAX_RMS_SPEED})",
            m.max_rms_speed
        ));
    }
    if !(m.final_loss.is_finite() && m.initial_loss.is_finite()) {
        return fail(format!(
            "loss {} -> {} is not finite",
            m.initial_loss, m.final_loss
        ));
    }
    if let Some(g) = m
        .grad_norms
        .iter()
        .flat_map(|&(a, b)| [a, b])
        .find(|g| g.is_infinite())
    {
        return fail(format!("a gradient norm is {g}"));
    }
    Ok(())
}

/// Watches every frame of a run.
struct Watch<'a> {
    prep: &'a Prepared,
    m: Measured,
    peak_energy: f64,
    last_energy: f64,
    start: Vec<Vector3<f64>>,
}

impl Observer for Watch<'_> {
    fn event(&mut self, event: &morph::MorphEvent) {
        if let morph::MorphEvent::Iteration { loss, .. } = event
            && loss.is_infinite()
        {
            self.m.rejected_steps += 1;
        }
    }

    fn frame(&mut self, frame: &Frame) -> Result<(), MorphError> {
        let s = frame.state;
        let model = self.prep.model();
        let g = &model.grid;
        let m = &mut self.m;
        m.frames += 1;
        if s.first_non_finite().is_some() {
            m.non_finite_frames += 1;
            return Ok(());
        }
        let lo = g.origin_vec();
        let hi = lo + g.dx * Vector3::from(g.cells.map(|c| c as f64));
        m.outside +=
            s.x.iter()
                .filter(|x| (0..3).any(|a| x[a] < lo[a] || x[a] > hi[a]))
                .count();
        for f in &s.f {
            let j = f.determinant();
            m.min_j = m.min_j.min(j);
            m.max_j = m.max_j.max(j);
        }
        let energy = s.kinetic_energy(&model.mass);
        let total_mass: f64 = model.mass.iter().sum();
        let rms = (2.0 * energy / total_mass).sqrt() / crate::geometry::placement::DOMAIN_SIZE;
        m.max_rms_speed = m.max_rms_speed.max(rms);
        self.peak_energy = self.peak_energy.max(energy);
        self.last_energy = energy;
        let moved =
            s.x.iter()
                .zip(&self.start)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
        m.max_displacement_cells = m.max_displacement_cells.max(moved / g.dx);
        Ok(())
    }
}

/// Runs a case: prepares the morph (where refusals happen), runs it and measures every frame.
pub fn run_case(case: &Case) -> Outcome {
    let clock = Instant::now();
    let measured = measure(case);
    let (verdict, error, measured) = match measured {
        Ok(m) => ("ok", None, Some(m)),
        Err(e @ (MorphError::Settings(_) | MorphError::Mesh(_))) => {
            ("refused", Some(e.to_string()), None)
        }
        Err(e) => ("failed", Some(e.to_string()), None),
    };
    Outcome {
        case: case.name.into(),
        verdict: verdict.into(),
        error,
        measured,
        seconds: clock.elapsed().as_secs_f64(),
        resident_mb: resident_bytes().map(|b| b as f64 / (1 << 20) as f64),
    }
}

fn measure(case: &Case) -> Result<Measured, MorphError> {
    let load = |name: &str, mesh: &TriMesh| -> Result<(LoadedMesh, PathBuf), MorphError> {
        let path = PathBuf::from(format!("{}-{name}", case.name));
        Ok((prepare_mesh(&path, mesh.clone(), Vec::new())?, path))
    };
    let (src, src_path) = load("source", &case.source)?;
    let (tgt, tgt_path) = load("target", &case.target)?;
    let settings = case
        .settings
        .clone()
        .checked()
        .map_err(MorphError::Settings)?;
    let mut prep = Prepared::from_meshes(&settings, (&src, &src_path), &[(&tgt, &tgt_path)])?;
    prep.plan_memory(case.memory_limit)?;
    let mut watch = Watch {
        prep: &prep,
        m: Measured {
            particles: prep.initial.len(),
            substeps: prep.substeps,
            dt: prep.model().dt,
            stable_dt: prep.model().stable_dt().0,
            min_j: f64::INFINITY,
            max_j: f64::NEG_INFINITY,
            ..Default::default()
        },
        peak_energy: 0.0,
        last_energy: 0.0,
        start: prep.initial.x.clone(),
    };
    let result = morph::run_prepared(&prep, None, &mut watch)?;
    let mut m = watch.m;
    m.last_over_peak_energy = if watch.peak_energy > 0.0 {
        watch.last_energy / watch.peak_energy
    } else {
        0.0
    };
    m.initial_loss = result.initial_loss;
    m.final_loss = result.final_loss;
    m.grad_norms = result
        .segments
        .iter()
        .filter(|r| r.pass == 0)
        .map(|r| (r.grad_norm_first, r.grad_norm_last))
        .collect();
    m.warnings = morph::run_warnings(&result.segments);
    Ok(m)
}

/// Small settings the fast cases start from: 16 cells, 2 segments of 30 steps, 3 iterations.
pub fn quick() -> MorphSettings {
    let mut s = MorphSettings::preset(Preset::Draft);
    s.body.resolution = 16;
    s.method.segments = 2;
    s.method.optimizer.iterations = 3;
    s.outputs.surfaces = crate::morph::settings::Surfaces::None;
    s
}

fn sphere() -> TriMesh {
    uv_sphere(1.0, 16, 32, |_, _| 1.0)
}

fn scaled(mesh: &TriMesh, s: Vector3<f64>) -> TriMesh {
    TriMesh {
        vertices: mesh.vertices.iter().map(|v| v.component_mul(&s)).collect(),
        triangles: mesh.triangles.clone(),
    }
}

fn joined(a: &TriMesh, b: &TriMesh) -> TriMesh {
    let offset = a.vertices.len() as u32;
    TriMesh {
        vertices: a.vertices.iter().chain(&b.vertices).copied().collect(),
        triangles: a
            .triangles
            .iter()
            .copied()
            .chain(b.triangles.iter().map(|t| t.map(|i| i + offset)))
            .collect(),
    }
}

/// Every case. `meshes` is the folder of the shared test meshes (the bunny's ears).
pub fn cases(meshes: &Path) -> Result<Vec<Case>, MorphError> {
    let bunny = load_mesh(&meshes.join("stanford-bunny.obj"))?.mesh;
    let case = |name, source: TriMesh, target: TriMesh, settings, expect| Case {
        name,
        source,
        target,
        settings,
        expect,
        long: false,
        memory_limit: MemoryLimit::Auto,
    };
    let with = |f: &dyn Fn(&mut MorphSettings)| {
        let mut s = quick();
        f(&mut s);
        s
    };
    let stiff = |factor: f64| {
        with(&|s| {
            s.body.resolution = 12;
            s.method.segments = 1;
            s.method.steps_per_segment = 6;
            s.method.control_stride = 3;
            s.method.optimizer.iterations = 2;
            s.body.material.mu *= factor;
            s.body.material.lambda *= factor;
        })
    };
    let lobes = two_lobes(24, 32);
    let units = |scale: f64| {
        let v = Vector3::repeat(scale);
        (scaled(&sphere(), v), scaled(&lobes, v))
    };
    let (tiny_s, tiny_t) = units(1e-4);
    let (huge_s, huge_t) = units(1e4);
    // Two blobs a diameter apart, in one mesh.
    let blobs = joined(
        &scaled(&sphere(), Vector3::repeat(0.6)).transformed(1.0, &Vector3::new(-1.2, 0.0, 0.0)),
        &scaled(&sphere(), Vector3::repeat(0.6)).transformed(1.0, &Vector3::new(1.2, 0.0, 0.0)),
    );
    let mut all = vec![
        case(
            "stiff-x100",
            sphere(),
            lobes.clone(),
            stiff(100.0),
            Expect::Stable,
        ),
        case(
            "stiff-x10000",
            sphere(),
            lobes.clone(),
            stiff(1e4),
            Expect::Stable,
        ),
        case(
            "dt-above-bound",
            sphere(),
            lobes.clone(),
            {
                let mut s = stiff(100.0);
                s.method.dt = Some(0.01);
                s.shot.fps = None;
                s
            },
            Expect::Refused("above the stable bound"),
        ),
        case(
            "bunny-ears-24",
            sphere(),
            bunny.clone(),
            with(&|s| s.body.resolution = 24),
            Expect::Stable,
        ),
        case(
            "bunny-ears-32",
            sphere(),
            bunny.clone(),
            with(&|s| s.body.resolution = 32),
            Expect::Stable,
        ),
        case(
            "thin-rod",
            sphere(),
            scaled(&cube(2.0, 4), Vector3::new(12.0, 1.0, 1.0)),
            with(&|s| s.body.resolution = 32),
            Expect::Stable,
        ),
        case(
            "far-apart-as-given",
            sphere(),
            sphere().transformed(1.0, &Vector3::new(10.0, 0.0, 0.0)),
            with(&|s| s.body.target_fit = TargetFit::AsGiven),
            Expect::Refused("cannot move its centre of mass"),
        ),
        case(
            // 32 cells across a plate 20 times wider than thick: about 1.3 cells thick.
            "plate-thinner-than-two-cells",
            sphere(),
            scaled(&cube(2.0, 4), Vector3::new(10.0, 10.0, 0.5)),
            with(&|s| s.body.resolution = 32),
            Expect::Stable,
        ),
        case("units-1e-4", tiny_s, tiny_t, quick(), Expect::Stable),
        case("units-1e4", huge_s, huge_t, quick(), Expect::Stable),
        case(
            "sphere-to-torus",
            sphere(),
            torus(1.0, 0.4, 32, 16),
            quick(),
            Expect::Stable,
        ),
        case(
            "two-lobes-to-sphere",
            lobes.clone(),
            sphere(),
            quick(),
            Expect::Stable,
        ),
        case(
            "sphere-to-two-blobs",
            sphere(),
            blobs,
            quick(),
            Expect::Stable,
        ),
        case(
            "source-equals-target",
            sphere(),
            sphere(),
            quick(),
            Expect::Stable,
        ),
        case(
            "learning-rate-x100",
            sphere(),
            lobes.clone(),
            with(&|s| s.method.optimizer.learning_rate *= 100.0),
            Expect::Stable,
        ),
        case(
            "chain-40-segments",
            sphere(),
            lobes.clone(),
            with(&|s| {
                s.body.resolution = 12;
                s.method.segments = 40;
                s.method.optimizer.iterations = 2;
                // Every segment aims at the target, so the body arrives early and the chain
                // is mostly holding: what this case checks is that holding stays bounded.
                s.shot.at = vec![1];
            }),
            Expect::Stable,
        ),
        case(
            "segment-300-steps",
            sphere(),
            lobes.clone(),
            with(&|s| {
                s.body.resolution = 12;
                s.method.segments = 1;
                s.method.steps_per_segment = 300;
                s.method.control_stride = 30;
                s.shot.frame_every = 10;
                s.shot.fps = None;
            }),
            Expect::Stable,
        ),
    ];
    // The long ones: a 300,000-particle morph within 4 GB, and the default preset on the
    // bunny's ears.
    let mut big = MorphSettings::preset(Preset::Draft);
    big.body.particles = Some(300_000);
    big.method.segments = 2;
    big.method.optimizer.iterations = 4;
    big.outputs.surfaces = crate::morph::settings::Surfaces::None;
    all.push(Case {
        long: true,
        memory_limit: MemoryLimit::Bytes(4 << 30),
        ..case(
            "particles-300k",
            sphere(),
            bunny.clone(),
            big,
            Expect::Stable,
        )
    });
    Ok(all)
}

/// How the gradient norm of one segment grows with its horizon: `(steps, first norm)` for a
/// segment of each length from the same start (the sphere toward two lobes at 12 cells).
pub fn horizon_study(steps: &[usize]) -> Result<Vec<(usize, f64, f64)>, MorphError> {
    let mut out = Vec::new();
    for &n in steps {
        let mut s = quick();
        s.body.resolution = 12;
        s.method.segments = 1;
        s.method.steps_per_segment = n;
        s.method.control_stride = 10.min(n);
        s.shot.frame_every = n;
        s.shot.fps = None;
        s.method.optimizer.iterations = 2;
        let c = Case {
            name: "horizon",
            source: sphere(),
            target: two_lobes(24, 32),
            settings: s,
            expect: Expect::Stable,
            long: false,
            memory_limit: MemoryLimit::Auto,
        };
        let m = measure(&c)?;
        let (first, last) = m
            .grad_norms
            .first()
            .copied()
            .unwrap_or((f64::NAN, f64::NAN));
        out.push((n, first, last));
    }
    Ok(out)
}

/// `morph bench-hard-cases`: every case (the long ones too when `long`), one JSON line each,
/// then the horizon study; fails when a case did not do what it should.
pub fn run(meshes: &Path, long: bool) -> anyhow::Result<()> {
    let mut failures = Vec::new();
    for case in cases(meshes)?.into_iter().filter(|c| long || !c.long) {
        let outcome = run_case(&case);
        println!("{}", serde_json::to_string(&outcome)?);
        if let Err(e) = outcome.check(&case.expect) {
            failures.push(e);
        }
    }
    for (steps, first, last) in horizon_study(&[30, 100, 300, 1000])? {
        println!(
            "{}",
            serde_json::json!({"study": "gradient-vs-horizon", "steps": steps, "grad_norm_first": first, "grad_norm_last": last})
        );
    }
    if failures.is_empty() {
        Ok(())
    } else {
        anyhow::bail!(
            "{} hard cases failed: {}",
            failures.len(),
            failures.join("; ")
        )
    }
}
