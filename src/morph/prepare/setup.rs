//! The pieces of [`Prepared::from_sized`], in the order it takes them: the particles within a
//! budget, the shot's timing, the effects, the substeps, the losses, the keyframes' masses,
//! the body's own path before the first keyframe, the coarser level.

use super::sim::{Sim, with_sim};
use super::{CheckedSettings, MorphError, MorphSettings, Prepared, settings};
use crate::engine::integrator::Integrator;
use crate::engine::mpm::{GridSpec, SimError, State};
use crate::engine::scene::{EffectConfig, SceneConfig, WorldMap};
use crate::geometry::{Jitter, LoadedMesh, MorphGeometry};
use crate::loss::{FINE_KERNEL, FineMassLoss, MassLoss};
use crate::morph::reach::ReachLoss;
use nalgebra::Vector3;
use std::path::Path;

/// The source filled at the settings' resolution, or with `--particles` at the resolution
/// whose count comes nearest the budget (which the returned settings hold).
pub(super) fn geometry_in_budget(
    settings: &MorphSettings,
    source: (&LoadedMesh, &Path),
    targets: &[(&LoadedMesh, &Path)],
) -> Result<(MorphSettings, MorphGeometry), MorphError> {
    let jitter = (settings.body.jitter > 0.0).then_some(Jitter {
        amount: settings.body.jitter,
        seed: settings.body.seed,
    });
    let geometry_at = |resolution: usize| {
        let placement = settings.placement_options(resolution);
        MorphGeometry::with_keyframes(
            source,
            targets,
            &placement,
            settings.body.particles_per_cell,
            jitter,
        )
    };
    let mut settings = settings.clone();
    let Some(budget) = settings.body.particles else {
        let geometry = geometry_at(settings.body.resolution)?;
        return Ok((settings, geometry));
    };
    // Start from the resolution the shapes' volumes call for, then step one resolution at a
    // time toward the budget while the count gets closer: the count grows with the
    // resolution, so a larger budget never gets fewer particles.
    let limits = settings::limits::RESOLUTION;
    let mut r = Prepared::resolution_for_budget(&settings, source, targets)?;
    let mut best = geometry_at(r)?;
    let count = |g: &MorphGeometry| g.source.positions.len();
    let up = count(&best) < budget;
    for _ in 0..MAX_BUDGET_STEPS {
        let next = if up { r + 1 } else { r.saturating_sub(1) };
        if !limits.contains(&next) {
            break;
        }
        let g = geometry_at(next)?;
        if count(&g).abs_diff(budget) >= count(&best).abs_diff(budget) {
            break;
        }
        let crossed = (count(&g) >= budget) == up;
        (r, best) = (next, g);
        if crossed {
            break;
        }
    }
    settings.body.resolution = r;
    Ok((settings, best))
}

/// The settings with the shot's timing (`--fps`, `--frames`): the segments, the frame
/// spacing and, when none were given, the targets' arrival frames; checked again with them.
pub(super) fn timed(
    mut settings: MorphSettings,
    targets: usize,
) -> Result<(MorphSettings, settings::Timing), MorphError> {
    let shot = settings.timing();
    settings.method.segments = shot.segment_steps.len();
    settings.shot.frame_every = shot.frame_every;
    if settings.shot.at.is_empty() {
        // The last target near the end, earlier ones evenly before it.
        let last = settings::default_arrival(shot.frame_count());
        settings.shot.at = (1..=targets)
            .map(|k| 1 + (last - 1) * k / targets)
            .collect();
    }
    debug_assert_eq!(settings.validate(), Ok(()));
    Ok((settings, shot))
}

