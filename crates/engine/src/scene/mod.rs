//! Scene description (serde JSON): grid, time step, kernel, material, particles' density and
//! the list of effects that are on. Only listed effects run.

use crate::effects::{Collider, ColliderShape, Drag, Effect, Gravity, Solid, WallMode, Walls};
use crate::material::{ConstitutiveModel, MaterialModel};
use crate::mpm::model::Model;
use crate::mpm::{Euler, GridSpec, KernelKind, SimError};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;

/// One effect and its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum EffectConfig {
    /// Linear drag `c(t)`, per second; it may switch on at `start` (seconds), eased in over
    /// `ramp` (see [`crate::effects::Drag`]).
    Drag {
        coefficient: f64,
        #[serde(default)]
        start: f64,
        #[serde(default)]
        ramp: f64,
    },
    Gravity {
        acceleration: [f64; 3],
    },
    Walls {
        mode: WallMode,
        thickness: usize,
    },
    /// A static collider with Coulomb friction (see [`crate::effects::collider`]).
    Collider {
        shape: ColliderConfig,
        #[serde(default = "default_friction")]
        friction: f64,
    },
}

/// A collider's friction when a scene does not give one.
pub const DEFAULT_FRICTION: f64 = 0.5;

fn default_friction() -> f64 {
    DEFAULT_FRICTION
}

fn unit_scale() -> f64 {
    1.0
}

/// A collider's solid, in simulation coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum ColliderConfig {
    /// The half-space below the plane through `point` with upward `normal`.
    Plane { point: [f64; 3], normal: [f64; 3] },
    /// The inside of a closed mesh file, mapped by `x -> scale x + translation`.
    Mesh {
        path: std::path::PathBuf,
        #[serde(default = "unit_scale")]
        scale: f64,
        #[serde(default)]
        translation: [f64; 3],
    },
}

/// A similarity `x -> scale x + translation` from the units a scene's effects are given in
/// (a morph's world: the source mesh's) to the simulation's grid coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldMap {
    pub scale: f64,
    pub translation: [f64; 3],
}

impl WorldMap {
    /// Effects given in the simulation's own coordinates.
    pub const IDENTITY: WorldMap = WorldMap {
        scale: 1.0,
        translation: [0.0; 3],
    };

    fn point(&self, x: [f64; 3]) -> [f64; 3] {
        (self.scale * Vector3::from(x) + Vector3::from(self.translation)).into()
    }
}

impl EffectConfig {
    /// Drag of `coefficient` per second from the first step on.
    pub fn drag(coefficient: f64) -> Self {
        EffectConfig::Drag {
            coefficient,
            start: 0.0,
            ramp: 0.0,
        }
    }

    /// The same effect in the simulation's coordinates, when `self` is given in the units
    /// `map` takes to them: positions and meshes are placed, gravity scaled; drag (per second)
    /// and walls (in cells) are the same in any units.
    pub fn placed(&self, map: &WorldMap) -> EffectConfig {
        let mut placed = self.clone();
        match &mut placed {
            EffectConfig::Gravity { acceleration } => {
                *acceleration = (map.scale * Vector3::from(*acceleration)).into();
            }
            EffectConfig::Collider { shape, .. } => match shape {
                ColliderConfig::Plane { point, .. } => *point = map.point(*point),
                ColliderConfig::Mesh {
                    scale, translation, ..
                } => {
                    *translation = map.point(*translation);
                    *scale *= map.scale;
                }
            },
            EffectConfig::Drag { .. } | EffectConfig::Walls { .. } => {}
        }
        placed
    }

