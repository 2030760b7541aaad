//! The world a body is in: the engine's own effect specs, in the source mesh's units.
//!
//! A run places them on its grid with [`EffectConfig::placed`] and the placement's map; nothing
//! between the settings and the engine translates them. A scene file may give the list itself
//! (`[[world.effects]]`) or the shorthand keys a shot usually needs (`gravity`, `drag`,
//! `[ground]`, `[[colliders]]`, `[walls]`), which set their entries of the list as it is read.

use crate::engine::effects::WallMode;
use crate::engine::scene::{ColliderConfig, DEFAULT_FRICTION, EffectConfig};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The walls on the grid's faces (a safety net: no kernel stencil may leave the grid) are at
/// least this deep: the cubic kernel reaches two cells from a particle.
pub const MIN_WALL_THICKNESS: usize = 3;

/// The world's effects, in the order they act, in the source mesh's units (y is up).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "WorldKeys")]
pub struct World {
    pub effects: Vec<EffectConfig>,
}

/// A ground plane: everything below `height` (the source mesh's y) is solid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ground {
    pub height: f64,
    /// Coulomb friction coefficient (0: ice).
    #[serde(default = "default_friction")]
    pub friction: f64,
}

/// A closed mesh, in the source mesh's coordinates, that the body cannot enter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshCollider {
    pub mesh: PathBuf,
    /// Coulomb friction coefficient (0: frictionless).
    #[serde(default = "default_friction")]
    pub friction: f64,
}

/// The walls on the grid's faces.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WallSettings {
    /// Slip (the body slides along a wall) or sticky (it stops there).
    pub mode: WallMode,
    /// Depth in grid cells, at least [`MIN_WALL_THICKNESS`].
    pub thickness: usize,
}

fn default_friction() -> f64 {
    DEFAULT_FRICTION
}

/// What a file may give for the world: the list and the shorthand keys over it.
#[derive(Deserialize)]
struct WorldKeys {
    #[serde(default)]
    effects: Vec<EffectConfig>,
    /// Gravity in the source mesh's units per second squared (`[0, -9.81, 0]` for metres).
    gravity: Option<[f64; 3]>,
    /// The air's drag per second, from the first frame on (0 takes it out).
    drag: Option<f64>,
    ground: Option<Ground>,
    /// The mesh colliders: they replace the list's.
    colliders: Option<Vec<MeshCollider>>,
    walls: Option<WallSettings>,
}

impl From<WorldKeys> for World {
    fn from(keys: WorldKeys) -> World {
        let mut world = World {
            effects: keys.effects,
        };
        if let Some(c) = keys.drag {
            world.set(EffectConfig::drag(c), |e| is_air_drag(e));
            if c == 0.0 {
                world.effects.retain(|e| !is_air_drag(e));
            }
        }
        if let Some(acceleration) = keys.gravity {
            world.set(EffectConfig::Gravity { acceleration }, |e| {
                matches!(e, EffectConfig::Gravity { .. })
            });
        }
        if let Some(g) = keys.ground {
            world.set(ground_plane(g.height, g.friction), |e| {
                ground_of(e).is_some()
            });
        }
        if let Some(colliders) = keys.colliders {
            world.effects.retain(|e| mesh_of(e).is_none());
            for c in colliders {
                world.insert(EffectConfig::Collider {
                    shape: ColliderConfig::Mesh {
                        path: c.mesh,
                        scale: 1.0,
                        translation: [0.0; 3],
                    },
                    friction: c.friction,
                });
            }
        }
        if let Some(WallSettings { mode, thickness }) = keys.walls {
            world.set(EffectConfig::Walls { mode, thickness }, |e| {
                matches!(e, EffectConfig::Walls { .. })
            });
        }
        world
    }
}

impl World {
    /// The presets' world: the reference's drag of 0.5 per second, and slip walls.
    pub fn preset() -> World {
        World {
            effects: vec![
                EffectConfig::drag(0.5),
                EffectConfig::Walls {
                    mode: WallMode::Slip,
                    thickness: MIN_WALL_THICKNESS,
                },
            ],
        }
    }

    /// Replaces the first effect `is_slot` picks with `effect`, or inserts it in its place.
    fn set(&mut self, effect: EffectConfig, is_slot: impl Fn(&EffectConfig) -> bool) {
        match self.effects.iter().position(is_slot) {
            Some(i) => self.effects[i] = effect,
            None => self.insert(effect),
        }
    }

    /// Inserts `effect` before the first effect that acts after its kind (drag, gravity, the
    /// ground, colliders, walls: the order in which a shot's effects act).
    fn insert(&mut self, effect: EffectConfig) {
        let rank = order(&effect);
        let at = (self.effects.iter())
            .position(|e| order(e) > rank)
            .unwrap_or(self.effects.len());
        self.effects.insert(at, effect);
    }

    /// The ground's height and friction: the first plane collider facing straight up.
    pub fn ground(&self) -> Option<(f64, f64)> {
        self.effects.iter().find_map(ground_of)
    }

    /// Whether the world pulls the body down (or any way).
    pub fn has_gravity(&self) -> bool {
        (self.effects.iter()).any(|e| matches!(e, EffectConfig::Gravity { .. }))
    }

