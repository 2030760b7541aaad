//! Particles for thin parts: the default's particles per cell, chosen from the thinnest parts
//! of the source and the targets (docs/morph.md, "Particles for thin parts").
//!
//! A leg or an ear thinner than about two particle spacings cannot hold material: the morph
//! has nothing to put there. The grid is the preset's (a finer grid costs a second substep
//! per step, docs/accuracy.md); the particles per cell on it are raised from two until the
//! thinnest part ([`crate::geometry::thickness`]) gets `thin_across` particles across, while
//! the source's particles stay within [`DETAIL_BUDGET`]. What was chosen and why is in the
//! summary and the manifest.

use super::MorphError;
use super::settings::CheckedSettings;
use crate::geometry::thickness::thickness;
use crate::geometry::{LoadedMesh, MorphGeometry};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The most source particles the thin parts' rule gives a morph: about what a shared morph
/// already has at `default` (stanford-bunny's 16,669), so that its time stays that of one.
pub const DETAIL_BUDGET: usize = 17_000;

/// What the thin parts' rule found and chose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sizing {
    /// The shape whose thin parts are thinnest (its file), and their thickness in particles
    /// across at the preset's particles per cell.
    pub thinnest: String,
    pub across_before: f64,
    /// The particles per cell chosen, the particles across the thinnest parts they give, and
    /// the source's particles (estimated from its volume).
    pub per_cell: usize,
    pub across: f64,
    pub particles: f64,
    /// The particles per cell the thin parts ask for (`thin_across` of them across, at most
    /// the largest per cell) and the source's particles there: above `per_cell` when the
    /// budget stopped the rule short.
    pub wanted_per_cell: usize,
    pub wanted_particles: f64,
}

