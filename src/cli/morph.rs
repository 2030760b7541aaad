//! `morph SOURCE TARGET`: the main job. Parses options into the library's settings (every
//! default comes from [`MorphSettings::preset`]), watches SIGINT/SIGTERM, and reports progress
//! as a bar or JSON lines.

use super::{choice, defaults, fail, help, name};
use clap::Args;
use morph::basis::ControlResolution;
use morph::geometry::TargetFit;
use morph::integrator::IntegratorKind;
use morph::loss::MassLossKind;
use morph::material::MaterialModel;
use morph::memory::MemoryLimit;
use morph::mpm::ControlForm;
use morph::scene_file::SceneFile;
use morph::segment::Optimizer;
use morph::settings::{Inbetween, RebuiltMethod, Surfaces, UsdFormat, limits};
use morph::{MorphError, MorphEvent, MorphSettings, Preset};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicUsize;

pub const LONG_ABOUT: &str = "\
morph turns the shape in SOURCE into the shape in TARGET: SOURCE is filled with particles of an
elastic material, simulated with a differentiable Material Point Method, and steered by
optimized per-particle controls until it flows into TARGET. The result is a folder with a
frame sequence for Blender or Houdini.

SOURCE and TARGET are OBJ or PLY meshes in any units and position; open meshes (holes) are
accepted. TARGET is scaled to SOURCE's volume and centred on it unless --target-fit as-given.
More targets make keyframes (--at). A scene file (--scene, docs/scenes.md) adds gravity, a
ground, colliders and any setting.";

pub(super) const AFTER_LONG_HELP: &str = "\
OUTPUT (folder -o, written in the locked OUT.partial and put in place when complete):
  frames/frame_0001.ply ...  binary PLY points per frame: x y z vx vy vz J id, source units
  meshes/frame_0001.obj ...  clean closed surface rebuilt per frame, source units
  final_mass.mgrid           final nodal mass grid; compare two with `morph compare`
  manifest.json              inputs with SHA-256, settings, placement, losses, timings, frames
  run.json                   what decides the result: tool version, input hashes, settings
  scene.toml                 the resolved scene: `morph --scene OUT/scene.toml` reruns it
  loss.png, preview.png      loss curves; a contact sheet of frames
  preview.gif                the sequence animated at its fps
  carried/frame_0001.obj ... the source mesh carried through the morph (--surface)
  volumes/frame_0001.vdb ... the fill field per frame as an OpenVDB density grid (--volume)
  morph.usdc                 the whole sequence in one USD file (points, both surfaces, the
                             volume; --usd usda for text)
  -o is checked before any work; --overwrite replaces only a folder morph provably wrote (its
  manifest.json is morph's and lists every file in it), never anything else; a second run on
  the same -o fails at once. Each completed segment is checkpointed in OUT.partial (sealed
  with the run id and SHA-256: a damaged checkpoint is refused by name).

PRESETS (resolution or particle budget, segments x steps, passes, iterations per segment,
look-ahead; measured quality and time from docs/morph.md, 2 cores):
{presets}
  Any of --resolution --particles --segments --steps --passes --iterations --levels
  --refine-iterations --lookahead --path-weight --waypoint-weight --control-smoothing
  --carry-controls --inbetween --progress-timing overrides its preset value (--resolution
  replaces a budget).

EXIT CODES:
  0    success (every written file checked finite)
  1    the run failed (bad mesh, simulation, writing, output folder in use, an
       optimization that could not work: a non-finite objective, or no segment moved)
  2    bad command line, option value, output folder or memory limit (refused before
       any work)
  130  interrupted by SIGINT (Ctrl-C), 143 by SIGTERM, 129 by SIGHUP, 141 by a closed
       stdout: completed segments are kept in OUT.partial; the same command with --resume
       continues bit for bit

EXAMPLES:
  morph assets/sphere.obj assets/two-lobes.obj -o out
  morph sphere.obj bunny.obj -o bunny_morph --preset final --json > log.jsonl
  morph sphere.obj cube.obj bunny.obj -o keys --at 48,96 --frames 120  # through a cube
  morph --scene examples/fall-onto-floor.toml -o fall                   # a scene file
  morph sphere.obj bunny.obj -o bunny_morph --preset final --resume   # after an interruption
  morph compare out/final_mass.mgrid golden/final_mass.mgrid --rtol 1e-6";

const PRESETS: [(Preset, &str); 3] = [
    (Preset::Draft, "draft"),
    (Preset::Default, "default"),
    (Preset::Final, "final"),
];

/// A preset-dependent default, read from the library: "draft 6, default 12, final 40".
fn by_preset<T: std::fmt::Display>(value: impl Fn(&MorphSettings) -> T) -> String {
    let parts: Vec<String> = PRESETS
        .iter()
        .map(|(p, name)| format!("{name} {}", value(&MorphSettings::preset(*p))))
        .collect();
    format!("by preset: {}", parts.join(", "))
}

pub(super) fn after_long_help() -> String {
    let presets: Vec<String> = PRESETS
        .iter()
        .map(|(p, name)| {
            let s = MorphSettings::preset(*p);
            let detail = s.particles.map_or(format!("r{}", s.resolution), |n| {
                format!("{}k particles", n / 1000)
            });
            format!(
                "  {name:<8}{detail}, {:>2} x {}, {} pass(es), {:>2}, look-ahead {}; {}",
                s.segments,
                s.steps_per_segment,
                s.passes,
                s.optimizer.iterations,
                s.lookahead,
                p.measured()
            )
        })
        .collect();
    AFTER_LONG_HELP.replace("{presets}", &presets.join("\n"))
}

/// How `morph` shows a run's progress (`--json` prints every event instead).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum ProgressShown {
    Bar,
    Openjd,
}