    /// The drag coefficients together (the most the air can damp at once).
    pub fn drag(&self) -> f64 {
        (self.effects.iter())
            .map(|e| match e {
                EffectConfig::Drag { coefficient, .. } => *coefficient,
                _ => 0.0,
            })
            .sum()
    }

    /// The mesh colliders' files.
    pub fn meshes(&self) -> impl Iterator<Item = &Path> {
        self.effects.iter().filter_map(mesh_of)
    }

    /// Each mesh collider's file, to be replaced (made absolute, or hashed).
    pub fn meshes_mut(&mut self) -> impl Iterator<Item = &mut PathBuf> {
        self.effects.iter_mut().filter_map(|e| match e {
            EffectConfig::Collider {
                shape: ColliderConfig::Mesh { path, .. },
                ..
            } => Some(path),
            _ => None,
        })
    }

    /// Each effect's parameters, and the walls every world has as its safety net.
    pub fn validate(&self) -> Result<(), String> {
        for e in &self.effects {
            e.check().map_err(|why| format!("world: {why}"))?;
        }
        let walls: Vec<usize> = (self.effects.iter())
            .filter_map(|e| match e {
                EffectConfig::Walls { thickness, .. } => Some(*thickness),
                _ => None,
            })
            .collect();
        match walls[..] {
            [t] if t >= MIN_WALL_THICKNESS => Ok(()),
            [t] => Err(format!(
                "walls thickness must be at least {MIN_WALL_THICKNESS} cells (the kernel's reach), got {t}"
            )),
            _ => Err(format!(
                "the world has {} walls effects; it needs one (`[walls] mode = \"slip\", thickness = {MIN_WALL_THICKNESS}`): they keep every particle on the grid",
                walls.len()
            )),
        }
    }
}

/// The plane below `height` (the ground).
fn ground_plane(height: f64, friction: f64) -> EffectConfig {
    EffectConfig::Collider {
        shape: ColliderConfig::Plane {
            point: [0.0, height, 0.0],
            normal: [0.0, 1.0, 0.0],
        },
        friction,
    }
}

/// The height and friction of a plane collider that faces straight up.
fn ground_of(e: &EffectConfig) -> Option<(f64, f64)> {
    match e {
        EffectConfig::Collider {
            shape: ColliderConfig::Plane { point, normal },
            friction,
        } if normal[0] == 0.0 && normal[2] == 0.0 && normal[1] > 0.0 => Some((point[1], *friction)),
        _ => None,
    }
}

fn mesh_of(e: &EffectConfig) -> Option<&Path> {
    match e {
        EffectConfig::Collider {
            shape: ColliderConfig::Mesh { path, .. },
            ..
        } => Some(path),
        _ => None,
    }
}

/// A drag on from the first step (the `drag` key's; a later one is the settling's).
fn is_air_drag(e: &EffectConfig) -> bool {
    matches!(e, EffectConfig::Drag { start, .. } if *start == 0.0)
}

/// Where an effect's kind acts among a shot's effects.
fn order(e: &EffectConfig) -> u8 {
    match e {
        EffectConfig::Drag { .. } => 0,
        EffectConfig::Gravity { .. } => 1,
        e if ground_of(e).is_some() => 2,
        EffectConfig::Collider { .. } => 3,
        EffectConfig::Walls { .. } => 4,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> World {
        let mut table: toml::Table = toml::to_string(&World::preset()).unwrap().parse().unwrap();
        table.extend(text.parse::<toml::Table>().unwrap());
        table.try_into().unwrap()
    }

    #[test]
    fn the_shorthand_keys_set_their_entries_in_the_order_effects_act() {
        let w = read(
            "gravity = [0.0, -9.81, 0.0]\n[ground]\nheight = -1.0\n[[colliders]]\nmesh = \"rock.obj\"\nfriction = 0.2\n",
        );
        let kinds: Vec<u8> = w.effects.iter().map(order).collect();
        assert_eq!(kinds, [0, 1, 2, 3, 4], "{w:?}");
        assert_eq!(w.ground(), Some((-1.0, DEFAULT_FRICTION)));
        assert_eq!(w.meshes().collect::<Vec<_>>(), [Path::new("rock.obj")]);
        assert!(w.has_gravity() && w.validate().is_ok());
        // Given again, a key replaces its entry; drag 0 takes the air's drag out.
        let w = read("drag = 0.0\n[walls]\nmode = \"sticky\"\nthickness = 4\n");
        assert_eq!(w.drag(), 0.0);
        assert_eq!(
            w.effects,
            [EffectConfig::Walls {
                mode: WallMode::Sticky,
                thickness: 4
            }]
        );
        // The list as it serializes reads back to itself.
        let again: World = toml::to_string(&w)
            .unwrap()
            .parse::<toml::Table>()
            .unwrap()
            .try_into()
            .unwrap();
        assert_eq!(again, w);
    }

    #[test]
    fn a_world_needs_one_wall_of_the_kernels_reach() {
        let mut w = World::preset();
        assert!(w.validate().is_ok());
        w.effects.pop();
        assert!(w.validate().unwrap_err().contains("needs one"));
        let w = read("[walls]\nmode = \"slip\"\nthickness = 2\n");
        assert!(w.validate().unwrap_err().contains("at least 3"));
    }
}
