//! Meshes in, surfaces out: loading and validating OBJ/PLY meshes, placing source and target
//! in one simulation domain, voxelizing them into particles, and extracting a closed surface
//! from particles for export. `assets` generates the built-in shapes.

pub mod assets;
pub mod carried;
pub mod cleanup;
pub mod collider_solid;
pub mod error;
pub mod features;
pub mod fidelity;
pub mod fit;
pub mod likeness;
pub mod mesh;
pub mod neighbourhood;
pub mod placement;
pub mod point_grid;
pub mod splashsurf;
pub mod surface;
pub mod thickness;
pub mod voxelize;
pub mod winding;

pub use collider_solid::{MeshSolid, MeshSolids};
pub use error::MeshError;
pub use mesh::{Aabb, LoadedMesh, TriMesh, load_mesh, parse_mesh, prepare_mesh};
pub use placement::{Placement, PlacementOptions, Similarity, Solid, TargetFit};
pub use surface::{SurfaceError, extract_surface};
pub use voxelize::{Jitter, Lattice, Particles, Voxelization, particles_in, voxelize};

use nalgebra::Vector3;
use std::path::Path;

/// Source particles and target particles of a morph, in sim coordinates.
#[derive(Clone, Debug)]
pub struct MorphGeometry {
    pub placement: Placement,
    pub source: Particles,
    /// How much each source particle's kernel weighs in the rebuilt surface's field
    /// ([`surface::edge_weights`]): where the source's surface passes between particles.
    pub source_edge_weights: Vec<f64>,
    pub target: Particles,
    pub source_solid: Solid,
    pub target_solid: Solid,
    /// The target's surface placed in sim coordinates (the quality judge reads it).
    pub target_sim: TriMesh,
    /// Non-fatal findings (open meshes, flipped faces, a missing .mtl), one line each.
    pub warnings: Vec<String>,
    /// The keyframe targets before the last (`morph A B C`: B), placed like the target.
    pub keyframes: Vec<KeyframeTarget>,
}

/// A keyframe target before the last one, in sim coordinates.
#[derive(Clone, Debug)]
pub struct KeyframeTarget {
    pub particles: Particles,
    pub solid: Solid,
    /// Its surface placed in sim coordinates (the quality judge reads it).
    pub sim: TriMesh,
}

/// What a morph's grid and particles will be, estimated from the shapes' volumes before any
/// particle is placed (no fill at the run's resolution: cheap at any resolution). The memory
/// plan checks a limit against it before setup, and `--particles` picks a resolution by it.
#[derive(Clone, Debug, PartialEq)]
pub struct SizeEstimate {
    /// Grid nodes.
    pub nodes: usize,
    /// The grid's spacing (simulation units).
    pub dx: f64,
    /// Source particles (the inside volume over a particle's).
    pub source_particles: f64,
    /// Particles of every target together (the last and the keyframes before it).
    pub target_particles: f64,
    /// Each target's particles, in keyframe order.
    pub each_target_particles: Vec<f64>,
}

