//! The summary a finished `morph SOURCE TARGET` prints: one line per part of the report.

use super::{MorphArgs, ProgressShown};
use morph::output::Summary;
use std::process::ExitCode;

/// A run that wrote its folder: the summary (a JSON event with `--json`) and the warnings.
pub fn written(args: &MorphArgs, summary: &Summary) -> ExitCode {
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
        for line in summary_lines(summary) {
            say!("{line}");
        }
        if let Some(f) = &summary.frames_summary
            && f.frames_inverted > 0
        {
            eprintln!(
                "morph: warning: particles turned inside out (J <= 0) in {} frames; see the frames' min_j in manifest.json",
                f.frames_inverted
            );
        }
    }
    if !args.quiet {
        for w in &summary.warnings {
            eprintln!("morph: warning: {w}");
        }
    }
    ExitCode::SUCCESS
}

/// The summary's lines, in the order they are printed.
fn summary_lines(summary: &Summary) -> Vec<String> {
    let mut lines = Vec::new();
    if let Some(from) = &summary.resumed_from {
        lines.push(format!("resumed from the checkpoint ({from})"));
    }
    lines.push(format!(
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
    ));
    lines.extend(summary.sizing.as_ref().map(sizing_line));
    if summary.device != "cpu" {
        lines.push(format!("device: {}", summary.device));
    }
    lines.extend(summary.optimization.as_ref().map(|o| {
        format!(
            "optimization: {} evaluations, {} steps undone (they raised the objective or blew the simulation up), {} of {} segments moved (loss down by {}% or more)",
            o.evaluations,
            o.undone_steps,
            o.segments_moved,
            o.segments,
            100.0 * morph::MOVED_SHARE
        )
    }));
    lines.extend(summary.quality.as_ref().map(quality_line));
    let surfaces = summary
        .frames_summary
        .as_ref()
        .and_then(|f| f.surfaces.as_ref());
    lines.extend(
        surfaces
            .and_then(|s| s.likeness.as_ref())
            .map(likeness_line),
    );
    lines.extend(summary.motion.as_ref().map(motion_line));
    if let Some(f) = &summary.frames_summary {
        let volume = f.max_surface_volume_error.map_or(String::new(), |e| {
            format!("; surface volume within {:.1}% of the body's", 100.0 * e)
        });
        lines.push(format!(
            "all frames: J {:.3} to {:.3}, {} frames with inverted particles, close neighbours at most {:.1}%{volume}",
            f.min_j,
            f.max_j,
            f.frames_inverted,
            100.0 * f.max_close_share
        ));
        lines.extend(
            surfaces
                .and_then(surfaces_line)
                .map(|l| format!("surfaces: {l}")),
        );
    }
    lines
}

/// The summary's quality line: the judge's figures.
fn quality_line(q: &morph::quality::Quality) -> String {
    format!(
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
    )
}

/// The summary's motion line.
fn motion_line(m: &morph::motion::MotionMeasures) -> String {
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
    format!(
        "motion: pulse {:.2}, dip {:.2}, wobble {:.2}, settle {:.2}, ease error {ease}, {} frozen frames{from}",
        m.pulse, m.dip, m.wobble, m.settle, m.frozen_frames
    )
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
            "; {} per cell would give them {:.1} across with about {:.0} particles, over the budget of {} (--set particles_per_cell={} or --particles {:.0} asks for them)",
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
        s.carried_likeness.map(|l| {
            let (worst, direction) = l.worst_tips();
            format!(
                "carried tips {:.1}% at the top, {:.1}% at worst ({direction})",
                100.0 * l.top_tips(),
                100.0 * worst
            )
        }),
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