/// The main job: `morph SOURCE TARGET [options]`.
#[derive(Args, Debug)]
pub struct MorphArgs {
    /// Mesh to start from, then the mesh(es) to become in order (OBJ or PLY; at most 1000
    /// targets): `morph A B`, or `morph A B C --at 48,96` to pass through B on the way to C.
    #[arg(value_name = "SOURCE TARGET...")]
    meshes: Vec<PathBuf>,
    /// A scene file (TOML, or JSON): the meshes and any settings, by the settings' names
    /// (docs/scenes.md); options given here override it.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Output folder (a new folder, an empty one, or an earlier morph output with --overwrite).
    #[arg(short, long, default_value = "morph-out")]
    output: PathBuf,
    /// Replace the output folder if morph provably wrote it (its manifest.json is morph's and
    /// lists every file there; nothing else is ever replaced); also starts over from an
    /// interrupted run's OUT.partial, once the new inputs have loaded.
    #[arg(long)]
    overwrite: bool,
    /// Continue an interrupted run (same inputs and settings) from OUT.partial; starts afresh
    /// when there is nothing to continue, and does nothing when OUT is already complete. With
    /// --overwrite, a run of other inputs or settings is started over instead of refused.
    #[arg(long)]
    resume: bool,
    #[arg(long, value_parser = choice(&Preset::ALL), help = format!("Effort preset; the options below override its values [default {}]", name(&Preset::default())))]
    preset: Option<Preset>,
    #[arg(long, help = help("Grid cells across the domain's longest side", Some(limits::RESOLUTION), by_preset(|s| s.particles.map_or(s.resolution.to_string(), |_| "from the budget".into()))))]
    resolution: Option<usize>,
    #[arg(long, conflicts_with = "resolution", help = help("Particle budget: picks the resolution so the source gets about this many particles, whatever the shapes' proportions", Some(limits::PARTICLES), by_preset(|s| s.particles.map_or("off".to_string(), |n| n.to_string()))))]
    particles: Option<usize>,
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
    #[arg(long, help = help("Coarse-to-fine levels: n > 1 solves the morph on grids 2^(n-1), ..., 2 times coarser first, each level starting from the one below (docs/morph.md)", Some(limits::LEVELS), by_preset(|s| s.levels)))]
    levels: Option<usize>,
    #[arg(long, help = help("Optimizer evaluations per segment on the finest level when --levels > 1 (the coarser levels take --iterations)", Some(limits::ITERATIONS), "the same as --iterations"))]
    refine_iterations: Option<usize>,
    /// Optimizer [default adam].
    #[arg(long, value_parser = choice(&Optimizer::ALL))]
    optimizer: Option<Optimizer>,
    #[arg(long, help = help("Step size (Adam: per control entry; line search: initial normalized step), > 0", None, format!("{} (line search {})", Optimizer::Adam.default_learning_rate(), Optimizer::LineSearch.default_learning_rate())))]
    learning_rate: Option<f64>,
    #[arg(long, value_parser = choice(&MassLossKind::ALL), help = format!("Mass loss on the grid [default {}]", name(&defaults().loss)))]
    loss: Option<MassLossKind>,
    #[arg(long, help = help("Weight of the kinetic energy left at the end of each segment after the final target's arrival (the held shape comes to rest), >= 0", None, defaults().arrival_weight))]
    arrival_weight: Option<f64>,
    #[arg(long, help = help("Drag per second added once the final target is reached, eased in over six frames (the held shape comes to rest), >= 0 (0: off)", None, defaults().settle_drag))]
    settle_drag: Option<f64>,
    #[arg(long, help = help("Weight of the volume cost (sum 1/2 (ln J)^2 per particle, and the whole body's) averaged over every step, >= 0 (keeps the body at its volume)", None, defaults().volume_weight))]
    volume_weight: Option<f64>,
    #[arg(long, help = help("Weight of the scheduled path: the mass loss at every frame inside a segment against where the easing curve puts the body then, >= 0 (0: each segment's end alone)", None, by_preset(|s| s.path_weight)))]
    path_weight: Option<f64>,
    #[arg(long, help = help("Look-ahead: optimize each segment together with the next N, scored at each of their ends, and keep its own controls (the body answers its controls a segment late; docs/morph.md)", Some(limits::LOOKAHEAD), by_preset(|s| s.lookahead)))]
    lookahead: Option<usize>,
    #[arg(long, help = help("Weight of the controls' continuity in time: each control layer against the one before it, across segment boundaries too, scaled by the material's shear modulus over the presets' material's, >= 0 (0: off)", None, by_preset(|s| s.control_smoothing)))]
    control_smoothing: Option<f64>,
    #[arg(long, help = help("Weight of each earlier segment end inside a look-ahead window, against that segment's target (the window's end weighs 1), >= 0", None, by_preset(|s| s.waypoint_weight)))]
    waypoint_weight: Option<f64>,
    #[arg(long, help = help("Where a look-ahead window's new segment starts: this share of the last control layer before it, 0..=1 (0: zeros; with --control-smoothing only)", None, by_preset(|s| s.carry_controls)))]
    carry_controls: Option<f64>,
    #[arg(long, help = help("Weight of the mass loss on a grid twice as fine as the simulation's, >= 0 (sees holes and clumps within a cell)", None, defaults().fine_weight))]
    fine_weight: Option<f64>,
    #[arg(long, help = help("Weight of the reach cost: where the body should have the final target's shape, each part of the target's surface farther than 0.75 spacings from every particle pulls the nearest one, >= 0 (0: off; 10 reaches horns and ears: docs/morph.md, \"Reach\")", None, by_preset(|s| s.reach_weight)))]
    reach_weight: Option<f64>,
    #[arg(long, value_parser = choice(&TargetFit::ALL), help = format!("How each target is placed (on-ground needs a scene's ground) [default {}]", name(&defaults().target_fit)))]
    target_fit: Option<TargetFit>,
    #[arg(long, help = help("Particles per cell along each axis (k^3 per cell; at `default` raised to 3 or 4 where the shapes have thin parts, docs/morph.md; giving it or --resolution keeps it as given)", Some(limits::PARTICLES_PER_CELL), defaults().particles_per_cell))]
    particles_per_cell: Option<usize>,
    #[arg(long, help = help("Random particle offsets, in particle spacings, 0 to 1", None, defaults().jitter))]
    jitter: Option<f64>,
    #[arg(long, value_parser = choice(&MaterialModel::ALL), help = format!("Constitutive model of the body [default {}]", name(&defaults().material.model)))]
    material: Option<MaterialModel>,
    #[arg(long, help = format!("Young's modulus of the body in Pa, > 0 (stiffer: more substeps) [default {:.0}]", default_young_poisson().0))]
    youngs_modulus: Option<f64>,
    #[arg(long, help = format!("Poisson's ratio of the body, 0 to 0.49 [default {:.2}]", default_young_poisson().1))]
    poisson_ratio: Option<f64>,
    #[arg(long, help = help("Density of the body in kg per cubic simulation unit, > 0", None, defaults().material.density))]
    density: Option<f64>,
    /// Simulation time step in seconds, one per step; refused above the material's stability
    /// bound (the error gives it) [default: steps of 1/120 s, each split into the substeps
    /// the material and grid need].
    #[arg(long)]
    dt: Option<f64>,
    #[arg(long, value_parser = choice(&IntegratorKind::ALL), help = format!("Time integrator: euler (one transfer round trip a step) or rk4 (four, less numerical damping) [default {}]", name(&defaults().integrator)))]
    integrator: Option<IntegratorKind>,
    #[arg(long, value_parser = choice(&ControlForm::ALL), help = format!("How a control acts on a particle's deformation: plastic (a volume-preserving change of its rest shape: J stays the volume ratio) or additive (the reference paper's F + Fc, for comparison) [default {}]", name(&defaults().control)))]
    control: Option<ControlForm>,
    #[arg(long, value_parser = choice(&ControlResolution::ALL), help = format!("Where the optimizer's free control values live: grid (one per grid node, interpolated to the particles: smooth controls keep the body's particles in order) or particle (one per particle, the reference) [default {}]", name(&defaults().control_resolution)))]
    control_resolution: Option<ControlResolution>,
    #[arg(long, help = format!("Seed for the jitter [default {}]", defaults().seed))]
    seed: Option<u64>,
    #[arg(long, help = help("Export every n-th step as a frame, instead of --fps", Some(limits::FRAME_EVERY), defaults().frame_every))]
    frame_every: Option<usize>,
    #[arg(long, help = help("Number of the first frame (the rest shape) in file names and USD time codes, e.g. a shot's 1001; --at still counts from 1", Some(limits::START_FRAME), defaults().start_frame))]
    start_frame: Option<usize>,
    /// Frames per second of the sequence: frames exactly 1/FPS s apart, each the fewest equal
    /// steps of at most 1/120 s (24: 5 steps of 1/120 s; 25: 5 of 1/125 s) [default 24;
    /// --frame-every or --dt replace it].
    #[arg(long, conflicts_with_all = ["frame_every", "dt"])]
    fps: Option<f64>,
    #[arg(long, conflicts_with = "segments", help = help("Frames in the sequence, the rest shape first: the chain is cut into segments of --steps steps to fit (the last one shorter)", Some(limits::FRAMES), "--segments segments"))]
    frames: Option<usize>,
    /// The shot's length in seconds instead of --frames: the frames that fill it at the frame
    /// rate, the rest shape first (4 s at 24 fps: 97 frames).
    #[arg(long, conflicts_with_all = ["segments", "frames"])]
    seconds: Option<f64>,
    /// The frame (1 = the rest shape) by which each target is reached, comma-separated in
    /// target order (--arrive for one target). The shape eases there along a smoothstep in
    /// time, then holds and settles; 1 aims at the target from the start [default: the last
    /// target at 80% of the frames, earlier ones evenly before it].
    #[arg(long, visible_alias = "arrive", value_delimiter = ',')]
    at: Vec<usize>,
    #[arg(long, help = help("The frame the shape change begins on (1 = the rest shape). Before it the body runs without controls: it holds still, or falls and lands under the scene's gravity; the easing curve toward the first keyframe starts here, and the motion measures count from here", None, defaults().begin))]
    begin: Option<usize>,
    #[arg(long, value_parser = choice(&Surfaces::ALL), help = format!("Surfaces per frame: carried (the source mesh itself, with its UVs and groups, following the body; carried/), rebuilt (a closed surface made from the particles, which follows any change of topology; meshes/), both, or none [default {}]", name(&defaults().surfaces)))]
    surface: Option<Surfaces>,
    #[arg(long, value_parser = choice(&RebuiltMethod::ALL), help = format!("How the rebuilt surface is made: sharp (deformed, with its vertices moved onto the source's planes the particles carry: sharp edges and corners), deformed (each particle's kernel follows its deformation; smooth, rounds edges), lattice (0.2.0's narrow round kernels; shows the particles as bumps) or splashsurf (the fluid surfacer's pipeline, recommended settings; positions only) [default {}]", name(&defaults().rebuilt_method)))]
    rebuilt_method: Option<RebuiltMethod>,
    #[arg(long, value_parser = choice(&Inbetween::ALL), help = format!("What a segment aims at between two keyframes: crossfade (their nodal masses faded into each other) or shape (their signed distances blended: a boundary that sweeps from one to the other) [{}]", by_preset(|s| name(&s.inbetween))))]
    inbetween: Option<Inbetween>,
    #[arg(long, help = help("How far the schedule is re-timed so the shape in-between's own progress (its IoU gain toward the next keyframe) follows the easing curve, 0..=1 (0: the easing weight as it is)", None, by_preset(|s| s.progress_timing)))]
    progress_timing: Option<f64>,
    #[arg(long, value_parser = choice(&UsdFormat::ALL), help = format!("The USD file of the whole sequence: usdc (binary, morph.usdc), usda (text, morph.usda; about five times larger) or none [default {}]", name(&defaults().usd)))]
    usd: Option<UsdFormat>,
    /// Write each frame's fill field (the field the rebuilt surface is made from; 1 inside the
    /// body, 1/2 on its surface) as an OpenVDB float grid `density` in world units,
    /// volumes/frame_0001.vdb ..., and a Volume prim in the USD file that reads them.
    #[arg(long)]
    volume: bool,
    /// Points only: the same as --surface none.
    #[arg(long, conflicts_with = "surface")]
    no_surfaces: bool,
    /// Print one JSON object per event on stdout (for farm logs) instead of progress bars;
    /// a failure ends the stream with an `error` event.
    #[arg(long)]
    json: bool,
    /// Print nothing but errors.
    #[arg(long, short)]
    quiet: bool,
    /// How progress is shown: bar (a progress bar on a terminal) or openjd (Open Job
    /// Description's lines on stdout for a render farm: `openjd_progress: <percent>`,
    /// `openjd_status: <message>`, and `openjd_fail: <message>` when the run fails).
    #[arg(long, value_enum, default_value_t = ProgressShown::Bar, conflicts_with = "json")]
    progress: ProgressShown,
    /// Cap on the run's memory, e.g. 200M or 4G, at most the machine's (or its container's)
    /// memory: segments then keep checkpoints and recompute instead of holding every step
    /// (same results, more time). auto: a quarter of the memory this process may use.
    #[arg(long, default_value = "auto", value_parser = parse_memory_limit)]
    memory_limit: MemoryLimit,
}

