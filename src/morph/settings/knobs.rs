//! The method's knobs by name: what `morph help method` lists and `--set KEY=VALUE` (or a scene
//! file's `[method]` table) changes. An artist leaves them at the preset's values; each is one
//! line here, its default read from the presets and its range from [`super::limits`] or its
//! type's values.

use super::{Inbetween, MorphSettings, Preset, RebuiltMethod, limits};
use crate::engine::integrator::IntegratorKind;
use crate::engine::mpm::{ControlForm, KernelKind};
use crate::gpu::{DeviceKind, Precision};
use crate::loss::MassLossKind;
use crate::morph::basis::ControlResolution;
use crate::morph::segment::Optimizer;
use std::ops::RangeInclusive;

/// The command line's names for settings the scene file holds deeper or by another name, given
/// flat: each alias and the path it stands for.
pub const ALIASES: &[(&str, &[&str])] = &[
    ("iterations", &["optimizer", "iterations"]),
    ("learning_rate", &["optimizer", "learning_rate"]),
    ("steps", &["steps_per_segment"]),
    ("surface", &["surfaces"]),
];

/// One knob: its key in its part (`optimizer.iterations` in `[method]`), its range and what it
/// does.
pub struct Knob {
    pub part: &'static str,
    pub key: &'static str,
    pub range: String,
    pub what: &'static str,
}

fn counts(r: RangeInclusive<usize>) -> String {
    format!("{} to {}", r.start(), r.end())
}

/// A value's name in files and on the command line (a unit variant's serde name; empty for
/// anything else).
pub fn name_of<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default()
}

/// A type's values by their names in files.
fn values<T: serde::Serialize>(all: &[T]) -> String {
    let names: Vec<String> = all.iter().map(name_of).collect();
    names.join(", ")
}

/// Every knob, in the order `morph help method` lists them.
pub fn knobs() -> Vec<Knob> {
    let k = |part, key, range: String, what| Knob {
        part,
        key,
        range,
        what,
    };
    let weight = || ">= 0".to_string();
    vec![
        k(
            "method",
            "segments",
            counts(limits::SEGMENTS),
            "segments in the chain (a shot's frames decide it when given)",
        ),
        k(
            "method",
            "steps_per_segment",
            counts(limits::STEPS),
            "simulation steps per segment (alias `steps`)",
        ),
        k(
            "method",
            "control_stride",
            "1 to steps_per_segment".into(),
            "steps between control layers in a segment",
        ),
        k(
            "method",
            "passes",
            counts(limits::PASSES),
            "passes over the chain; later passes refine the earlier controls",
        ),
        k(
            "method",
            "levels",
            counts(limits::LEVELS),
            "coarse-to-fine levels: n > 1 solves the morph on grids 2^(n-1) .. 2 times coarser first",
        ),
        k(
            "method",
            "refine_iterations",
            counts(limits::ITERATIONS),
            "evaluations per segment on the finest level when levels > 1 (none: the same as iterations)",
        ),
        k(
            "method",
            "optimizer.kind",
            values(&Optimizer::ALL),
            "the optimizer (alias `optimizer`); its own default step unless learning_rate is given",
        ),
        k(
            "method",
            "optimizer.iterations",
            counts(limits::ITERATIONS),
            "evaluations per segment (Adam) or per control layer (line search) (alias `iterations`)",
        ),
        k(
            "method",
            "optimizer.learning_rate",
            "> 0".into(),
            "step size: Adam's per control entry, the line search's first normalized step (alias `learning_rate`)",
        ),
        k(
            "method",
            "optimizer.line_search_tries",
            "1 or more".into(),
            "line search: halvings before a layer gives up",
        ),
        k(
            "method",
            "optimizer.gd_tol",
            "> 0".into(),
            "line search: a layer stops when |g| < gd_tol |g0|",
        ),
        k(
            "method",
            "loss",
            values(&MassLossKind::ALL),
            "the mass loss on the grid",
        ),
        k(
            "method",
            "arrival_weight",
            weight(),
            "kinetic energy left at each segment end after the final target's arrival (the held shape comes to rest)",
        ),
        k(
            "method",
            "settle_drag",
            weight(),
            "drag per second eased in once the final target is reached (0: off)",
        ),
        k(
            "method",
            "volume_weight",
            weight(),
            "the volume cost, 1/2 (ln J)^2 per particle and the body's, over every step",
        ),
        k(
            "method",
            "path_weight",
            weight(),
            "the mass loss at every frame inside a segment against the easing curve's shape then",
        ),
        k(
            "method",
            "lookahead",
            counts(limits::LOOKAHEAD),
            "optimize each segment with the next N, scored at each of their ends",
        ),
        k(
            "method",
            "waypoint_weight",
            weight(),
            "each earlier segment end inside a look-ahead window (the window's end weighs 1)",
        ),
        k(
            "method",
            "control_smoothing",
            weight(),
            "the controls' continuity in time, scaled by the material's shear modulus (0: off)",
        ),
        k(
            "method",
            "carry_controls",
            "0 to 1".into(),
            "share of the last control layer a look-ahead window's new segment starts from",
        ),
        k(
            "method",
            "fine_weight",
            weight(),
            "the mass loss on a grid twice as fine (sees holes and clumps within a cell)",
        ),
        k(
            "method",
            "reach_weight",
            weight(),
            "the reach cost: the target's surface pulls its nearest particle where that is far (0: off)",
        ),
        k(
            "method",
            "control",
            values(&ControlForm::ALL),
            "how a control acts on F: plastic (volume-preserving rest shape) or additive (F + Fc)",
        ),
        k(
            "method",
            "control_resolution",
            values(&ControlResolution::ALL),
            "where the free control values live: one per grid node or one per particle",
        ),
        k(
            "method",
            "kernel",
            values(&KernelKind::ALL),
            "the B-spline transfer kernel",
        ),
        k(
            "method",
            "integrator",
            values(&IntegratorKind::ALL),
            "euler (one transfer round trip a step) or rk4 (four, less damping)",
        ),
        k(
            "method",
            "device",
            values(&DeviceKind::ALL),
            "where the engine runs (also --device)",
        ),
        k(
            "method",
            "precision",
            values(&Precision::ALL),
            "the GPU device's floats: f64, or f32 for consumer GPUs",
        ),
        k(
            "method",
            "dt",
            "> 0, below the stability bound".into(),
            "one time step in seconds (none: steps of 1/120 s split into the substeps the material needs)",
        ),
        k(
            "method",
            "inbetween",
            values(&Inbetween::ALL),
            "what a segment aims at between keyframes: masses crossfaded or distances blended",
        ),
        k(
            "method",
            "progress_timing",
            "0 to 1".into(),
            "how far the schedule is re-timed to the in-between's own progress",
        ),
        k(
            "body",
            "particles_per_cell",
            counts(limits::PARTICLES_PER_CELL),
            "particles per cell along each axis (giving it keeps it, the thin parts' rule off)",
        ),
        k(
            "body",
            "thin_across",
            format!("0 to {}", limits::MAX_THIN_ACROSS),
            "particles the thinnest parts should get across: raises particles_per_cell (0: off)",
        ),
        k(
            "body",
            "jitter",
            "0 to 1".into(),
            "random particle offsets, in particle spacings",
        ),
        k(
            "body",
            "seed",
            "any whole number".into(),
            "the jitter's seed",
        ),
        k(
            "shot",
            "frame_every",
            counts(limits::FRAME_EVERY),
            "a frame every n steps instead of the frame rate",
        ),
        k(
            "outputs",
            "rebuilt_method",
            values(&RebuiltMethod::ALL),
            "how the rebuilt surface is made from the particles",
        ),
    ]
}

