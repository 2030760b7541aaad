//! Boundary walls on the grid's faces: nodes within `thickness` cells of a face are
//! sticky (velocity set to zero) or slip (the velocity component into the wall is removed;
//! motion along the wall and away from it is kept). In the ODE form the same components of
//! the node's velocity and acceleration are removed.

use super::{Effect, GridContext};
use nalgebra::Vector3;
use rayon::prelude::*;
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
    /// For each axis, -1 if node index `i` is in the low wall layer, +1 in the high one, else 0.
    #[inline]
    fn sides(&self, ctx: &GridContext, node: usize) -> [i8; 3] {
        let n = ctx.spec.nodes();
        let s = ctx.spec.strides();
        self.sides_at(n, [node / s[0], (node / s[1]) % n[1], node % n[2]])
    }

    /// [`Walls::sides`] of the node with indices `idx` on a grid of `n` nodes per axis.
    #[inline]
    fn sides_at(&self, n: [usize; 3], idx: [usize; 3]) -> [i8; 3] {
        let t = self.thickness;
        let mut out = [0i8; 3];
        for a in 0..3 {
            if idx[a] < t {
                out[a] = -1;
            } else if idx[a] + t >= n[a] {
                out[a] = 1;
            }
        }
        out
    }

    /// Per-axis mask (1 keep, 0 zero) that the wall applies to velocity `v` at `node`.
    #[inline]
    fn mask(&self, ctx: &GridContext, node: usize, v: &Vector3<f64>) -> Option<[bool; 3]> {
        self.mask_at(self.sides(ctx, node), v)
    }

    /// [`Walls::mask`] given the node's sides.
    #[inline]
    fn mask_at(&self, sides: [i8; 3], v: &Vector3<f64>) -> Option<[bool; 3]> {
        if sides == [0, 0, 0] {
            return None;
        }
        Some(match self.mode {
            WallMode::Sticky => [false; 3],
            // Moving into the wall means v . outward normal > 0 on that face.
            WallMode::Slip => [0, 1, 2].map(|a| !(sides[a] != 0 && v[a] * sides[a] as f64 > 0.0)),
        })
    }

    /// Zeroes the components of `out` the wall removes at each node, deciding from `v`
    /// (the velocity the wall sees). Walks the grid row by row: no division per node.
    fn zero_masked(&self, ctx: &GridContext, v: Option<&[Vector3<f64>]>, out: &mut [Vector3<f64>]) {
        let n = ctx.spec.nodes();
        out.par_chunks_mut(n[2])
            .enumerate()
            .for_each(|(row, outs)| {
                let (i, j) = (row / n[1], row % n[1]);
                for (k, o) in outs.iter_mut().enumerate() {
                    let seen = v.map_or(*o, |v| v[row * n[2] + k]);
                    if let Some(keep) = self.mask_at(self.sides_at(n, [i, j, k]), &seen) {
                        for a in 0..3 {
                            if !keep[a] {
                                o[a] = 0.0;
                            }
                        }
                    }
                }
            });
    }
}

impl Effect for Walls {
    fn name(&self) -> &'static str {
        "walls"
    }

    fn acts_on_grid(&self) -> bool {
        true
    }

    fn apply_grid(&self, ctx: &GridContext, v: &mut [Vector3<f64>]) {
        self.zero_masked(ctx, None, v);
    }

    fn acts_on_rates(&self) -> bool {
        true
    }

    fn apply_rate(
        &self,
        ctx: &GridContext,
        node: usize,
        v: &mut Vector3<f64>,
        a: &mut Vector3<f64>,
    ) {
        if let Some(keep) = self.mask(ctx, node, v) {
            for k in 0..3 {
                if !keep[k] {
                    v[k] = 0.0;
                    a[k] = 0.0;
                }
            }
        }
    }

    fn reverse_rate(
        &self,
        ctx: &GridContext,
        node: usize,
        v_in: &Vector3<f64>,
        _: &Vector3<f64>,
        grad_v: &mut Vector3<f64>,
        grad_a: &mut Vector3<f64>,
        _: &mut [f64],
    ) {
        if let Some(keep) = self.mask(ctx, node, v_in) {
            for k in 0..3 {
                if !keep[k] {
                    grad_v[k] = 0.0;
                    grad_a[k] = 0.0;
                }
            }
        }
    }

    fn reverse_grid(
        &self,
        ctx: &GridContext,
        v_in: &[Vector3<f64>],
        grad_v: &mut [Vector3<f64>],
        _grad_params: &mut [f64],
    ) {
        self.zero_masked(ctx, Some(v_in), grad_v);
    }
}
