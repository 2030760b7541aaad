//! Bringing a source and a target mesh into one simulation domain.
//!
//! Frames: *world* is the source mesh's own coordinate system (what users get back);
//! *target* is the target mesh's own; *sim* is the simulation frame, where the domain's
//! longest side is [`DOMAIN_SIZE`] units whatever `--resolution` is (so the material and
//! time settings mean the same at every resolution; only dx changes).

use super::error::MeshError;
use super::mesh::{Aabb, TriMesh};
use super::voxelize::{Lattice, voxelize};
use crate::engine::mpm::GridSpec;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Longest side of the simulation domain, in sim units (the reference domain, 32 cells of
/// dx = 1).
pub const DOMAIN_SIZE: f64 = 32.0;

/// Samples across the longest side when measuring a mesh's volume and centroid.
pub const MEASURE_SAMPLES: usize = 96;

/// `y = scale * x + translation`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Similarity {
    pub scale: f64,
    pub translation: [f64; 3],
}

impl Similarity {
    pub fn identity() -> Self {
        Similarity {
            scale: 1.0,
            translation: [0.0; 3],
        }
    }

    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.scale * x + Vector3::from(self.translation)
    }

    pub fn inverse(&self) -> Similarity {
        let inv = 1.0 / self.scale;
        Similarity {
            scale: inv,
            translation: (-inv * Vector3::from(self.translation)).into(),
        }
    }

    /// `self` after `first`: x -> self(first(x)).
    pub fn after(&self, first: &Similarity) -> Similarity {
        Similarity {
            scale: self.scale * first.scale,
            translation: self.apply(&Vector3::from(first.translation)).into(),
        }
    }

    pub fn apply_mesh(&self, mesh: &TriMesh) -> TriMesh {
        mesh.transformed(self.scale, &Vector3::from(self.translation))
    }
}

/// What a mesh encloses, measured by voxelization (valid for open meshes too).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Solid {
    /// Inside volume in the mesh's units; it over- or underflows f64 for meshes in extreme
    /// units (a 1e300-unit mesh), which is why placement uses `unit_volume` and `length`.
    pub volume: f64,
    pub centroid: [f64; 3],
    pub bounds_min: [f64; 3],
    pub bounds_max: [f64; 3],
    /// The longest side of the bounding box.
    pub length: f64,
    /// The inside volume with the longest side scaled to 1 (always a plain number).
    pub unit_volume: f64,
}

impl Solid {
    /// Measures the inside of `mesh` (named `path` in errors) on a lattice of
    /// `MEASURE_SAMPLES` across its longest side. Fails when nothing is inside, or when the
    /// winding number is near 1/2 for more samples than are inside (an open sheet, not a
    /// solid). The mesh is first brought to unit size about its box centre in f64, so meshes
    /// in any units measure alike.
    pub fn measure(mesh: &TriMesh, path: &Path) -> Result<Solid, MeshError> {
        let bounds = mesh.bounds();
        let centre = bounds.centre();
        let length = bounds.longest_side();
        let unit = mesh.transformed(1.0 / length, &(-centre / length));
        let vox = voxelize(&unit, &Lattice::covering(&unit.bounds(), MEASURE_SAMPLES));
        let s = vox.stats;
        if s.inside == 0 {
            return Err(MeshError::NoInside {
                path: path.into(),
                reason: "no point is enclosed by the surface (an open sheet or a flat shell?)"
                    .into(),
            });
        }
        if s.ambiguous > s.inside {
            return Err(MeshError::NoInside {
                path: path.into(),
                reason: format!(
                    "{} samples are half inside and only {} inside: an open surface, not a solid; close its holes",
                    s.ambiguous, s.inside
                ),
            });
        }
        let points = vox.inside_points();
        let centroid = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        let unit_volume = vox.volume();
        Ok(Solid {
            volume: unit_volume * length.powi(3),
            centroid: (centre + length * centroid).into(),
            bounds_min: bounds.min.into(),
            bounds_max: bounds.max.into(),
            length,
            unit_volume,
        })
    }

    /// The uniform scale that gives `self` the volume of `other`, computed without forming
    /// either volume (which may not fit in f64).
    pub fn scale_to_volume_of(&self, other: &Solid) -> f64 {
        (other.length / self.length) * (other.unit_volume / self.unit_volume).cbrt()
    }