fn parse_memory_limit(s: &str) -> Result<MemoryLimit, String> {
    s.parse()
}

/// The default material as Young's modulus and Poisson's ratio.
fn default_young_poisson() -> (f64, f64) {
    let m = defaults().material;
    morph::material::young_poisson_from_lame(m.mu, m.lambda)
}

impl MorphArgs {
    /// The settings, the source and the targets: the scene file's (when given), with the
    /// command line's options and meshes over them.
    /// The output folder (`-o`).
    pub fn output(&self) -> &std::path::Path {
        &self.output
    }

    /// Whether `--quiet` was given (no summary, no warnings).
    pub fn quiet(&self) -> bool {
        self.quiet
    }

    /// Whether `--overwrite` was given.
    pub fn overwrite(&self) -> bool {
        self.overwrite
    }

    /// The settings, source and targets these options ask for (a scene file read over its
    /// preset, then each option given).
    pub fn job(&self) -> Result<(MorphSettings, PathBuf, Vec<PathBuf>), String> {
        let (settings, mut source, mut targets) = match &self.scene {
            Some(path) => {
                let scene = SceneFile::read(path, self.preset)?;
                (scene.settings, scene.source, scene.targets)
            }
            None => (
                MorphSettings::preset(self.preset.unwrap_or_default()),
                None,
                Vec::new(),
            ),
        };
        match self.meshes.as_slice() {
            [] => {}
            [_] => {
                return Err("give a SOURCE and at least one TARGET mesh (see morph --help)".into());
            }
            [first, rest @ ..] => {
                source = Some(first.clone());
                targets = rest.to_vec();
            }
        }
        let Some(source) = source else {
            return Err(
                "give a SOURCE and a TARGET mesh, or a --scene file that names them (see morph --help)"
                    .into(),
            );
        };
        if targets.is_empty() {
            return Err(match &self.scene {
                Some(p) => format!(
                    "scene file '{}' names no targets; give `targets = [\"mesh.obj\"]`",
                    p.display()
                ),
                None => "give a TARGET mesh after the SOURCE (see morph --help)".into(),
            });
        }
        Ok((self.settings(settings)?, source, targets))
    }

