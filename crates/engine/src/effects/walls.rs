//! Boundary walls on the grid's faces: nodes within `thickness` cells of a face are
//! sticky (velocity set to zero) or slip (the velocity component into the wall is removed;
//! motion along the wall and away from it is kept). In the ODE form the same components of
//! the node's velocity and acceleration are removed: one rule for both forms.

use super::{Effect, GridContext, GridForm, GridRule, NodeMotion};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallMode {
    Sticky,
    Slip,
}

#[derive(Clone, Copy, Debug)]
pub struct Walls {
    pub mode: WallMode,
    /// Boundary layer width in cells.
    pub thickness: usize,
}

impl Walls {
    /// Which components of velocity `v` the wall keeps at `node` (`None`: not in a wall
    /// layer). On each axis the node is in the low layer, the high one, or neither.
    #[inline]
    fn mask(&self, ctx: &GridContext, node: usize, v: &Vector3<f64>) -> Option<[bool; 3]> {
        let n = ctx.spec.nodes();
        let s = ctx.spec.strides();
        let idx = [node / s[0], (node / s[1]) % n[1], node % n[2]];
        let t = self.thickness;
        let sides: [i8; 3] = std::array::from_fn(|a| {
            if idx[a] < t {
                -1
            } else if idx[a] + t >= n[a] {
                1
            } else {
                0
            }
        });
        if sides == [0, 0, 0] {
            return None;
        }
        Some(match self.mode {
            WallMode::Sticky => [false; 3],
            // Moving into the wall means v . outward normal > 0 on that face.
            WallMode::Slip => [0, 1, 2].map(|a| !(sides[a] != 0 && v[a] * sides[a] as f64 > 0.0)),
        })
    }
}

impl Effect for Walls {
    fn name(&self) -> &'static str {
        "walls"
    }

    /// The same rule in both forms: the components removed from the velocity are removed
    /// from the acceleration too (zero in the Euler step).
    fn acts_on_grid(&self, _: GridForm) -> bool {
        true
    }

    fn grid_rule(&self) -> Option<GridRule> {
        Some(GridRule::Walls {
            sticky: self.mode == WallMode::Sticky,
            thickness: self.thickness,
        })
    }

    fn apply_grid(&self, ctx: &GridContext, node: usize, m: &mut NodeMotion) {
        if let Some(keep) = self.mask(ctx, node, &m.v) {
            for (k, kept) in keep.into_iter().enumerate() {
                if !kept {
                    m.v[k] = 0.0;
                    m.a[k] = 0.0;
                }
            }
        }
    }

    fn reverse_grid(
        &self,
        ctx: &GridContext,
        node: usize,
        input: &NodeMotion,
        grad: &mut NodeMotion,
        _: &mut [f64],
    ) {
        if let Some(keep) = self.mask(ctx, node, &input.v) {
            for (k, kept) in keep.into_iter().enumerate() {
                if !kept {
                    grad.v[k] = 0.0;
                    grad.a[k] = 0.0;
                }
            }
        }
    }
}