impl MorphGeometry {
    /// Estimates the grid and particle counts of [`MorphGeometry::with_keyframes`] with the
    /// same arguments.
    pub fn estimate(
        (src, source_path): (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
        options: &PlacementOptions,
        per_cell: usize,
    ) -> Result<SizeEstimate, MeshError> {
        check_options(options, per_cell, None)?;
        let source = Solid::measure(&src.mesh, source_path)?;
        let solids = targets
            .iter()
            .map(|(m, p)| Solid::measure(&m.mesh, p))
            .collect::<Result<Vec<_>, _>>()?;
        let all: Vec<&Solid> = solids.iter().collect();
        let placement = Placement::with_targets(&source, &all, options)?;
        let spacing = placement.grid.dx / per_cell as f64;
        // A solid's volume at a scale, from its unit volume (never over- or underflows).
        let particles = |solid: &Solid, scale: f64| {
            solid.unit_volume * (solid.length * scale / spacing).powi(3)
        };
        let last = solids.len() - 1;
        let each_target_particles: Vec<f64> = solids
            .iter()
            .enumerate()
            .map(|(k, solid)| {
                let to_sim = if k == last {
                    placement.target_to_sim()
                } else {
                    placement.keyframe_to_sim(k)
                };
                particles(solid, to_sim.scale)
            })
            .collect();
        let target_particles = each_target_particles.iter().sum();
        Ok(SizeEstimate {
            nodes: placement.grid.node_count(),
            dx: placement.grid.dx,
            source_particles: particles(&source, placement.world_to_sim.scale),
            target_particles,
            each_target_particles,
        })
    }

    /// Loads both meshes, places them (see [`Placement`]) and fills them with `per_cell^3`
    /// particles per cell. Target particles are never jittered: they only define `m*`.
    pub fn prepare(
        source_path: &Path,
        target_path: &Path,
        options: &PlacementOptions,
        per_cell: usize,
        jitter: Option<Jitter>,
    ) -> Result<MorphGeometry, MeshError> {
        check_options(options, per_cell, jitter)?;
        let src = load_mesh(source_path)?;
        let tgt = load_mesh(target_path)?;
        Self::from_loaded(
            (&src, source_path),
            (&tgt, target_path),
            options,
            per_cell,
            jitter,
        )
    }

    /// [`MorphGeometry::prepare`] on meshes already loaded (see [`prepare_mesh`] for meshes
    /// made in memory); each comes with the name its messages use.
    pub fn from_loaded(
        source: (&LoadedMesh, &Path),
        target: (&LoadedMesh, &Path),
        options: &PlacementOptions,
        per_cell: usize,
        jitter: Option<Jitter>,
    ) -> Result<MorphGeometry, MeshError> {
        Self::with_keyframes(source, &[target], options, per_cell, jitter)
    }

    /// [`MorphGeometry::from_loaded`] for a morph through several targets in turn
    /// (keyframes); the last is the final target.
    pub fn with_keyframes(
        (src, source_path): (&LoadedMesh, &Path),
        targets: &[(&LoadedMesh, &Path)],
        options: &PlacementOptions,
        per_cell: usize,
        jitter: Option<Jitter>,
    ) -> Result<MorphGeometry, MeshError> {
        check_options(options, per_cell, jitter)?;
        let Some((&(tgt, target_path), earlier)) = targets.split_last() else {
            return Err(MeshError::BadOption("a morph needs a target mesh".into()));
        };
        let source_solid = Solid::measure(&src.mesh, source_path)?;
        let target_solid = Solid::measure(&tgt.mesh, target_path)?;
        let earlier_solids = earlier
            .iter()
            .map(|(m, p)| Solid::measure(&m.mesh, p))
            .collect::<Result<Vec<_>, _>>()?;
        let mut all: Vec<&Solid> = earlier_solids.iter().collect();
        all.push(&target_solid);
        let placement = Placement::with_targets(&source_solid, &all, options)?;
        placement.check_output_range(source_path, per_cell)?;
        if options.target_fit == TargetFit::AsGiven {
            // A body's own forces cannot move its centre of mass: a target far from the
            // source cannot be reached, whatever the optimizer does.
            let d = (Vector3::from(target_solid.centroid) - Vector3::from(source_solid.centroid))
                .norm();
            let size = source_solid.bounds().extent().norm();
            if d > FAR_APART * size {
                let cells = d * placement.world_to_sim.scale / placement.grid.dx;
                return Err(MeshError::Invalid {
                    path: target_path.into(),
                    reason: format!(
                        "with --target-fit as-given its centre of mass is {d:.4} units ({cells:.1} grid cells) from the source's, more than {:.0}% of the source's size: the body's own forces cannot move its centre of mass, so the morph cannot reach it; place the target over the source or use --target-fit match-volume",
                        100.0 * FAR_APART
                    ),
                });
            }
        }
        let source_sim = placement.world_to_sim.apply_mesh(&src.mesh);
        let target_sim = placement.target_to_sim().apply_mesh(&tgt.mesh);
        let source = particles_in(&source_sim, &placement.grid, per_cell, jitter);
        let target = particles_in(&target_sim, &placement.grid, per_cell, None);
        let source_edge_weights = surface::edge_weights(
            &source_sim,
            &source.positions,
            placement.grid.dx / per_cell as f64,
        );
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
        let mut warnings = src.warnings.clone();
        warnings.extend(tgt.warnings.iter().cloned());
        let mut keyframes = Vec::with_capacity(earlier.len());
        for (k, ((mesh, path), solid)) in earlier.iter().zip(earlier_solids).enumerate() {
            let sim = placement.keyframe_to_sim(k).apply_mesh(&mesh.mesh);
            let particles = particles_in(&sim, &placement.grid, per_cell, None);
            if particles.positions.is_empty() {
                return Err(MeshError::NoInside {
                    path: (*path).into(),
                    reason: format!(
                        "no particle fits inside at resolution {} (the shape is thinner than a particle spacing); raise --resolution",
                        options.resolution
                    ),
                });
            }
            warnings.extend(mesh.warnings.iter().cloned());
            keyframes.push(KeyframeTarget {
                particles,
                solid,
                sim,
            });
        }
        Ok(MorphGeometry {
            placement,
            source,
            source_edge_weights,
            target,
            source_solid,
            target_solid,
            target_sim,
            warnings,
            keyframes,
        })
    }
}

/// With [`TargetFit::AsGiven`], the largest distance between the centres of mass of source
/// and target, as a fraction of the source's bounding-box diagonal.
pub const FAR_APART: f64 = 0.1;

/// Options are checked before any mesh is read.
fn check_options(
    options: &PlacementOptions,
    per_cell: usize,
    jitter: Option<Jitter>,
) -> Result<(), MeshError> {
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
    let samples = (options.resolution * per_cell).pow(3);
    if samples > 1 << 28 {
        return Err(MeshError::BadOption(format!(
            "resolution {} with {per_cell}^3 particles per cell needs up to {samples} samples (limit {}); lower one of them",
            options.resolution,
            1 << 28
        )));
    }
    Ok(())
}

impl MorphGeometry {
    /// Target nodal masses `m*_i`: the target particles' mass P2G-transferred with `kernel`,
    /// scaled so the total equals the source's mass (mass is conserved, so a target of
    /// another mass could not be matched; the scale is within voxelization error of 1).
    pub fn target_masses(
        &self,
        kernel: crate::engine::mpm::KernelKind,
        density: f64,
    ) -> Result<Vec<f64>, crate::engine::mpm::SimError> {
        self.target_masses_on(&self.placement.grid, kernel, density)
    }

