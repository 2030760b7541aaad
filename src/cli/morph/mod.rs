//! `morph SOURCE TARGET`: the main job. Parses options into the library's settings (every
//! default comes from [`MorphSettings::preset`]), watches SIGINT/SIGTERM, and reports progress
//! as a bar or JSON lines.

use super::{choice, defaults, help, name};
use clap::Args;
use morph::engine::material::MaterialModel;
use morph::geometry::TargetFit;
use morph::gpu::DeviceKind;
use morph::memory::MemoryLimit;
use morph::scene_file::SceneFile;
use morph::settings::{Surfaces, UsdFormat, limits};
use morph::{CheckedSettings, MorphSettings, Preset};
use std::ffi::OsString;
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
look-ahead; measured quality and time: docs/accuracy.md, Presets):
{presets}
  --resolution, --particles and any knob (--set KEY=VALUE; `morph help method` lists them)
  override the preset's value (--resolution replaces a budget).

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
  morph sphere.obj bunny.obj -o bunny_morph --set iterations=20 --set reach_weight=10  # knobs
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

/// The main job: `morph SOURCE TARGET [options]`. The options are an artist's, under five
/// headings; the method's knobs are `--set KEY=VALUE` (`morph help method`).
#[derive(Args, Debug)]
pub struct MorphArgs {
    /// Mesh to start from, then the mesh(es) to become in order (OBJ or PLY; at most 1000
    /// targets): `morph A B`, or `morph A B C --at 48,96` to pass through B on the way to C.
    #[arg(value_name = "SOURCE TARGET...")]
    meshes: Vec<PathBuf>,
    #[arg(long, help_heading = SHOT, conflicts_with = "seconds", help = help("Frames in the sequence, the rest shape first: the chain is cut into segments to fit (the last one shorter)", Some(limits::FRAMES), "the preset's segments"))]
    frames: Option<usize>,
    /// The shot's length in seconds instead of --frames: the frames that fill it at the frame
    /// rate, the rest shape first (4 s at 24 fps: 97 frames).
    #[arg(long, help_heading = SHOT)]
    seconds: Option<f64>,
    /// Frames per second of the sequence: frames exactly 1/FPS s apart, each the fewest equal
    /// steps of at most 1/120 s (24: 5 steps of 1/120 s; 25: 5 of 1/125 s) [default 24].
    #[arg(long, help_heading = SHOT)]
    fps: Option<f64>,
    /// The frame (1 = the rest shape) by which each target is reached, comma-separated in
    /// target order (--arrive for one target). The shape eases there along a smoothstep in
    /// time, then holds and settles; 1 aims at the target from the start [default: the last
    /// target at 80% of the frames, earlier ones evenly before it].
    #[arg(long, help_heading = SHOT, visible_alias = "arrive", value_delimiter = ',')]
    at: Vec<usize>,
    #[arg(long, help_heading = SHOT, help = help("The frame the shape change begins on (1 = the rest shape). Before it the body runs without controls: it holds still, or falls and lands under the scene's gravity", None, defaults().shot.begin))]
    begin: Option<usize>,
    #[arg(long, help_heading = SHOT, help = help("Number of the first frame (the rest shape) in file names and USD time codes, e.g. a shot's 1001; --at still counts from 1", Some(limits::START_FRAME), defaults().shot.start_frame))]
    start_frame: Option<usize>,
    #[arg(long, help_heading = QUALITY, value_parser = choice(&Preset::ALL), help = format!("Effort preset: draft, default or final (below: what each costs) [default {}]", name(&Preset::default())))]
    preset: Option<Preset>,
    #[arg(long, help_heading = QUALITY, help = help("Grid cells across the domain's longest side", Some(limits::RESOLUTION), by_preset(|s| s.body.particles.map_or(s.body.resolution.to_string(), |_| "from the budget".into()))))]
    resolution: Option<usize>,
    #[arg(long, help_heading = QUALITY, conflicts_with = "resolution", help = help("Particle budget: picks the resolution so the source gets about this many particles, whatever the shapes' proportions", Some(limits::PARTICLES), by_preset(|s| s.body.particles.map_or("off".to_string(), |n| n.to_string()))))]
    particles: Option<usize>,
    /// A method knob, KEY=VALUE (repeatable): `--set iterations=20 --set path_weight=0.5`.
    /// `morph help method` lists every knob with its default and range; a scene file's
    /// [method] table takes the same keys.
    #[arg(long = "set", help_heading = QUALITY, value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// A scene file (TOML, or JSON): the meshes and any settings, by the settings' names
    /// (docs/scenes.md); options given here override it.
    #[arg(long, help_heading = SCENE)]
    scene: Option<PathBuf>,
    #[arg(long, help_heading = SCENE, value_parser = choice(&MaterialModel::ALL), help = format!("Constitutive model of the body [default {}]", name(&defaults().body.material.model)))]
    material: Option<MaterialModel>,
    #[arg(long, help_heading = SCENE, help = format!("Young's modulus of the body in Pa, > 0 (stiffer: more substeps) [default {:.0}]", default_young_poisson().0))]
    youngs_modulus: Option<f64>,
    #[arg(long, help_heading = SCENE, help = format!("Poisson's ratio of the body, 0 to 0.49 [default {:.2}]", default_young_poisson().1))]
    poisson_ratio: Option<f64>,
    #[arg(long, help_heading = SCENE, help = help("Density of the body in kg per cubic simulation unit, > 0", None, defaults().body.material.density))]
    density: Option<f64>,
    #[arg(long, help_heading = SCENE, value_parser = choice(&TargetFit::ALL), help = format!("How each target is placed (on-ground needs a scene's ground) [default {}]", name(&defaults().body.target_fit)))]
    target_fit: Option<TargetFit>,
    /// Output folder (a new folder, an empty one, or an earlier morph output with --overwrite).
    #[arg(short, long, help_heading = OUTPUT, default_value = "morph-out")]
    output: PathBuf,
    /// Replace the output folder if morph provably wrote it (its manifest.json is morph's and
    /// lists every file there; nothing else is ever replaced); also starts over from an
    /// interrupted run's OUT.partial, once the new inputs have loaded.
    #[arg(long, help_heading = OUTPUT)]
    overwrite: bool,
    /// Continue an interrupted run (same inputs and settings) from OUT.partial; starts afresh
    /// when there is nothing to continue, and does nothing when OUT is already complete. With
    /// --overwrite, a run of other inputs or settings is started over instead of refused.
    #[arg(long, help_heading = OUTPUT)]
    resume: bool,
    #[arg(long, help_heading = OUTPUT, value_parser = choice(&Surfaces::ALL), help = format!("Surfaces per frame: carried (the source mesh itself, with its UVs and groups, following the body; carried/), rebuilt (a closed surface made from the particles, which follows any change of topology; meshes/), both, all (both, and the last target's own mesh carried backward from the last frame, with its UVs: target_carried/), or none [default {}]", name(&defaults().outputs.surfaces)))]
    surface: Option<Surfaces>,
    #[arg(long, help_heading = OUTPUT, value_parser = choice(&UsdFormat::ALL), help = format!("The USD file of the whole sequence: usdc (binary, morph.usdc), usda (text, morph.usda; about five times larger) or none [default {}]", name(&defaults().outputs.usd)))]
    usd: Option<UsdFormat>,
    /// Write each frame's fill field (1 inside the body, 1/2 on its surface) as an OpenVDB
    /// float grid `density` in world units, volumes/frame_0001.vdb ..., and a Volume prim in
    /// the USD file that reads them.
    #[arg(long, help_heading = OUTPUT)]
    volume: bool,
    #[arg(long, help_heading = RUN, value_parser = choice(&DeviceKind::ALL), help = format!("Where the engine runs: cpu, gpu (the Euler step through Vulkan, Metal or DX12; an error says what is missing) or auto (a GPU, not a software driver, where one runs the scene, else the CPU) [default {}]", name(&defaults().method.device)))]
    device: Option<DeviceKind>,
    /// Print one JSON object per event on stdout (for farm logs) instead of progress bars;
    /// a failure ends the stream with an `error` event.
    #[arg(long, help_heading = RUN)]
    json: bool,
    /// Print nothing but errors.
    #[arg(long, short, help_heading = RUN)]
    quiet: bool,
    /// How progress is shown: bar (a progress bar on a terminal) or openjd (Open Job
    /// Description's lines on stdout for a render farm: `openjd_progress: <percent>`,
    /// `openjd_status: <message>`, and `openjd_fail: <message>` when the run fails).
    #[arg(long, help_heading = RUN, value_enum, default_value_t = ProgressShown::Bar, conflicts_with = "json")]
    progress: ProgressShown,
    /// Cap on the run's memory, e.g. 200M or 4G, at most the machine's (or its container's)
    /// memory: segments then keep checkpoints and recompute instead of holding every step
    /// (same results, more time). auto: a quarter of the memory this process may use.
    #[arg(long, help_heading = RUN, default_value = "auto", value_parser = parse_memory_limit)]
    memory_limit: MemoryLimit,
}