/// Substeps per morph step. Without a set dt, a morph step (1/120 s, or what --fps makes) is
/// split into the fewest equal substeps that keep each within half the elastic stability
/// bound: a stiffer material or a finer grid costs more substeps, never a shorter shot. A set
/// dt above the bound is refused, with the bound; so is physics no control can move.
pub(super) fn substeps(
    settings: &MorphSettings,
    scene: &SceneConfig,
    shot: &settings::Timing,
) -> Result<usize, MorphError> {
    let (limit, wave_speed) = scene.stable_dt();
    let segment_seconds =
        settings.method.dt.unwrap_or(shot.step) * settings.method.steps_per_segment as f64;
    if limit > segment_seconds {
        return Err(MorphError::Settings(format!(
            "the material is too soft for its density: its elastic waves ({wave_speed:.3e} grid units per second) cross {:.2e} grid cells in a segment of {segment_seconds:.3} s, less than one, so no control can move the body; raise --youngs-modulus or lower --density",
            segment_seconds / limit
        )));
    }
    let frame_seconds = settings.method.dt.unwrap_or(shot.step) * shot.frame_every as f64;
    for (name, drag) in [
        ("drag", settings.world.drag()),
        (
            "drag and settle drag",
            settings.world.drag() + settings.method.settle_drag,
        ),
    ] {
        if drag * frame_seconds > MAX_DRAG_DAMPING {
            return Err(MorphError::Settings(format!(
                "{name} {drag:.3e} leaves e^-{:.3e} of the body's speed from one frame to the next ({frame_seconds:.4} s apart), so nothing can move; use at most {:.3e}",
                drag * frame_seconds,
                MAX_DRAG_DAMPING / frame_seconds
            )));
        }
    }
    // The drag's explicit form keeps a share `1 - c dt` of the momentum each step: at most
    // half of it may go in one step.
    let most_drag = settings.world.drag() + settings.method.settle_drag;
    let limit = if most_drag > 0.0 {
        limit.min(1.0 / most_drag)
    } else {
        limit
    };
    match settings.method.dt {
        Some(dt) if dt > limit => Err(MorphError::Settings(format!(
            "`dt` {dt} is above the stable bound {limit:.4e} s of this material on this grid (elastic wave speed {wave_speed:.4} over a cell of {:.4}); use --set dt={:.4e} or less, or leave it out to substep automatically",
            scene.grid.dx,
            0.5 * limit
        ))),
        Some(_) => Ok(1),
        None => substeps_for(shot.step, 0.5 * limit).map_err(MorphError::Settings),
    }
}

/// The mass loss toward the final target, the fine grid's when its weight is positive, and
/// the reach cost when its weight is.
pub(super) fn losses(
    settings: &MorphSettings,
    geometry: &MorphGeometry,
) -> Result<(MassLoss, Option<FineMassLoss>, Option<ReachLoss>), MorphError> {
    let target = geometry.target_masses(settings.method.kernel, settings.body.material.density)?;
    let loss = MassLoss::new(settings.method.loss, target);
    let fine_loss = if settings.method.fine_weight > 0.0 {
        let grid = FineMassLoss::refine(&geometry.placement.grid, FINE_REFINE);
        let target =
            geometry.target_masses_on(&grid, FINE_KERNEL, settings.body.material.density)?;
        Some(FineMassLoss {
            grid,
            loss: MassLoss::new(settings.method.loss, target),
            weight: settings.method.fine_weight,
        })
    } else {
        None
    };
    let reach = (settings.method.reach_weight > 0.0).then(|| {
        let spacing = geometry.placement.grid.dx / settings.body.particles_per_cell as f64;
        ReachLoss::new(&geometry.target_sim, spacing, settings.method.reach_weight)
    });
    Ok((loss, fine_loss, reach))
}

/// The nodal masses of each keyframe target before the last, on the simulation grid and on
/// the fine loss's grid when there is one.
pub(super) fn keyframe_masses(
    settings: &MorphSettings,
    geometry: &MorphGeometry,
    grid: &GridSpec,
    fine_loss: Option<&FineMassLoss>,
) -> Result<Vec<super::KeyframeMasses>, SimError> {
    let density = settings.body.material.density;
    (0..geometry.keyframes.len())
        .map(|k| {
            let on_sim = geometry.keyframe_masses_on(k, grid, settings.method.kernel, density)?;
            let on_fine = match fine_loss {
                Some(f) => Some(geometry.keyframe_masses_on(k, &f.grid, FINE_KERNEL, density)?),
                None => None,
            };
            Ok((on_sim, on_fine))
        })
        .collect()
}

/// The morph steps at which the body's own path before the first keyframe (at step `first`)
/// is kept: the segments' ends (and every frame when the path term needs it there), and the
/// step the shape change begins at.
pub(super) fn passive_ends(
    settings: &MorphSettings,
    shot: &settings::Timing,
    first: usize,
    begin: usize,
) -> Vec<usize> {
    let mut ends = Vec::new();
    let mut end = 0;
    for &n in &shot.segment_steps {
        if settings.method.path_weight > 0.0 {
            let every = settings.shot.frame_every;
            ends.extend((end + 1..end + n).filter(|s| s.is_multiple_of(every)));
        }
        end += n;
        if end >= first {
            break;
        }
        ends.push(end);
    }
    // The body's place where the shape change begins: the first section starts there.
    if begin > 0 && !ends.contains(&begin) {
        ends.push(begin);
        ends.sort_unstable();
    }
    ends.retain(|&s| s < first);
    ends
}