    /// [`MorphGeometry::target_masses`] on another grid over the same domain.
    pub fn target_masses_on(
        &self,
        grid: &crate::engine::mpm::GridSpec,
        kernel: crate::engine::mpm::KernelKind,
        density: f64,
    ) -> Result<Vec<f64>, crate::engine::mpm::SimError> {
        self.masses_of(&self.target.positions, grid, kernel, density)
    }

    /// The nodal masses of keyframe target `k` (see [`MorphGeometry::keyframes`]), like
    /// [`MorphGeometry::target_masses_on`].
    pub fn keyframe_masses_on(
        &self,
        k: usize,
        grid: &crate::engine::mpm::GridSpec,
        kernel: crate::engine::mpm::KernelKind,
        density: f64,
    ) -> Result<Vec<f64>, crate::engine::mpm::SimError> {
        self.masses_of(
            &self.keyframes[k].particles.positions,
            grid,
            kernel,
            density,
        )
    }

    /// Target particles carrying the source's total mass, transferred to `grid`.
    fn masses_of(
        &self,
        positions: &[Vector3<f64>],
        grid: &crate::engine::mpm::GridSpec,
        kernel: crate::engine::mpm::KernelKind,
        density: f64,
    ) -> Result<Vec<f64>, crate::engine::mpm::SimError> {
        let source_mass = density * self.source.volume * self.source.positions.len() as f64;
        let per_particle = source_mass / positions.len() as f64;
        let masses = vec![per_particle; positions.len()];
        crate::engine::mpm::transfer::mass_grid(grid, kernel, positions, &masses)
    }
}

/// A mesh report for `morph inspect`: topology, inside volume, particle count.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MeshReport {
    pub path: String,
    pub vertices: usize,
    pub triangles: usize,
    pub closed: bool,
    pub boundary_edges: usize,
    pub non_manifold_edges: usize,
    /// Vertices merged because they coincide (within 1e-7 of the box diagonal), and
    /// triangles that collapsed doing so; the counts above are after welding.
    pub welded_vertices: usize,
    pub collapsed_triangles: usize,
    /// Genus of a one-part closed mesh (see `parts` for each part of a multi-part mesh).
    pub genus: Option<i64>,
    /// Connected parts, each with its own counts, Euler characteristic and genus.
    pub parts: Vec<mesh::PartTopology>,
    pub bounds_min: [f64; 3],
    pub bounds_max: [f64; 3],
    /// Inside volume in the mesh's units: exact (divergence theorem) for a closed mesh, else
    /// the winding-number voxelization's; null when it is beyond f64 (a warning gives its
    /// order of magnitude).
    pub volume: Option<f64>,
    pub centroid: [f64; 3],
    pub resolution: usize,
    /// Particles at `resolution` cells across, 2x2x2 per cell, placed as a morph source.
    pub particles: usize,
    /// Its thin parts' and its body's local thickness, the mesh's units ([`thickness`]).
    pub thickness: Option<thickness::Thickness>,
    pub warnings: Vec<String>,
}