/// The option headings of `morph --help`.
const SHOT: &str = "Shot";
const QUALITY: &str = "Quality";
const SCENE: &str = "Physics and scene";
const OUTPUT: &str = "Output";
pub(super) const RUN: &str = "Run and farm";

/// Options of earlier versions that are method knobs now, and the knob each sets: given on
/// the command line they are read as `--set KEY=VALUE` (scripts and farm templates keep
/// working; `morph --help` shows `--set`).
const KNOB_OPTIONS: &[&str] = &[
    "segments",
    "steps",
    "control-stride",
    "passes",
    "iterations",
    "levels",
    "refine-iterations",
    "optimizer",
    "learning-rate",
    "loss",
    "arrival-weight",
    "settle-drag",
    "volume-weight",
    "path-weight",
    "lookahead",
    "control-smoothing",
    "waypoint-weight",
    "carry-controls",
    "fine-weight",
    "reach-weight",
    "particles-per-cell",
    "jitter",
    "dt",
    "integrator",
    "precision",
    "control",
    "control-resolution",
    "seed",
    "frame-every",
    "rebuilt-method",
    "inbetween",
    "progress-timing",
];

/// The main job's arguments with each knob option (`--iterations 4`, `--iterations=4`) as
/// `--set iterations=4`, and `--no-surfaces` as `--set surfaces=none` (an argument that is
/// not text is passed as it is).
pub fn knob_options_as_set(args: Vec<OsString>) -> Vec<OsString> {
    let mut out: Vec<OsString> = Vec::with_capacity(args.len());
    let mut it = args.into_iter();
    while let Some(arg) = it.next() {
        let Some(text) = arg.to_str() else {
            out.push(arg);
            continue;
        };
        if text == "--" {
            out.push(arg);
            out.extend(it);
            break;
        }
        if text == "--no-surfaces" {
            out.extend(["--set".into(), "surfaces=none".into()]);
            continue;
        }
        let flag = text.strip_prefix("--").unwrap_or("");
        let (name, inline) = match flag.split_once('=') {
            Some((n, v)) => (n, Some(OsString::from(v))),
            None => (flag, None),
        };
        if !KNOB_OPTIONS.contains(&name) {
            out.push(arg);
            continue;
        }
        let mut pair = OsString::from(format!("{}=", name.replace('-', "_")));
        pair.push(inline.or_else(|| it.next()).unwrap_or_default());
        out.extend(["--set".into(), pair]);
    }
    out
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

    /// `base` (the preset's, or the scene file's) with the knobs set (`--set`), then the
    /// options given on the command line.
    fn settings(&self, base: MorphSettings) -> Result<MorphSettings, String> {
        // A knob by any of its spellings: `frame_every`, `shot.frame-every`.
        let sets = |key: &str| {
            (self.set.iter()).any(|p| {
                let given = p.split('=').next().unwrap_or("").trim();
                given.rsplit('.').next().map(|k| k.replace('-', "_")) == Some(key.into())
            })
        };
        // What an option decides, a knob must not decide too.
        if self.fps.is_some() && sets("frame_every") {
            return Err("--fps and `frame_every` cannot be combined: a frame every n steps replaces the frame rate".into());
        }
        if (self.frames.is_some() || self.seconds.is_some()) && sets("segments") {
            return Err("--frames (or --seconds) and `segments` cannot be combined: the frames decide the segments".into());
        }
        let mut s = morph::scene_file::with_keys(base, &self.set)?;
        // A resolution replaces the preset's particle budget; a budget replaces both.
        if let Some(r) = self.resolution {
            s.body.resolution = r;
            s.body.particles = None;
            s.body.thin_across = 0.0;
        }
        if self.particles.is_some() {
            s.body.particles = self.particles;
        }
        set(&mut s.shot.start_frame, self.start_frame);
        self.apply_physics(&mut s)?;
        self.apply_shot(&mut s)?;
        self.apply_outputs(&mut s);
        Ok(s)
    }

    /// The material and the device.
    fn apply_physics(&self, s: &mut MorphSettings) -> Result<(), String> {
        if let Some(m) = self.material {
            s.body.material.model = m;
        }
        if let Some(d) = self.device {
            s.method.device = d;
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
        if let Some(fit) = self.target_fit {
            s.body.target_fit = fit;
        }
        Ok(())
    }

    /// The shot's timing and keyframes.
    fn apply_shot(&self, s: &mut MorphSettings) -> Result<(), String> {
        if self.fps.is_some() {
            s.shot.fps = self.fps;
        }
        if self.frames.is_some() {
            s.shot.frames = self.frames;
        }
        if let Some(seconds) = self.seconds {
            s.shot.frames = Some(s.frames_for(seconds)?);
        }
        if !self.at.is_empty() {
            s.shot.at = self.at.clone();
        }
        if let Some(b) = self.begin {
            s.shot.begin = b;
        }
        Ok(())
    }

    /// The outputs.
    fn apply_outputs(&self, s: &mut MorphSettings) {
        if let Some(surfaces) = self.surface {
            s.outputs.surfaces = surfaces;
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