    /// Checks the parameters a scene gives, in any units, before any grid is made.
    pub fn check(&self) -> Result<(), String> {
        match *self {
            EffectConfig::Drag {
                coefficient,
                start,
                ramp,
            } => {
                if !(coefficient.is_finite() && coefficient >= 0.0) {
                    return Err(format!(
                        "drag coefficient must be finite and >= 0, got {coefficient}"
                    ));
                }
                if !(start.is_finite() && start >= 0.0 && ramp.is_finite() && ramp >= 0.0) {
                    return Err(format!(
                        "drag start and ramp must be finite and >= 0, got {start} and {ramp}"
                    ));
                }
            }
            EffectConfig::Gravity { acceleration } => {
                if acceleration.iter().any(|a| !a.is_finite()) {
                    return Err(format!("gravity must be finite, got {acceleration:?}"));
                }
            }
            EffectConfig::Walls { thickness, .. } => {
                if thickness == 0 {
                    return Err("wall thickness must be at least 1 cell".into());
                }
            }
            EffectConfig::Collider {
                ref shape,
                friction,
            } => {
                if !(friction.is_finite() && friction >= 0.0) {
                    return Err(format!(
                        "collider friction must be finite and >= 0, got {friction}"
                    ));
                }
                match shape {
                    ColliderConfig::Plane { point, normal } => {
                        let n = Vector3::from(*normal);
                        if !(n.norm() > 0.0 && n.iter().chain(point).all(|v| v.is_finite())) {
                            return Err(format!(
                                "a plane collider needs a finite point and a non-zero normal, got {point:?} and {normal:?}"
                            ));
                        }
                    }
                    ColliderConfig::Mesh {
                        path,
                        scale,
                        translation,
                    } => {
                        if !(scale.is_finite()
                            && *scale > 0.0
                            && translation.iter().all(|t| t.is_finite()))
                        {
                            return Err(format!(
                                "collider {} needs a finite scale above 0 and a finite translation, got {scale} and {translation:?}",
                                path.display()
                            ));
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// The effect on `grid` (colliders find their boundary nodes on it; `solids` loads the
    /// meshes mesh colliders name).
    pub fn build(
        &self,
        grid: &GridSpec,
        solids: &dyn SolidLoader,
    ) -> Result<Box<dyn Effect>, SimError> {
        self.check().map_err(SimError::InvalidScene)?;
        Ok(match *self {
            EffectConfig::Collider {
                ref shape,
                friction,
            } => Box::new(collider(shape, friction, grid, solids)?),
            EffectConfig::Drag {
                coefficient,
                start,
                ramp,
            } => Box::new(Drag {
                coefficient,
                start,
                ramp,
            }),
            EffectConfig::Gravity { acceleration } => Box::new(Gravity {
                acceleration: Vector3::from(acceleration),
            }),
            EffectConfig::Walls { mode, thickness } => Box::new(Walls { mode, thickness }),
        })
    }
}

/// What loads the solid of a mesh collider (the engine reads no files: the layer above
/// implements it, `morph::geometry::MeshSolids`).
pub trait SolidLoader {
    /// The inside of the closed mesh at `path`, mapped by `x -> scale x + translation`; the
    /// error is the whole message (it names the file).
    fn load(
        &self,
        path: &Path,
        scale: f64,
        translation: Vector3<f64>,
    ) -> Result<Box<dyn Solid>, String>;
}

/// The loader of scenes without mesh colliders: it refuses any.
pub struct NoSolids;

impl SolidLoader for NoSolids {
    fn load(&self, path: &Path, _: f64, _: Vector3<f64>) -> Result<Box<dyn Solid>, String> {
        Err(format!(
            "collider {}: this scene was built without a mesh loader",
            path.display()
        ))
    }
}

/// A collider's boundary on `grid` (its parameters checked).
fn collider(
    shape: &ColliderConfig,
    friction: f64,
    grid: &GridSpec,
    solids: &dyn SolidLoader,
) -> Result<Collider, SimError> {
    let collider = match shape {
        ColliderConfig::Plane { point, normal } => {
            let n = Vector3::from(*normal);
            Collider::on_grid(
                "ground".into(),
                ColliderShape::HalfSpace {
                    point: Vector3::from(*point),
                    normal: n,
                },
                friction,
                grid,
            )
        }
        ColliderConfig::Mesh {
            path,
            scale,
            translation,
        } => {
            let solid = solids
                .load(path, *scale, Vector3::from(*translation))
                .map_err(SimError::InvalidScene)?;
            Collider::on_grid(
                format!("collider {}", path.display()),
                ColliderShape::Solid(solid.as_ref()),
                friction,
                grid,
            )
        }
    };
    Ok(collider)
}

/// A material: which model (a tag; fixed-corotated when absent), its Lamé parameters and its
/// density. Built into a constitutive model in one place, [`MaterialConfig::build`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MaterialConfig {
    #[serde(default)]
    pub model: MaterialModel,
    pub mu: f64,
    pub lambda: f64,
    pub density: f64,
}

impl MaterialConfig {
    /// The constitutive model.
    pub fn build(&self) -> Arc<dyn ConstitutiveModel> {
        self.model.build(self.mu, self.lambda)
    }
}

/// A complete scene without its particles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneConfig {
    pub grid: GridSpec,
    pub dt: f64,
    pub kernel: KernelKind,
    pub material: MaterialConfig,
    #[serde(default)]
    pub effects: Vec<EffectConfig>,
}

impl SceneConfig {
    /// The reference settings of the published morphing code (design.md section 6).
    pub fn reference() -> Self {
        SceneConfig {
            grid: GridSpec::centred_cube(32, 1.0),
            dt: 1.0 / 120.0,
            kernel: KernelKind::Cubic,
            material: MaterialConfig {
                model: MaterialModel::FixedCorotated,
                mu: 38888.9,
                lambda: 58333.0,
                density: 40.0,
            },
            effects: vec![EffectConfig::drag(0.5)],
        }
    }

    /// The elastic time-step bound `(dx / c, c)` of this scene's material on its grid, known
    /// before any simulator is built (every particle has the material's density).
    pub fn stable_dt(&self) -> (f64, f64) {
        let m = &self.material;
        crate::material::stable_dt(m.build().wave_modulus(), m.density, self.grid.dx)
    }

    /// Builds the Euler simulator for particles of the given rest volumes.
    pub fn build(&self, volumes: Vec<f64>) -> Result<Euler, SimError> {
        self.model(volumes).map(Euler::from)
    }

    /// Builds the model for particles of the given rest volumes (mass = density x volume), in
    /// one place for both integrators; a scene with a mesh collider needs
    /// [`SceneConfig::model_with`].
    pub fn model(&self, volumes: Vec<f64>) -> Result<Model, SimError> {
        self.model_with(volumes, &NoSolids)
    }

    /// [`SceneConfig::model`] with `solids` loading the meshes of mesh colliders.
    pub fn model_with(
        &self,
        volumes: Vec<f64>,
        solids: &dyn SolidLoader,
    ) -> Result<Model, SimError> {
        let m = &self.material;
        for (name, val) in [("mu", m.mu), ("lambda", m.lambda), ("density", m.density)] {
            if !val.is_finite() || val < 0.0 || (name == "density" && val == 0.0) {
                return Err(SimError::InvalidScene(format!(
                    "material {name} must be finite and positive, got {val}"
                )));
            }
        }
        let effects = self
            .effects
            .iter()
            .map(|e| e.build(&self.grid, solids))
            .collect::<Result<Vec<_>, _>>()?;
        let mass = volumes.iter().map(|v| v * m.density).collect();
        Model::new(
            self.grid.clone(),
            self.dt,
            self.kernel,
            m.build(),
            effects,
            mass,
            volumes,
        )
    }
}

/// Particles on a lattice of `per_cell^3` per cell inside a ball, with their rest volumes.
pub fn ball_particles(
    grid: &GridSpec,
    centre: Vector3<f64>,
    radius: f64,
    per_cell: usize,
) -> (Vec<Vector3<f64>>, Vec<f64>) {
    let h = grid.dx / per_cell as f64;
    let o = grid.origin_vec();
    let mut pts = Vec::new();
    for i in 0..grid.cells[0] * per_cell {
        for j in 0..grid.cells[1] * per_cell {
            for k in 0..grid.cells[2] * per_cell {
                let x = o + h * Vector3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5);
                if (x - centre).norm() < radius {
                    pts.push(x);
                }
            }
        }
    }
    let vol = vec![h * h * h; pts.len()];
    (pts, vol)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A world effect placed on the grid: positions and meshes mapped, gravity scaled, drag and
    /// walls as they are.
    #[test]
    fn placing_maps_positions_and_meshes_and_scales_gravity() {
        let map = WorldMap {
            scale: 4.0,
            translation: [1.0, 2.0, 3.0],
        };
        let gravity = EffectConfig::Gravity {
            acceleration: [0.0, -9.81, 0.0],
        };
        assert_eq!(
            gravity.placed(&map),
            EffectConfig::Gravity {
                acceleration: [0.0, -39.24, 0.0]
            }
        );
        let plane = EffectConfig::Collider {
            shape: ColliderConfig::Plane {
                point: [0.0, -1.0, 0.0],
                normal: [0.0, 1.0, 0.0],
            },
            friction: 0.2,
        };
        let EffectConfig::Collider {
            shape: ColliderConfig::Plane { point, normal },
            ..
        } = plane.placed(&map)
        else {
            panic!()
        };
        assert_eq!((point, normal), ([1.0, -2.0, 3.0], [0.0, 1.0, 0.0]));
        let mesh = EffectConfig::Collider {
            shape: ColliderConfig::Mesh {
                path: "rock.obj".into(),
                scale: 0.5,
                translation: [1.0, 0.0, 0.0],
            },
            friction: 0.2,
        };
        // x -> 4 (0.5 x + (1, 0, 0)) + (1, 2, 3) = 2 x + (5, 2, 3).
        let EffectConfig::Collider {
            shape: ColliderConfig::Mesh {
                scale, translation, ..
            },
            ..
        } = mesh.placed(&map)
        else {
            panic!()
        };
        assert_eq!((scale, translation), (2.0, [5.0, 2.0, 3.0]));
        let drag = EffectConfig::drag(0.5);
        assert_eq!(drag.placed(&map), drag);
        assert_eq!(WorldMap::IDENTITY.point([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    }

    /// A mesh collider needs a loader: without one the scene is refused, naming the file.
    #[test]
    fn a_mesh_collider_without_a_loader_is_refused_naming_its_file() {
        let mut scene = SceneConfig::reference();
        scene.effects.push(EffectConfig::Collider {
            shape: ColliderConfig::Mesh {
                path: "rock.obj".into(),
                scale: 1.0,
                translation: [0.0; 3],
            },
            friction: 0.5,
        });
        match scene.model(vec![1e-3; 8]) {
            Err(SimError::InvalidScene(why)) => {
                assert!(
                    why.contains("rock.obj") && why.contains("mesh loader"),
                    "{why}"
                )
            }
            other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
        }
    }
}