    /// log10 of the volume, finite even where the volume itself is not representable.
    pub fn log10_volume(&self) -> f64 {
        self.unit_volume.log10() + 3.0 * self.length.log10()
    }

    pub fn bounds(&self) -> Aabb {
        Aabb {
            min: self.bounds_min.into(),
            max: self.bounds_max.into(),
        }
    }
}

/// How the target is placed relative to the source.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TargetFit {
    /// Scale the target uniformly to the source's volume and put its centroid on the
    /// source's (mass and centre of mass are conserved, so this is what can be matched).
    #[default]
    MatchVolume,
    /// Use the target exactly as given, in the source's coordinates.
    AsGiven,
    /// Scale the target to the source's volume, centre it horizontally (x, z) under the
    /// source's centroid and stand its lowest point on the ground plane (a scene with gravity
    /// and a ground: the body falls and lands there).
    OnGround,
}

impl TargetFit {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [TargetFit; 3] = [
        TargetFit::MatchVolume,
        TargetFit::AsGiven,
        TargetFit::OnGround,
    ];
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlacementOptions {
    /// Grid cells across the domain's longest side (reference: 32).
    pub resolution: usize,
    pub target_fit: TargetFit,
    /// Empty margin on each side of the shapes, as a fraction of `resolution` (at least 3
    /// cells).
    pub padding: f64,
    /// Height (world y) of a ground plane: the domain reaches down to it, and
    /// [`TargetFit::OnGround`] stands targets on it.
    #[serde(default)]
    pub ground: Option<f64>,
}

impl Default for PlacementOptions {
    fn default() -> Self {
        PlacementOptions {
            resolution: 32,
            target_fit: TargetFit::MatchVolume,
            padding: 0.15,
            ground: None,
        }
    }
}

/// Grid cells along the domain's longest side that a placement accepts (the morph's
/// `--resolution` limits are these).
pub const RESOLUTION_LIMITS: std::ops::RangeInclusive<usize> = 8..=256;

impl PlacementOptions {
    pub fn validate(&self) -> Result<(), MeshError> {
        let range = RESOLUTION_LIMITS;
        if !range.contains(&self.resolution) {
            return Err(MeshError::BadOption(format!(
                "--resolution must be between {} and {} cells, got {}",
                range.start(),
                range.end(),
                self.resolution
            )));
        }
        if !(self.padding.is_finite() && (0.0..=0.4).contains(&self.padding)) {
            return Err(MeshError::BadOption(format!(
                "padding must be between 0 and 0.4 of the domain, got {}",
                self.padding
            )));
        }
        Ok(())
    }

    /// Empty cells on each side of the shapes.
    pub fn pad_cells(&self) -> usize {
        ((self.padding * self.resolution as f64).round() as usize).max(3)
    }
}

/// Where everything sits: the grid (in sim units) and the maps between the frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    pub grid: GridSpec,
    /// World (source mesh) coordinates -> sim coordinates.
    pub world_to_sim: Similarity,
    /// Target mesh coordinates -> world coordinates (`target.scale`, `target.translation`).
    pub target_to_world: Similarity,
    /// The same for each keyframe target before the last (`morph A B C`: B's), in order.
    #[serde(default)]
    pub keyframes_to_world: Vec<Similarity>,
}

impl Placement {
    /// Places one target; see [`Placement::with_targets`].
    pub fn new(
        source: &Solid,
        target: &Solid,
        options: &PlacementOptions,
    ) -> Result<Placement, MeshError> {
        Placement::with_targets(source, &[target], options)
    }