    fn settings(&self, base: MorphSettings) -> Result<MorphSettings, String> {
        let mut s = base;
        let set = |dst: &mut usize, v: Option<usize>| {
            if let Some(v) = v {
                *dst = v;
            }
        };
        // A resolution replaces the preset's particle budget; a budget replaces both.
        if let Some(r) = self.resolution {
            s.resolution = r;
            s.particles = None;
            s.thin_across = 0.0;
        }
        if self.particles.is_some() {
            s.particles = self.particles;
        }
        set(&mut s.segments, self.segments);
        set(&mut s.steps_per_segment, self.steps);
        set(&mut s.control_stride, self.control_stride);
        set(&mut s.passes, self.passes);
        set(&mut s.optimizer.iterations, self.iterations);
        set(&mut s.levels, self.levels);
        if self.refine_iterations.is_some() {
            s.refine_iterations = self.refine_iterations;
        }
        if let Some(k) = self.particles_per_cell {
            s.particles_per_cell = k;
            s.thin_across = 0.0;
        }
        set(&mut s.start_frame, self.start_frame);
        if let Some(n) = self.frame_every {
            // A frame every n steps replaces the frame rate.
            s.frame_every = n;
            s.fps = None;
        }
        if let Some(o) = self.optimizer {
            s.optimizer.kind = o;
            s.optimizer.learning_rate = o.default_learning_rate();
        }
        if let Some(lr) = self.learning_rate {
            s.optimizer.learning_rate = lr;
        }
        if let Some(w) = self.path_weight {
            s.path_weight = w;
        }
        if let Some(w) = self.control_smoothing {
            s.control_smoothing = w;
        }
        if let Some(w) = self.waypoint_weight {
            s.waypoint_weight = w;
        }
        if let Some(c) = self.carry_controls {
            s.carry_controls = c;
        }
        if let Some(n) = self.lookahead {
            s.lookahead = n;
        }
        if let Some(w) = self.fine_weight {
            s.fine_weight = w;
        }
        if let Some(w) = self.reach_weight {
            s.reach_weight = w;
        }
        if let Some(w) = self.volume_weight {
            s.volume_weight = w;
        }
        if let Some(w) = self.arrival_weight {
            s.arrival_weight = w;
        }
        if let Some(d) = self.settle_drag {
            s.settle_drag = d;
        }
        if let Some(j) = self.jitter {
            s.jitter = j;
        }
        if let Some(m) = self.material {
            s.material.model = m;
        }
        if let Some(c) = self.control {
            s.control = c;
        }
        if let Some(r) = self.control_resolution {
            s.control_resolution = r;
        }
        if let Some(i) = self.integrator {
            s.integrator = i;
        }
        if self.youngs_modulus.is_some() || self.poisson_ratio.is_some() {
            let (e0, nu0) = default_young_poisson();
            let e = self.youngs_modulus.unwrap_or(e0);
            let nu = self.poisson_ratio.unwrap_or(nu0);
            if !(e.is_finite() && e > 0.0) {
                return Err(format!(
                    "--youngs-modulus must be a positive number, got {e}"
                ));
            }
            if !(0.0..=0.49).contains(&nu) {
                return Err(format!(
                    "--poisson-ratio must be between 0 and 0.49, got {nu}"
                ));
            }
            (s.material.mu, s.material.lambda) = morph::material::lame_from_young_poisson(e, nu);
        }
        if let Some(d) = self.density {
            s.material.density = d;
        }
        if self.dt.is_some() {
            // A set dt is the step: frames come every --frame-every of them.
            s.dt = self.dt;
            s.fps = None;
        }
        if self.fps.is_some() {
            s.fps = self.fps;
        }
        if self.frames.is_some() {
            s.frames = self.frames;
        }
        if let Some(seconds) = self.seconds {
            s.frames = Some(s.frames_for(seconds)?);
        }
        if self.segments.is_some() {
            // --segments replaces a scene's frame count, as --frames replaces its segments.
            s.frames = None;
        }
        if !self.at.is_empty() {
            s.at = self.at.clone();
        }
        if let Some(b) = self.begin {
            s.begin = b;
        }
        if let Some(seed) = self.seed {
            s.seed = seed;
        }
        if let Some(loss) = self.loss {
            s.loss = loss;
        }
        if let Some(fit) = self.target_fit {
            s.target_fit = fit;
        }
        if let Some(m) = self.inbetween {
            s.inbetween = m;
        }
        if let Some(t) = self.progress_timing {
            s.progress_timing = t;
        }
        if let Some(m) = self.rebuilt_method {
            s.rebuilt_method = m;
        }
        if let Some(surfaces) = self.surface {
            s.surfaces = surfaces;
        }
        if self.no_surfaces {
            s.surfaces = Surfaces::None;
        }
        if let Some(usd) = self.usd {
            s.usd = usd;
        }
        if self.volume {
            s.volume = true;
        }
        Ok(s)
    }
}