/// `settings` with the particles per cell the thin parts call for, and what was decided;
/// `settings` as they are (and `None`) when a budget is set or the rule is off.
pub fn size(
    settings: &CheckedSettings,
    source: (&LoadedMesh, &Path),
    targets: &[(&LoadedMesh, &Path)],
) -> Result<(CheckedSettings, Option<Sizing>), MorphError> {
    if settings.body.particles.is_some() || settings.body.thin_across <= 0.0 {
        return Ok((settings.clone(), None));
    }
    let k0 = settings.body.particles_per_cell;
    let estimate = MorphGeometry::estimate(
        source,
        targets,
        &settings.placement_options(settings.body.resolution),
        k0,
    )?;
    // A shape's thin parts across, in particles at `k0` per cell: its thin-part thickness
    // over its volume's cube root is scale-free, and its particle count gives that volume
    // in particle spacings.
    let shapes = std::iter::once((source, estimate.source_particles)).chain(
        targets
            .iter()
            .copied()
            .zip(estimate.each_target_particles.iter().copied()),
    );
    let mut thinnest = (String::new(), f64::INFINITY);
    for ((mesh, path), particles) in shapes {
        if let Some(t) = thickness(&mesh.mesh) {
            let across = t.thin / t.volume.cbrt() * particles.cbrt();
            if across < thinnest.1 {
                thinnest = (path.display().to_string(), across);
            }
        }
    }
    let (name, across_before) = thinnest;
    if !across_before.is_finite() {
        return Ok((settings.clone(), None));
    }
    let scale = |k: usize| k as f64 / k0 as f64;
    let most = *super::settings::limits::PARTICLES_PER_CELL.end();
    let wanted = (k0..=most)
        .find(|&k| across_before * scale(k) >= settings.body.thin_across)
        .unwrap_or(most);
    let particles_at = |k: usize| estimate.source_particles * scale(k).powi(3);
    let chosen = (k0..=wanted)
        .rev()
        .find(|&k| k == k0 || particles_at(k) <= DETAIL_BUDGET as f64)
        .unwrap_or(k0);
    let mut sized = (**settings).clone();
    sized.body.particles_per_cell = chosen;
    Ok((
        CheckedSettings::derived(sized),
        Some(Sizing {
            thinnest: name,
            across_before,
            per_cell: chosen,
            across: across_before * scale(chosen),
            particles: particles_at(chosen),
            wanted_per_cell: wanted,
            wanted_particles: particles_at(wanted),
        }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MorphSettings;
    use crate::geometry::assets::{cube, uv_sphere};
    use crate::geometry::{TriMesh, prepare_mesh};
    use nalgebra::Vector3;

    /// A box from `min` to `max`.
    fn cuboid(min: [f64; 3], max: [f64; 3]) -> TriMesh {
        let mut c = cube(1.0, 1);
        for v in &mut c.vertices {
            *v = Vector3::from_fn(|a, _| min[a] + (v[a] + 0.5) * (max[a] - min[a]));
        }
        c
    }

    /// A table: a slab on four legs a 27th of its length across.
    fn table() -> TriMesh {
        let mut t = cuboid([-1.6, 1.0, -0.6], [1.6, 1.3, 0.6]);
        for (x, z) in [(-1.45, -0.45), (-1.45, 0.45), (1.45, -0.45), (1.45, 0.45)] {
            let leg = cuboid([x - 0.06, 0.0, z - 0.06], [x + 0.06, 1.0, z + 0.06]);
            let offset = t.vertices.len() as u32;
            t.vertices.extend(leg.vertices);
            t.triangles
                .extend(leg.triangles.iter().map(|f| f.map(|i| i + offset)));
        }
        t
    }

    #[test]
    fn a_thin_legged_target_gets_particles_across_its_legs() {
        let path = Path::new("table.obj");
        let target = prepare_mesh(path, table(), Vec::new()).unwrap();
        let sphere = Path::new("sphere.obj");
        let source = prepare_mesh(sphere, uv_sphere(1.0, 24, 48, |_, _| 1.0), Vec::new()).unwrap();
        let settings = MorphSettings::default();
        let checked = settings.clone().checked().unwrap();
        let (sized, sizing) = size(&checked, (&source, sphere), &[(&target, path)]).unwrap();
        let sizing = sizing.expect("the default sizes for thin parts");
        assert_eq!(sizing.thinnest, "table.obj");
        assert!(sizing.across_before < 2.0, "{sizing:?}");
        assert!(
            sized.body.particles_per_cell > settings.body.particles_per_cell,
            "{sizing:?}"
        );
        assert!(sizing.particles <= DETAIL_BUDGET as f64, "{sizing:?}");
        // The target's particles: a leg's cross-section at half its height holds at least
        // two particles along each axis at the chosen spacing, and more than at two per cell.
        let across_leg = |per_cell: usize| {
            let geometry = MorphGeometry::with_keyframes(
                (&source, sphere),
                &[(&target, path)],
                &sized.placement_options(sized.body.resolution),
                per_cell,
                None,
            )
            .unwrap();
            let to_sim = geometry.placement.target_to_sim();
            let centre = to_sim.apply(&Vector3::new(1.45, 0.5, 0.45));
            let half = to_sim.scale * 0.06;
            let spacing = geometry.placement.grid.dx / per_cell as f64;
            let in_leg: Vec<_> = geometry
                .target
                .positions
                .iter()
                .filter(|p| (p.y - centre.y).abs() <= 0.5 * spacing)
                .filter(|p| (p.x - centre.x).abs() <= half && (p.z - centre.z).abs() <= half)
                .collect();
            let distinct = |a: usize| {
                let mut v: Vec<i64> = in_leg
                    .iter()
                    .map(|p| (p[a] / spacing).round() as i64)
                    .collect();
                v.sort();
                v.dedup();
                v.len()
            };
            (distinct(0).min(distinct(2)), in_leg.len())
        };
        let (chosen, two) = (across_leg(sized.body.particles_per_cell), across_leg(2));
        assert!(
            chosen.0 >= 2 && chosen.1 > two.1,
            "{chosen:?} against {two:?}"
        );
        // Off, nothing is sized.
        let mut off_settings = settings.clone();
        off_settings.body.thin_across = 0.0;
        let (_, off) = size(
            &off_settings.checked().unwrap(),
            (&source, sphere),
            &[(&target, path)],
        )
        .unwrap();
        assert!(off.is_none());
    }
}