/// Where the body goes on its own (a run without controls from `initial`): its positions at
/// each of the morph steps `ends`.
pub(super) fn passive_path(
    engine: &Sim,
    initial: &State,
    ends: &[usize],
    substeps: usize,
) -> Result<Vec<super::PassivePoint>, SimError> {
    let mut passive = Vec::new();
    let Some(&last) = ends.last() else {
        return Ok(passive);
    };
    let mut state = initial.clone();
    let mut on_step = |k: usize, st: &State| {
        if (k + 1).is_multiple_of(substeps) && ends.contains(&((k + 1) / substeps)) {
            passive.push(((k + 1) / substeps, st.x.clone()));
        }
    };
    with_sim!(engine, sim => {
        let steps = crate::engine::integrator::Steps::new(0, last * substeps);
        let none = crate::engine::integrator::Controls::of_f(&[]);
        sim.forward_observed(&mut state, none, steps, None, Some(&mut on_step))
    })?;
    Ok(passive)
}

/// The same morph on a grid half as fine, when `settings.method.levels > 1`.
pub(super) fn coarse_level(
    settings: &MorphSettings,
    source: (&LoadedMesh, &Path),
    targets: &[(&LoadedMesh, &Path)],
) -> Result<Option<Box<Prepared>>, MorphError> {
    if settings.method.levels <= 1 {
        return Ok(None);
    }
    let mut below = settings.clone();
    below.body.resolution = settings.body.resolution.div_ceil(2);
    below.body.particles = None;
    below.body.thin_across = 0.0;
    below.method.levels -= 1;
    below.method.refine_iterations = None;
    below.outputs.surfaces = settings::Surfaces::None;
    // The coarsest level, checked here so the message names the levels asked for.
    let coarsest = (1..settings.method.levels).fold(settings.body.resolution, |r, _| r.div_ceil(2));
    let min = *settings::limits::RESOLUTION.start();
    if coarsest < min {
        return Err(MorphError::Settings(format!(
            "`levels` {} solves the morph on a grid of {coarsest} cells first, below the least resolution {min}: use fewer levels or a finer grid",
            settings.method.levels
        )));
    }
    let below = CheckedSettings::derived(below);
    Ok(Some(Box::new(Prepared::from_meshes(
        &below, source, targets,
    )?)))
}

/// The finer loss grid splits each simulation cell this many times per axis: one particle
/// per fine cell at the default two per cell.
pub const FINE_REFINE: usize = 2;

/// The most drag may damp the body between two frames, as an exponent: `e^-10` leaves
/// 0.005% of its speed, nothing a viewer could see move.
pub const MAX_DRAG_DAMPING: f64 = 10.0;

/// Resolutions `--particles` steps through from its estimate, at most.
const MAX_BUDGET_STEPS: usize = 8;

/// The morph's step when no dt is set: the reference's 1/120 s (simulated in substeps
/// where the material or the grid needs a shorter one).
pub const MORPH_STEP: f64 = 1.0 / 120.0;

/// Substeps past which a morph is refused (the material is too stiff for its grid).
pub const MAX_SUBSTEPS: usize = 10_000;

/// The effects a morph's settings call for, in the order they act: the world's, placed on the
/// grid by `placement` (the engine's own specs: `EffectConfig::placed`), with the settle drag
/// after the air's drag from the final target's arrival on. Nothing else runs.
pub(super) fn scene_effects(
    settings: &MorphSettings,
    placement: &crate::geometry::Placement,
    shot: &settings::Timing,
) -> Vec<EffectConfig> {
    let map = WorldMap {
        scale: placement.world_to_sim.scale,
        translation: placement.world_to_sim.translation,
    };
    let mut effects: Vec<EffectConfig> = (settings.world.effects.iter())
        .map(|e| e.placed(&map))
        .collect();
    if settings.method.settle_drag > 0.0 {
        // From the final target's arrival frame on (frame 1 at time 0), after the air's drag.
        let frame_seconds = settings.method.dt.unwrap_or(shot.step) * shot.frame_every as f64;
        let arrival = settings.shot.at.last().copied().unwrap_or(1);
        let after_drags = (effects.iter())
            .rposition(|e| matches!(e, EffectConfig::Drag { .. }))
            .map_or(0, |i| i + 1);
        let settle = EffectConfig::Drag {
            coefficient: settings.method.settle_drag,
            start: (arrival - 1) as f64 * frame_seconds,
            ramp: settings::SETTLE_RAMP_FRAMES * frame_seconds,
        };
        effects.insert(after_drags, settle);
    }
    effects
}