/// SIGINT, SIGTERM and SIGHUP (a closed terminal or SSH session) set `stop` to the signal's
/// number: the run stops at its next evaluation and keeps its checkpoint. A second signal
/// while stopping exits at once, with its line (and, with `--json`, its `interrupted` event)
/// written from the handler: the checkpoint's files are written under temporary names and
/// renamed, so the last one a resume needs is whole. SIGPIPE is ignored so that a closed stdout
/// (a log reader that went away) is seen as a failed write, which stops the run the same way.
fn stop_on_signals(json: bool, staging: &std::path::Path) -> std::io::Result<Arc<AtomicUsize>> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    // SAFETY: setting one signal's disposition to "ignore" is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
    let stop = Arc::new(AtomicUsize::new(0));
    let stopping = Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [SIGINT, SIGTERM, SIGHUP] {
        let code = 128 + sig;
        let message = format!(
            "interrupted again by {} while stopping: exited at once; the last checkpoint in '{}', if one was written, is kept for --resume",
            signal_name(sig as usize),
            staging.display()
        );
        // Made now: the handler only writes bytes (no allocation, no lock).
        let line = format!("morph: {message}\n").into_bytes();
        let event = json.then(|| {
            let e = serde_json::json!({ "event": "interrupted", "signal": signal_name(sig as usize), "message": message, "exit_code": code });
            format!("{e}\n").into_bytes()
        });
        let again = Arc::clone(&stopping);
        let second = move || {
            if again.load(std::sync::atomic::Ordering::SeqCst) {
                // SAFETY: write(2) and _exit(2) are async-signal-safe; the buffers are owned
                // by this closure and never change.
                unsafe {
                    libc::write(2, line.as_ptr().cast(), line.len());
                    if let Some(e) = &event {
                        libc::write(1, e.as_ptr().cast(), e.len());
                    }
                    libc::_exit(code);
                }
            }
        };
        // SAFETY: the action does only async-signal-safe work (see above).
        unsafe { signal_hook::low_level::register(sig, second)? };
        signal_hook::flag::register(sig, Arc::clone(&stopping))?;
        signal_hook::flag::register_usize(sig, Arc::clone(&stop), sig as usize)?;
    }
    Ok(stop)
}