/// Loads, measures and voxelizes one mesh as `morph SRC TGT` would use it as a source.
pub fn inspect(path: &Path, resolution: usize) -> Result<MeshReport, MeshError> {
    let loaded = load_mesh(path)?;
    let mesh = &loaded.mesh;
    let solid = Solid::measure(mesh, path)?;
    let options = PlacementOptions {
        resolution,
        ..Default::default()
    };
    let placement = Placement::new(&solid, &solid, &options)?;
    let particles = particles_in(
        &placement.world_to_sim.apply_mesh(mesh),
        &placement.grid,
        2,
        None,
    );
    let mut warnings = loaded.warnings.clone();
    if !(solid.volume.is_finite() && solid.volume > 0.0) {
        warnings.push(format!(
            "{}: its volume (about 1e{:.0} cubic units) is beyond 64-bit floats; only its shape is used as a target",
            path.display(),
            solid.log10_volume()
        ));
    }
    if let Err(e) = placement.check_output_range(path, 2) {
        warnings.push(e.to_string());
    }
    let topo = mesh.topology();
    // A closed mesh's volume is exact by the divergence theorem; the lattice's estimate
    // (what placement uses) cannot see parts thinner than its spacing.
    let exact = topo.is_closed().then(|| mesh.signed_volume().abs());
    let volume = exact
        .or(Some(solid.volume))
        .filter(|v| v.is_finite() && *v > 0.0);
    if let (Some(exact), true) = (exact, solid.volume.is_finite())
        && (solid.volume > 1.5 * exact || solid.volume < exact / 1.5)
    {
        warnings.push(format!(
            "{}: it is thinner than morph's measuring lattice (1/{} of its longest side): its volume is {exact:.3e}, but morph measures {:.3e}, so a morph would place it at the wrong size",
            path.display(),
            placement::MEASURE_SAMPLES,
            solid.volume
        ));
    }
    if particles.positions.is_empty() {
        warnings.push(format!(
            "{}: no particle fits inside at --resolution {resolution} (the shape is thinner than a particle spacing): it cannot be a morph's source or target there; raise --resolution",
            path.display()
        ));
    }
    let parts = mesh.parts();
    let genus = match parts.as_slice() {
        [one] => one.genus,
        _ => None,
    };
    Ok(MeshReport {
        path: path.display().to_string(),
        vertices: mesh.vertices.len(),
        triangles: mesh.triangles.len(),
        closed: topo.is_closed(),
        boundary_edges: topo.boundary_edges,
        non_manifold_edges: topo.non_manifold_edges,
        welded_vertices: loaded.welded_vertices,
        collapsed_triangles: loaded.collapsed_triangles,
        genus,
        parts,
        bounds_min: solid.bounds_min,
        bounds_max: solid.bounds_max,
        volume,
        centroid: solid.centroid,
        resolution,
        particles: particles.positions.len(),
        thickness: thickness::thickness(mesh),
        warnings,
    })
}
