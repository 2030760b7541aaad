//! `morph SOURCE TARGET`: the main job. Parses options into the library's settings (every
//! default comes from [`MorphSettings::preset`]), watches SIGINT/SIGTERM, and reports progress
//! as a bar or JSON lines.

use super::{choice, defaults, help, name};
use clap::Args;
use morph::basis::ControlResolution;
use morph::engine::integrator::IntegratorKind;
use morph::engine::material::MaterialModel;
use morph::engine::mpm::ControlForm;
use morph::geometry::TargetFit;
use morph::gpu::{DeviceKind, Precision};
use morph::loss::MassLossKind;
use morph::memory::MemoryLimit;
use morph::scene_file::SceneFile;
use morph::segment::Optimizer;
use morph::settings::{Inbetween, RebuiltMethod, Surfaces, UsdFormat, limits};
use morph::{CheckedSettings, MorphSettings, Preset};
use std::path::PathBuf;

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
            let detail = s
                .body
                .particles
                .map_or(format!("r{}", s.body.resolution), |n| {
                    format!("{}k particles", n / 1000)
                });
            format!(
                "  {name:<8}{detail}, {:>2} x {}, {} pass(es), {:>2}, look-ahead {}; {}",
                s.method.segments,
                s.method.steps_per_segment,
                s.method.passes,
                s.method.optimizer.iterations,
                s.method.lookahead,
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
    #[arg(long, help = help("Grid cells across the domain's longest side", Some(limits::RESOLUTION), by_preset(|s| s.body.particles.map_or(s.body.resolution.to_string(), |_| "from the budget".into()))))]
    resolution: Option<usize>,
    #[arg(long, conflicts_with = "resolution", help = help("Particle budget: picks the resolution so the source gets about this many particles, whatever the shapes' proportions", Some(limits::PARTICLES), by_preset(|s| s.body.particles.map_or("off".to_string(), |n| n.to_string()))))]
    particles: Option<usize>,
    #[arg(long, help = help("Segments in the chain", Some(limits::SEGMENTS), by_preset(|s| s.method.segments)))]
    segments: Option<usize>,
    #[arg(long, help = help("Simulation steps per segment (dt 1/120 s at the reference resolution)", Some(limits::STEPS), defaults().method.steps_per_segment))]
    steps: Option<usize>,
    #[arg(long, help = format!("Steps between control layers in a segment [range 1 to --steps; default {}]", defaults().method.control_stride))]
    control_stride: Option<usize>,
    #[arg(long, help = help("Passes over the chain (later passes refine the earlier controls)", Some(limits::PASSES), by_preset(|s| s.method.passes)))]
    passes: Option<usize>,
    #[arg(long, help = help("Optimizer evaluations per segment (Adam) or per control layer (line search)", Some(limits::ITERATIONS), by_preset(|s| s.method.optimizer.iterations)))]
    iterations: Option<usize>,
    #[arg(long, help = help("Coarse-to-fine levels: n > 1 solves the morph on grids 2^(n-1), ..., 2 times coarser first, each level starting from the one below (docs/morph.md)", Some(limits::LEVELS), by_preset(|s| s.method.levels)))]
    levels: Option<usize>,
    #[arg(long, help = help("Optimizer evaluations per segment on the finest level when --levels > 1 (the coarser levels take --iterations)", Some(limits::ITERATIONS), "the same as --iterations"))]
    refine_iterations: Option<usize>,
    /// Optimizer [default adam].
    #[arg(long, value_parser = choice(&Optimizer::ALL))]
    optimizer: Option<Optimizer>,
    #[arg(long, help = help("Step size (Adam: per control entry; line search: initial normalized step), > 0", None, format!("{} (line search {})", Optimizer::Adam.default_learning_rate(), Optimizer::LineSearch.default_learning_rate())))]
    learning_rate: Option<f64>,
    #[arg(long, value_parser = choice(&MassLossKind::ALL), help = format!("Mass loss on the grid [default {}]", name(&defaults().method.loss)))]
    loss: Option<MassLossKind>,
    #[arg(long, help = help("Weight of the kinetic energy left at the end of each segment after the final target's arrival (the held shape comes to rest), >= 0", None, defaults().method.arrival_weight))]
    arrival_weight: Option<f64>,
    #[arg(long, help = help("Drag per second added once the final target is reached, eased in over six frames (the held shape comes to rest), >= 0 (0: off)", None, defaults().method.settle_drag))]
    settle_drag: Option<f64>,
    #[arg(long, help = help("Weight of the volume cost (sum 1/2 (ln J)^2 per particle, and the whole body's) averaged over every step, >= 0 (keeps the body at its volume)", None, defaults().method.volume_weight))]
    volume_weight: Option<f64>,
    #[arg(long, help = help("Weight of the scheduled path: the mass loss at every frame inside a segment against where the easing curve puts the body then, >= 0 (0: each segment's end alone)", None, by_preset(|s| s.method.path_weight)))]
    path_weight: Option<f64>,
    #[arg(long, help = help("Look-ahead: optimize each segment together with the next N, scored at each of their ends, and keep its own controls (the body answers its controls a segment late; docs/morph.md)", Some(limits::LOOKAHEAD), by_preset(|s| s.method.lookahead)))]
    lookahead: Option<usize>,
    #[arg(long, help = help("Weight of the controls' continuity in time: each control layer against the one before it, across segment boundaries too, scaled by the material's shear modulus over the presets' material's, >= 0 (0: off)", None, by_preset(|s| s.method.control_smoothing)))]
    control_smoothing: Option<f64>,
    #[arg(long, help = help("Weight of each earlier segment end inside a look-ahead window, against that segment's target (the window's end weighs 1), >= 0", None, by_preset(|s| s.method.waypoint_weight)))]
    waypoint_weight: Option<f64>,
    #[arg(long, help = help("Where a look-ahead window's new segment starts: this share of the last control layer before it, 0..=1 (0: zeros; with --control-smoothing only)", None, by_preset(|s| s.method.carry_controls)))]
    carry_controls: Option<f64>,
    #[arg(long, help = help("Weight of the mass loss on a grid twice as fine as the simulation's, >= 0 (sees holes and clumps within a cell)", None, defaults().method.fine_weight))]
    fine_weight: Option<f64>,
    #[arg(long, help = help("Weight of the reach cost: where the body should have the final target's shape, each part of the target's surface farther than 0.75 spacings from every particle pulls the nearest one, >= 0 (0: off; 10 reaches horns and ears: docs/morph.md, \"Reach\")", None, by_preset(|s| s.method.reach_weight)))]
    reach_weight: Option<f64>,
    #[arg(long, value_parser = choice(&TargetFit::ALL), help = format!("How each target is placed (on-ground needs a scene's ground) [default {}]", name(&defaults().body.target_fit)))]
    target_fit: Option<TargetFit>,
    #[arg(long, help = help("Particles per cell along each axis (k^3 per cell; at `default` raised to 3 or 4 where the shapes have thin parts, docs/morph.md; giving it or --resolution keeps it as given)", Some(limits::PARTICLES_PER_CELL), defaults().body.particles_per_cell))]
    particles_per_cell: Option<usize>,
    #[arg(long, help = help("Random particle offsets, in particle spacings, 0 to 1", None, defaults().body.jitter))]
    jitter: Option<f64>,
    #[arg(long, value_parser = choice(&MaterialModel::ALL), help = format!("Constitutive model of the body [default {}]", name(&defaults().body.material.model)))]
    material: Option<MaterialModel>,
    #[arg(long, help = format!("Young's modulus of the body in Pa, > 0 (stiffer: more substeps) [default {:.0}]", default_young_poisson().0))]
    youngs_modulus: Option<f64>,
    #[arg(long, help = format!("Poisson's ratio of the body, 0 to 0.49 [default {:.2}]", default_young_poisson().1))]
    poisson_ratio: Option<f64>,
    #[arg(long, help = help("Density of the body in kg per cubic simulation unit, > 0", None, defaults().body.material.density))]
    density: Option<f64>,
    /// Simulation time step in seconds, one per step; refused above the material's stability
    /// bound (the error gives it) [default: steps of 1/120 s, each split into the substeps
    /// the material and grid need].
    #[arg(long)]
    dt: Option<f64>,
    #[arg(long, value_parser = choice(&IntegratorKind::ALL), help = format!("Time integrator: euler (one transfer round trip a step) or rk4 (four, less numerical damping) [default {}]", name(&defaults().method.integrator)))]
    integrator: Option<IntegratorKind>,
    #[arg(long, value_parser = choice(&DeviceKind::ALL), help = format!("Where the engine runs: cpu, gpu (the Euler step in f64 through Vulkan, Metal or DX12; an error says what is missing) or auto (a GPU, not a software driver, where one opens and runs the scene, else the CPU) [default {}]", name(&defaults().method.device)))]
    device: Option<DeviceKind>,
    #[arg(long, value_parser = choice(&Precision::ALL), help = format!("The GPU device's precision: f64 (the CPU engine's, where the adapter has 64-bit floats) or f32 (consumer GPUs run f64 at 1/32-1/64 of the rate) [default {}]", name(&defaults().method.precision)))]
    precision: Option<Precision>,
    #[arg(long, value_parser = choice(&ControlForm::ALL), help = format!("How a control acts on a particle's deformation: plastic (a volume-preserving change of its rest shape: J stays the volume ratio) or additive (the reference paper's F + Fc, for comparison) [default {}]", name(&defaults().method.control)))]
    control: Option<ControlForm>,
    #[arg(long, value_parser = choice(&ControlResolution::ALL), help = format!("Where the optimizer's free control values live: grid (one per grid node, interpolated to the particles: smooth controls keep the body's particles in order) or particle (one per particle, the reference) [default {}]", name(&defaults().method.control_resolution)))]
    control_resolution: Option<ControlResolution>,
    #[arg(long, help = format!("Seed for the jitter [default {}]", defaults().body.seed))]
    seed: Option<u64>,
    #[arg(long, help = help("Export every n-th step as a frame, instead of --fps", Some(limits::FRAME_EVERY), defaults().shot.frame_every))]
    frame_every: Option<usize>,
    #[arg(long, help = help("Number of the first frame (the rest shape) in file names and USD time codes, e.g. a shot's 1001; --at still counts from 1", Some(limits::START_FRAME), defaults().shot.start_frame))]
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
    #[arg(long, help = help("The frame the shape change begins on (1 = the rest shape). Before it the body runs without controls: it holds still, or falls and lands under the scene's gravity; the easing curve toward the first keyframe starts here, and the motion measures count from here", None, defaults().shot.begin))]
    begin: Option<usize>,
    #[arg(long, value_parser = choice(&Surfaces::ALL), help = format!("Surfaces per frame: carried (the source mesh itself, with its UVs and groups, following the body; carried/), rebuilt (a closed surface made from the particles, which follows any change of topology; meshes/), both, all (both, and the last target's own mesh carried backward from the last frame, with its UVs: target_carried/; the shot ends on the target asset), or none [default {}]", name(&defaults().outputs.surfaces)))]
    surface: Option<Surfaces>,
    #[arg(long, value_parser = choice(&RebuiltMethod::ALL), help = format!("How the rebuilt surface is made: sharp (deformed, with its vertices moved onto the source's planes the particles carry: sharp edges and corners), deformed (each particle's kernel follows its deformation; smooth, rounds edges), lattice (0.2.0's narrow round kernels; shows the particles as bumps) or splashsurf (the fluid surfacer's pipeline, recommended settings; positions only) [default {}]", name(&defaults().outputs.rebuilt_method)))]
    rebuilt_method: Option<RebuiltMethod>,
    #[arg(long, value_parser = choice(&Inbetween::ALL), help = format!("What a segment aims at between two keyframes: crossfade (their nodal masses faded into each other) or shape (their signed distances blended: a boundary that sweeps from one to the other) [{}]", by_preset(|s| name(&s.method.inbetween))))]
    inbetween: Option<Inbetween>,
    #[arg(long, help = help("How far the schedule is re-timed so the shape in-between's own progress (its IoU gain toward the next keyframe) follows the easing curve, 0..=1 (0: the easing weight as it is)", None, by_preset(|s| s.method.progress_timing)))]
    progress_timing: Option<f64>,
    #[arg(long, value_parser = choice(&UsdFormat::ALL), help = format!("The USD file of the whole sequence: usdc (binary, morph.usdc), usda (text, morph.usda; about five times larger) or none [default {}]", name(&defaults().outputs.usd)))]
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
    let m = defaults().body.material;
    morph::engine::material::young_poisson_from_lame(m.mu, m.lambda)
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
    pub fn job(&self) -> Result<(CheckedSettings, PathBuf, Vec<PathBuf>), String> {
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
        // The settings are made here, so they are checked here, once.
        Ok((self.settings(settings)?.checked()?, source, targets))
    }

    /// `base` (the preset's, or the scene file's) with the options given on the command line.
    fn settings(&self, base: MorphSettings) -> Result<MorphSettings, String> {
        let mut s = base;
        self.apply_counts(&mut s);
        self.apply_method(&mut s);
        self.apply_physics(&mut s)?;
        self.apply_shot(&mut s)?;
        self.apply_choices(&mut s);
        Ok(s)
    }

    /// The particles, the grid and the chain's counts.
    fn apply_counts(&self, s: &mut MorphSettings) {
        // A resolution replaces the preset's particle budget; a budget replaces both.
        if let Some(r) = self.resolution {
            s.body.resolution = r;
            s.body.particles = None;
            s.body.thin_across = 0.0;
        }
        if self.particles.is_some() {
            s.body.particles = self.particles;
        }
        set(&mut s.method.segments, self.segments);
        set(&mut s.method.steps_per_segment, self.steps);
        set(&mut s.method.control_stride, self.control_stride);
        set(&mut s.method.passes, self.passes);
        set(&mut s.method.optimizer.iterations, self.iterations);
        set(&mut s.method.levels, self.levels);
        if self.refine_iterations.is_some() {
            s.method.refine_iterations = self.refine_iterations;
        }
        if let Some(k) = self.particles_per_cell {
            s.body.particles_per_cell = k;
            s.body.thin_across = 0.0;
        }
        set(&mut s.shot.start_frame, self.start_frame);
        if let Some(n) = self.frame_every {
            // A frame every n steps replaces the frame rate.
            s.shot.frame_every = n;
            s.shot.fps = None;
        }
    }

    /// The optimizer and the objective's weights.
    fn apply_method(&self, s: &mut MorphSettings) {
        if let Some(o) = self.optimizer {
            s.method.optimizer.kind = o;
            s.method.optimizer.learning_rate = o.default_learning_rate();
        }
        if let Some(lr) = self.learning_rate {
            s.method.optimizer.learning_rate = lr;
        }
        if let Some(w) = self.path_weight {
            s.method.path_weight = w;
        }
        if let Some(w) = self.control_smoothing {
            s.method.control_smoothing = w;
        }
        if let Some(w) = self.waypoint_weight {
            s.method.waypoint_weight = w;
        }
        if let Some(c) = self.carry_controls {
            s.method.carry_controls = c;
        }
        if let Some(n) = self.lookahead {
            s.method.lookahead = n;
        }
        if let Some(w) = self.fine_weight {
            s.method.fine_weight = w;
        }
        if let Some(w) = self.reach_weight {
            s.method.reach_weight = w;
        }
        if let Some(w) = self.volume_weight {
            s.method.volume_weight = w;
        }
        if let Some(w) = self.arrival_weight {
            s.method.arrival_weight = w;
        }
        if let Some(d) = self.settle_drag {
            s.method.settle_drag = d;
        }
        if let Some(j) = self.jitter {
            s.body.jitter = j;
        }
    }

    /// The material, the control and the integrator.
    fn apply_physics(&self, s: &mut MorphSettings) -> Result<(), String> {
        if let Some(m) = self.material {
            s.body.material.model = m;
        }
        if let Some(c) = self.control {
            s.method.control = c;
        }
        if let Some(r) = self.control_resolution {
            s.method.control_resolution = r;
        }
        if let Some(i) = self.integrator {
            s.method.integrator = i;
        }
        if let Some(d) = self.device {
            s.method.device = d;
        }
        if let Some(p) = self.precision {
            s.method.precision = p;
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
            (s.body.material.mu, s.body.material.lambda) =
                morph::engine::material::lame_from_young_poisson(e, nu);
        }
        if let Some(d) = self.density {
            s.body.material.density = d;
        }
        Ok(())
    }

    /// The shot's timing, keyframes and seed.
    fn apply_shot(&self, s: &mut MorphSettings) -> Result<(), String> {
        if self.dt.is_some() {
            // A set dt is the step: frames come every --frame-every of them.
            s.method.dt = self.dt;
            s.shot.fps = None;
        }
        if self.fps.is_some() {
            s.shot.fps = self.fps;
        }
        if self.frames.is_some() {
            s.shot.frames = self.frames;
        }
        if let Some(seconds) = self.seconds {
            s.shot.frames = Some(s.frames_for(seconds)?);
        }
        if self.segments.is_some() {
            // --segments replaces a scene's frame count, as --frames replaces its segments.
            s.shot.frames = None;
        }
        if !self.at.is_empty() {
            s.shot.at = self.at.clone();
        }
        if let Some(b) = self.begin {
            s.shot.begin = b;
        }
        if let Some(seed) = self.seed {
            s.body.seed = seed;
        }
        Ok(())
    }

    /// The loss, the target's fit, the in-between and the outputs.
    fn apply_choices(&self, s: &mut MorphSettings) {
        if let Some(loss) = self.loss {
            s.method.loss = loss;
        }
        if let Some(fit) = self.target_fit {
            s.body.target_fit = fit;
        }
        if let Some(m) = self.inbetween {
            s.method.inbetween = m;
        }
        if let Some(t) = self.progress_timing {
            s.method.progress_timing = t;
        }
        if let Some(m) = self.rebuilt_method {
            s.outputs.rebuilt_method = m;
        }
        if let Some(surfaces) = self.surface {
            s.outputs.surfaces = surfaces;
        }
        if self.no_surfaces {
            s.outputs.surfaces = Surfaces::None;
        }
        if let Some(usd) = self.usd {
            s.outputs.usd = usd;
        }
        if self.volume {
            s.outputs.volume = true;
        }
    }
}

/// `*dst = v` when the option was given.
fn set(dst: &mut usize, v: Option<usize>) {
    if let Some(v) = v {
        *dst = v;
    }
}

mod report;
mod run;

pub use run::run;