fn signal_name(signal: usize) -> &'static str {
    match signal as i32 {
        signal_hook::consts::SIGINT => "SIGINT",
        signal_hook::consts::SIGTERM => "SIGTERM",
        signal_hook::consts::SIGHUP => "SIGHUP (the terminal closed)",
        libc::SIGPIPE => "SIGPIPE (stdout was closed)",
        _ => "a signal",
    }
}

/// `morph SOURCE TARGET`: progress bars on a terminal, JSON lines with --json.
pub fn run(args: &MorphArgs) -> ExitCode {
    use indicatif::{ProgressBar, ProgressStyle};
    use std::io::IsTerminal;
    // The library checks the settings (morph_to_folder, before the folder is touched).
    let (settings, source, targets) = match args.job() {
        Ok(j) => j,
        Err(e) => return fail_run(args, 2, &e),
    };
    let stop = match stop_on_signals(args.json, &morph::io::outdir::partial_dir(&args.output)) {
        Ok(s) => s,
        Err(e) => return fail_run(args, 1, &format!("cannot watch for signals: {e}")),
    };
    let openjd = args.progress == ProgressShown::Openjd;
    let show_bar = !args.quiet && !args.json && !openjd && std::io::stderr().is_terminal();
    // Open Job Description progress: the percent when its first decimal changes; 100 only
    // once every file is written.
    let mut meter = morph::progress::ProgressMeter::new();
    let mut shown_percent = String::new();
    let bar = ProgressBar::hidden();
    let mut last_loss = f64::NAN;
    let on_event = |e: &MorphEvent| {
        if args.json {
            use std::io::Write;
            let line = serde_json::to_string(e).expect("plain event");
            if writeln!(std::io::stdout(), "{line}").is_err() {
                // Nobody reads the events any more: stop as for a signal, keeping the work.
                stop.store(libc::SIGPIPE as usize, std::sync::atomic::Ordering::Relaxed);
            }
            return;
        }
        if openjd {
            let percent = format!("{:.1}", 100.0 * meter.observe(e).min(0.999));
            // With --resume, setup and a level's start know no progress yet (a resumed run's
            // starts at its checkpoint): shown from the first step or segment on, so it never
            // goes back. A fresh run starts at 0.
            let measured =
                !args.resume || !matches!(e, MorphEvent::Setup { .. } | MorphEvent::Level { .. });
            if measured && percent != shown_percent {
                say!("openjd_progress: {percent}");
                shown_percent = percent;
            }
            match e {
                MorphEvent::Setup {
                    particles,
                    segments,
                    passes,
                    ..
                } => say!(
                    "openjd_status: morphing {particles} particles: {segments} segments x {passes} passes"
                ),
                MorphEvent::Level { level, levels, .. } => {
                    say!("openjd_status: level {level} of {levels}")
                }
                MorphEvent::Segment { pass, segment, .. } => {
                    let (passes, segments) = meter.level_plan();
                    say!(
                        "openjd_status: pass {} of {passes}, segment {} of {segments} done",
                        pass + 1,
                        segment + 1
                    )
                }
                MorphEvent::Done { .. } => say!("openjd_status: writing the whole-sequence files"),
                MorphEvent::Iteration { .. } => {}
            }
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
            MorphEvent::Level {
                level,
                levels,
                particles,
                grid_cells,
                segments,
                iterations,
            } => {
                if show_bar {
                    bar.set_position(0);
                    bar.set_length((segments * iterations) as u64);
                    bar.println(format!(
                        "morph: level {level} of {levels}: {particles} particles on a {}x{}x{} grid",
                        grid_cells[0], grid_cells[1], grid_cells[2]
                    ));
                }
            }
            MorphEvent::Segment { .. } | MorphEvent::Done { .. } => {}
        }
    };
    let request = morph::output::OutputRequest {
        out: &args.output,
        overwrite: args.overwrite,
        resume: args.resume,
        stop: Some(&stop),
        memory_limit: args.memory_limit,
        scene: args.scene.as_deref(),
        on_frame: None,
    };
    let result = morph::output::morph_to_folder(&settings, &source, &targets, &request, on_event);
    bar.finish_and_clear();
    match result {
        Ok(summary) => {
            if args.progress == ProgressShown::Openjd {
                say!("openjd_progress: 100.0");
            }
            if args.json {
                say!(
                    "{}",
                    serde_json::json!({ "event": "written", "summary": summary })
                );
            } else if !args.quiet {
                if summary.already_complete {
                    say!(
                        "{} is already complete for these inputs and settings; nothing to do",
                        summary.output.display()
                    );
                    return ExitCode::SUCCESS;
                }
                if let Some(from) = &summary.resumed_from {
                    say!("resumed from the checkpoint ({from})");
                }
                say!(
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
                if let Some(z) = &summary.sizing {
                    say!("{}", sizing_line(z));
                }
                if let Some(o) = &summary.optimization {
                    say!(
                        "optimization: {} evaluations, {} steps undone (they raised the objective or blew the simulation up), {} of {} segments moved (loss down by {}% or more)",
                        o.evaluations,
                        o.undone_steps,
                        o.segments_moved,
                        o.segments,
                        100.0 * morph::MOVED_SHARE
                    );
                }
                if let Some(q) = &summary.quality {
                    say!(
                        "quality: IoU with the target {:.3}, fill {:.3} (1 = a lattice fill of the target; of its material {:.3}), surface gap {:.2} spacings, reach {:.2} (99%) and {:.2} (most) spacings (a lattice fill's {:.2} and {:.2}), ejected {:.2}%, close neighbours {:.1}%, J {:.2} to {:.2} (mean {:.2}, {:.2}% inverted)",
                        q.iou,
                        q.fill,
                        q.material_fill,
                        q.surface_gap,
                        q.reach_p99,
                        q.reach_max,
                        q.perfect_reach_p99,
                        q.perfect_reach_max,
                        100.0 * q.ejected,
                        100.0 * q.close_share,
                        q.min_j,
                        q.max_j,
                        q.mean_j,
                        100.0 * q.inverted
                    );
                }
                if let Some(l) = summary
                    .frames_summary
                    .as_ref()
                    .and_then(|f| f.surfaces.as_ref())
                    .and_then(|s| s.likeness.as_ref())
                {
                    say!("{}", likeness_line(l));
                }
                if let Some(m) = &summary.motion {
                    let ease = m
                        .ease_error
                        .map_or("n/a".to_string(), |e| format!("{e:.2}"));
                    let from = if m.first_frame > 1 {
                        format!(
                            " (from frame {}, where the shape change begins)",
                            m.first_frame
                        )
                    } else {
                        String::new()
                    };
                    say!(
                        "motion: pulse {:.2}, dip {:.2}, wobble {:.2}, settle {:.2}, ease error {ease}, {} frozen frames{from}",
                        m.pulse,
                        m.dip,
                        m.wobble,
                        m.settle,
                        m.frozen_frames
                    );
                }
                if let Some(f) = &summary.frames_summary {
                    let volume = f.max_surface_volume_error.map_or(String::new(), |e| {
                        format!("; surface volume within {:.1}% of the body's", 100.0 * e)
                    });
                    say!(
                        "all frames: J {:.3} to {:.3}, {} frames with inverted particles, close neighbours at most {:.1}%{volume}",
                        f.min_j,
                        f.max_j,
                        f.frames_inverted,
                        100.0 * f.max_close_share
                    );
                    if let Some(line) = f.surfaces.as_ref().and_then(surfaces_line) {
                        say!("surfaces: {line}");
                    }
                    if f.frames_inverted > 0 {
                        eprintln!(
                            "morph: warning: particles turned inside out (J <= 0) in {} frames; see the frames' min_j in manifest.json",
                            f.frames_inverted
                        );
                    }
                }
            }
            if !args.quiet {
                for w in &summary.warnings {
                    eprintln!("morph: warning: {w}");
                }
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
                say!(
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
            fail_run(args, code, &e.to_string())
        }
    }
}

/// The summary's particles line: what the thin parts' rule chose and why.
fn sizing_line(z: &morph::sizing::Sizing) -> String {
    let name = std::path::Path::new(&z.thinnest)
        .file_name()
        .map_or(z.thinnest.clone(), |n| n.to_string_lossy().into_owned());
    let mut line = format!(
        "particles: {} per cell, the thinnest parts ({name}'s) {:.1} particles across (about {:.0} particles)",
        z.per_cell, z.across, z.particles
    );
    if z.wanted_per_cell > z.per_cell {
        line += &format!(
            "; {} per cell would give them {:.1} across with about {:.0} particles, over the budget of {} (--particles-per-cell {} or --particles {:.0} asks for them)",
            z.wanted_per_cell,
            z.across / z.per_cell as f64 * z.wanted_per_cell as f64,
            z.wanted_particles,
            morph::sizing::DETAIL_BUDGET,
            z.wanted_per_cell,
            z.wanted_particles
        );
    }
    line
}

/// The summary's likeness line: what a render of the last frame's rebuilt surface shows
/// against the target.
fn likeness_line(l: &morph::geometry::likeness::Likeness) -> String {
    let [x, y, z] = l.silhouette_iou;
    let (worst, direction) = l.worst_tips();
    format!(
        "likeness: silhouette IoU {x:.3} / {y:.3} / {z:.3} (seen along x / y / z), tips {:.1}% of the target's size from the surface at the top and {:.1}% at worst ({direction}; 90th percentile of its {:.0}% farthest vertices each way)",
        100.0 * l.top_tips(),
        100.0 * worst,
        100.0 * morph::geometry::likeness::TIP_SHARE
    )
}

/// The summary's surfaces line: each surface against its reference (normal deviation, share
/// beyond 20 degrees), the carried surface's folds and the rebuilt one's creases against frame
/// 1's; `None` where no surface was measured.
fn surfaces_line(s: &morph::output::SurfaceSummary) -> Option<String> {
    let against = |what: &str, f: &Option<morph::geometry::fidelity::Fidelity>| {
        f.map(|f| {
            format!(
                "{what} {:.1} deg ({:.1}% beyond 20)",
                f.mean_normal_deg,
                100.0 * f.off_share
            )
        })
    };
    // The largest share over the frames, beside the body at rest's.
    let worst = |what: &str, most: Option<f64>, rest: &str, at_rest: Option<f64>| {
        most.map(|m| {
            let r = at_rest.unwrap_or(0.0);
            format!(
                "{what} at most {:.2}% ({rest} {:.2}%)",
                100.0 * m,
                100.0 * r
            )
        })
    };
    let parts: Vec<String> = [
        against("rebuilt frame 1 from the source", &s.rebuilt_first),
        against("rebuilt last frame from the target", &s.rebuilt_last),
        against("carried last frame from the target", &s.carried_last),
        worst(
            "carried folds",
            s.max_carried_fold_share,
            "the source",
            s.source_fold_share,
        ),
        worst(
            "rebuilt creases",
            s.max_rebuilt_crease_share,
            "frame 1",
            s.rebuilt_first_crease_share,
        ),
    ]
    .into_iter()
    .flatten()
    .collect();
    (!parts.is_empty()).then(|| parts.join(", "))
}

/// A failed run: the one-line error (and with `--json` its event, with `--progress openjd` the
/// farm's failure line).
fn fail_run(args: &MorphArgs, code: u8, message: &str) -> ExitCode {
    if args.progress == ProgressShown::Openjd {
        say!("openjd_fail: {message}");
    }
    fail(args.json, code, message)
}
