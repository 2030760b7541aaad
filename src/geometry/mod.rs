//! Meshes in, surfaces out: loading and validating OBJ/PLY meshes, placing source and target
//! in one simulation domain, voxelizing them into particles, and extracting a closed surface
//! from particles for export. `assets` generates the built-in shapes.

pub mod assets;
pub mod error;
pub mod mesh;
pub mod placement;
pub mod surface;
pub mod voxelize;
pub mod winding;

pub use error::MeshError;
pub use mesh::{Aabb, LoadedMesh, TriMesh, load_mesh};
pub use placement::{Placement, PlacementOptions, Similarity, Solid, TargetFit};
pub use surface::extract_surface;
pub use voxelize::{Jitter, Lattice, Particles, Voxelization, particles_in, voxelize};

use std::path::Path;

/// Source particles and target particles of a morph, in sim coordinates.
#[derive(Clone, Debug)]
pub struct MorphGeometry {
    pub placement: Placement,
    pub source: Particles,
    pub target: Particles,
    pub source_solid: Solid,
    pub target_solid: Solid,
    /// Non-fatal findings (open meshes, flipped faces, a missing .mtl), one line each.
    pub warnings: Vec<String>,
}

impl MorphGeometry {
    /// Loads both meshes, places them (see [`Placement`]) and fills them with `per_cell^3`
    /// particles per cell. Target particles are never jittered: they only define `m*`.
    pub fn prepare(
        source_path: &Path,
        target_path: &Path,
        options: &PlacementOptions,
        per_cell: usize,
        jitter: Option<Jitter>,
    ) -> Result<MorphGeometry, MeshError> {
        options.validate()?;
        if !(1..=4).contains(&per_cell) {
            return Err(MeshError::BadOption(format!(
                "particles per cell axis must be between 1 and 4, got {per_cell}"
            )));
        }
        if let Some(j) = jitter
            && !(j.amount.is_finite() && (0.0..=1.0).contains(&j.amount))
        {
            return Err(MeshError::BadOption(format!(
                "jitter must be between 0 and 1 particle spacing, got {}",
                j.amount
            )));
        }
        let src = load_mesh(source_path)?;
        let tgt = load_mesh(target_path)?;
        let source_solid = Solid::measure(&src.mesh, source_path)?;
        let target_solid = Solid::measure(&tgt.mesh, target_path)?;
        let placement = Placement::new(&source_solid, &target_solid, options)?;
        let source_sim = placement.world_to_sim.apply_mesh(&src.mesh);
        let target_sim = placement.target_to_sim().apply_mesh(&tgt.mesh);
        let source = particles_in(&source_sim, &placement.grid, per_cell, jitter);
        let target = particles_in(&target_sim, &placement.grid, per_cell, None);
        for (p, path) in [(&source, source_path), (&target, target_path)] {
            if p.positions.is_empty() {
                return Err(MeshError::NoInside {
                    path: path.into(),
                    reason: format!(
                        "no particle fits inside at resolution {} (the shape is thinner than a particle spacing); raise --resolution",
                        options.resolution
                    ),
                });
            }
        }
        let mut warnings = src.warnings;
        warnings.extend(tgt.warnings);
        Ok(MorphGeometry {
            placement,
            source,
            target,
            source_solid,
            target_solid,
            warnings,
        })
    }
}