/// Particle-and-node steps a second one thread does in an optimizer's evaluation, forward
/// and reverse (measured: 1.58 M on 2 threads over the README's job, 144 evaluations of 60
/// steps over 11,752 particles and 22,308 nodes in 187 s).
pub const STEPS_PER_THREAD_SECOND: f64 = 0.75e6;

/// Runs estimated above this many seconds get a warning with the estimate before any work.
pub const LONG_RUN_SECONDS: f64 = 3600.0;

/// A warning with the run's estimated time when it is above [`LONG_RUN_SECONDS`]: every
/// evaluation of every segment's window, a forward and a reverse pass over its steps, each
/// step over the particles and the grid's nodes.
pub(super) fn long_run_warning(
    settings: &MorphSettings,
    shot: &settings::Timing,
    substeps: usize,
    (particles, nodes): (usize, usize),
) -> Option<String> {
    let steps: usize = shot.segment_steps.iter().sum();
    let window = settings.method.lookahead + 1;
    let evaluations = settings.method.passes * settings.method.optimizer.iterations.max(1) * window;
    let work = (steps * substeps) as f64 * evaluations as f64 * (particles + nodes) as f64;
    let threads = rayon::current_num_threads() as f64;
    let seconds = work / (STEPS_PER_THREAD_SECOND * threads);
    (seconds > LONG_RUN_SECONDS).then(|| {
        format!(
            "this run is long: about {:.1} hours on {threads} threads ({} frames, {} segments x {} passes x {} iterations of {particles} particles); fewer frames (--frames, --fps) or particles make it shorter, and --resume continues it after an interruption",
            seconds / 3600.0,
            shot.frame_count(),
            shot.segment_steps.len(),
            settings.method.passes,
            settings.method.optimizer.iterations
        )
    })
}

/// A warning for each collider (and the ground) that holds source particles at frame 1: the
/// first step pushes them out at once, a jolt no control asked for.
pub(super) fn overlap_warnings(
    settings: &MorphSettings,
    geometry: &crate::geometry::MorphGeometry,
) -> Result<Vec<String>, MorphError> {
    use crate::engine::scene::ColliderConfig;
    let placement = &geometry.placement.world_to_sim;
    let map = WorldMap {
        scale: placement.scale,
        translation: placement.translation,
    };
    let particles = &geometry.source.positions;
    let share = |inside: usize| 100.0 * inside as f64 / particles.len().max(1) as f64;
    let mut warnings = Vec::new();
    for effect in &settings.world.effects {
        let EffectConfig::Collider { shape, .. } = effect.placed(&map) else {
            continue;
        };
        let (inside, what) = match &shape {
            ColliderConfig::Plane { point, normal } => {
                let (p, n) = (Vector3::from(*point), Vector3::from(*normal));
                let below = particles.iter().filter(|x| (*x - p).dot(&n) < 0.0).count();
                let what = match settings.world.ground() {
                    Some((height, _)) if n.x == 0.0 && n.z == 0.0 => {
                        format!("the ground at height {height} cuts the body")
                    }
                    _ => "a plane collider cuts the body".to_string(),
                };
                (below, what)
            }
            ColliderConfig::Mesh {
                path,
                scale,
                translation,
            } => {
                let mesh = crate::geometry::load_mesh(path)?;
                let placed = mesh.mesh.transformed(*scale, &Vector3::from(*translation));
                let winding = crate::geometry::winding::WindingNumber::new(&placed);
                let inside = {
                    use rayon::prelude::*;
                    particles.par_iter().filter(|p| winding.at(p) > 0.5).count()
                };
                (
                    inside,
                    format!("collider {} overlaps the body", path.display()),
                )
            }
        };
        if inside > 0 {
            warnings.push(format!(
                "{what} at frame 1: {inside} particles ({:.1}%) start inside it and are pushed out by the first step; move it or the source",
                share(inside)
            ));
        }
    }
    Ok(warnings)
}

/// The fewest equal substeps of `step` that are each at most `bound` seconds.
pub fn substeps_for(step: f64, bound: f64) -> Result<usize, String> {
    let n = (step / bound).ceil();
    if !(n.is_finite() && n <= MAX_SUBSTEPS as f64) {
        return Err(format!(
            "the material needs a time step of {bound:.3e} s on this grid, {n:.0} substeps per 1/120 s step (at most {MAX_SUBSTEPS}); lower its stiffness or the resolution"
        ));
    }
    Ok(n.max(1.0) as usize)
}