/// Every key a setting may be given by (the knobs, the other settings, the aliases), for a
/// refusal to name.
pub fn names() -> Vec<String> {
    let mut all: Vec<String> = super::PARTS
        .iter()
        .flat_map(|(_, keys)| keys.iter().map(|k| k.to_string()))
        .collect();
    all.extend(
        knobs()
            .iter()
            .filter(|k| k.key.contains('.'))
            .map(|k| k.key.to_string()),
    );
    all.extend(ALIASES.iter().map(|(a, _)| a.to_string()));
    all.sort();
    all.dedup();
    all
}

/// A knob's value in `settings` as a scene file writes it ("none" where it is unset).
pub fn value_of(settings: &MorphSettings, part: &str, key: &str) -> String {
    let table = toml::Table::try_from(settings).expect("settings serialize to TOML");
    let mut at = table.get(part);
    for name in key.split('.') {
        at = at.and_then(|v| v.get(name));
    }
    match at {
        Some(toml::Value::String(s)) => s.clone(),
        Some(v) => v.to_string(),
        None => "none".into(),
    }
}

/// A knob's default: one value, or the presets' where they differ.
pub fn default_of(part: &str, key: &str) -> String {
    let by: Vec<(Preset, String)> = (Preset::ALL.iter())
        .map(|&p| (p, value_of(&MorphSettings::preset(p), part, key)))
        .collect();
    if by.iter().all(|(_, v)| *v == by[0].1) {
        return by[0].1.clone();
    }
    let parts: Vec<String> = by
        .iter()
        .map(|(p, v)| format!("{} {v}", name_of(p)))
        .collect();
    parts.join(", ")
}

/// `morph help method`: every knob with its default, range and what it does.
pub fn help_text() -> String {
    let mut out = String::from(
        "The method's knobs: set one with --set KEY=VALUE (repeatable) or in a scene file's table of\n\
         its part ([method], [body], [shot], [outputs]; `optimizer.iterations` is [method.optimizer]\n\
         iterations). An artist leaves them at the preset's values.\n",
    );
    let mut part = "";
    for k in knobs() {
        if k.part != part {
            part = k.part;
            out += &format!("\n[{part}]\n");
        }
        out += &format!(
            "  {:<28} {}\n  {:<28}   default {}; {}\n",
            k.key,
            k.what,
            "",
            default_of(k.part, k.key),
            k.range
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every key of the method's part is a knob, and every knob is a setting.
    #[test]
    fn the_knobs_cover_the_method_and_name_real_settings() {
        let listed: Vec<&str> = knobs()
            .iter()
            .map(|k| k.key.split('.').next().unwrap())
            .collect();
        let method = super::super::PARTS
            .iter()
            .find(|(p, _)| *p == "method")
            .unwrap()
            .1;
        for key in method {
            assert!(listed.contains(key), "`{key}` is not in the knobs");
        }
        let s = MorphSettings::default();
        for k in knobs() {
            let optional = ["refine_iterations", "dt"].contains(&k.key);
            assert!(
                optional || value_of(&s, k.part, k.key) != "none",
                "{}",
                k.key
            );
        }
    }
}