    /// Places every target by the target-fit rule, each on its own against the source, and
    /// makes a grid over the source, the placed targets and (when set) the ground's height.
    pub fn with_targets(
        source: &Solid,
        targets: &[&Solid],
        options: &PlacementOptions,
    ) -> Result<Placement, MeshError> {
        options.validate()?;
        let fit = |target: &Solid| -> Result<Similarity, MeshError> {
            Ok(match options.target_fit {
                TargetFit::AsGiven => Similarity::identity(),
                TargetFit::MatchVolume | TargetFit::OnGround => {
                    let scale = target.scale_to_volume_of(source);
                    let mut t =
                        Vector3::from(source.centroid) - scale * Vector3::from(target.centroid);
                    if options.target_fit == TargetFit::OnGround {
                        let Some(ground) = options.ground else {
                            return Err(MeshError::BadOption(
                                "--target-fit on-ground needs a ground plane (a scene's [ground])"
                                    .into(),
                            ));
                        };
                        t.y = ground - scale * target.bounds_min[1];
                    }
                    Similarity {
                        scale,
                        translation: t.into(),
                    }
                }
            })
        };
        let fits = targets
            .iter()
            .map(|t| fit(t))
            .collect::<Result<Vec<_>, _>>()?;
        let mut shapes = source.bounds();
        for (target, to_world) in targets.iter().zip(&fits) {
            let tb = target.bounds();
            shapes = shapes.union(&Aabb::of_points(&[
                to_world.apply(&tb.min),
                to_world.apply(&tb.max),
            ]));
        }
        if let Some(ground) = options.ground {
            // The ground lies inside the domain, so the body can land on it.
            shapes.min.y = shapes.min.y.min(ground);
            shapes.max.y = shapes.max.y.max(ground);
        }
        let (target_to_world, keyframes_to_world) = match fits.split_last() {
            Some((last, earlier)) => (*last, earlier.to_vec()),
            None => (Similarity::identity(), Vec::new()),
        };
        let pad = options.pad_cells();
        let inner = options.resolution.saturating_sub(2 * pad).max(1);
        let dx = DOMAIN_SIZE / options.resolution as f64;
        let scale = inner as f64 * dx / shapes.longest_side();
        let extent = shapes.extent() * scale;
        let cells = [0, 1, 2].map(|a| {
            if a == shapes.extent().imax() {
                options.resolution
            } else {
                ((extent[a] / dx).ceil() as usize + 2 * pad).max(4)
            }
        });
        // Centre the shapes in the grid; the sim origin is the grid centre.
        let half = Vector3::new(cells[0] as f64, cells[1] as f64, cells[2] as f64) * (0.5 * dx);
        let world_to_sim = Similarity {
            scale,
            translation: (-scale * shapes.centre()).into(),
        };
        Ok(Placement {
            grid: GridSpec {
                origin: (-half).into(),
                dx,
                cells,
            },
            world_to_sim,
            target_to_world,
            keyframes_to_world,
        })
    }

    /// Target mesh coordinates -> sim coordinates.
    pub fn target_to_sim(&self) -> Similarity {
        self.world_to_sim.after(&self.target_to_world)
    }

    /// Keyframe target `k`'s mesh coordinates -> sim coordinates.
    pub fn keyframe_to_sim(&self, k: usize) -> Similarity {
        self.world_to_sim.after(&self.keyframes_to_world[k])
    }

    pub fn sim_to_world(&self) -> Similarity {
        self.world_to_sim.inverse()
    }
}

impl Placement {
    /// Frames are written as 32-bit floats in the source's units: refuses a source (named
    /// `path`) whose domain those cannot hold, or whose particle spacing (`per_cell`
    /// particles per cell axis) they cannot resolve at those coordinates.
    pub fn check_output_range(&self, path: &Path, per_cell: usize) -> Result<(), MeshError> {
        let w = self.sim_to_world();
        let g = &self.grid;
        let lo = w.apply(&Vector3::from(g.origin));
        let hi =
            w.apply(&(Vector3::from(g.origin) + g.dx * Vector3::from(g.cells.map(|c| c as f64))));
        let reach = lo.abs().max().max(hi.abs().max());
        let spacing = w.scale * g.dx / per_cell as f64;
        // Velocities reach a few domain sizes per second: keep three decades of headroom.
        const MAX_REACH: f64 = 1e35;
        // At least 64 float32 steps per particle spacing, and far from subnormal numbers.
        let min_spacing = (reach * 64.0 * f32::EPSILON as f64).max(1e-30);
        let invalid = |reason: String| {
            Err(MeshError::Invalid {
                path: path.into(),
                reason,
            })
        };
        if reach.is_nan() || reach > MAX_REACH {
            return invalid(format!(
                "as a source its coordinates reach {reach:.1e}, beyond what the 32-bit float frames can hold (about {MAX_REACH:.0e}); rescale the mesh"
            ));
        }
        if spacing.is_nan() || spacing < min_spacing {
            return invalid(format!(
                "as a source its particle spacing ({spacing:.1e} units) is below what 32-bit float frames resolve at coordinates up to {reach:.1e}; rescale the mesh or move it nearer the origin"
            ));
        }
        Ok(())
    }
}
