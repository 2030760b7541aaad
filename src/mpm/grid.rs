//! The background grid and the deterministic parallel scatter.
//!
//! Scatters (P2G, and the transpose of G2P in the reverse pass) are where parallel MPM codes
//! usually lose determinism: several threads add into the same node in whatever order they run.
//! Here particles are sorted into blocks of `BLOCK^3` cells by a counting sort (stable, so each
//! block keeps ascending particle order), and blocks are coloured by the parity of their block
//! coordinates. Two blocks of one colour are `2 * BLOCK` nodes apart, more than the `BLOCK +
//! N - 1` nodes one block's particles can touch, so blocks of one colour write disjoint nodes
//! and can run in parallel. Every node therefore receives its contributions in an order fixed
//! by the particle positions alone: results are bitwise identical for any thread count.

use super::error::SimError;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Cells per block edge. Must be at least `N - 1` for the widest kernel (cubic, N = 4).
pub const BLOCK: usize = 4;

/// Geometry of the grid: node `(i, j, k)` sits at `origin + dx * (i, j, k)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    pub origin: [f64; 3],
    pub dx: f64,
    /// Cells per axis; there are `cells + 1` nodes per axis.
    pub cells: [usize; 3],
}

impl GridSpec {
    /// A cube of `cells^3` cells of size `dx` centred on the origin.
    pub fn centred_cube(cells: usize, dx: f64) -> Self {
        let half = 0.5 * cells as f64 * dx;
        GridSpec {
            origin: [-half; 3],
            dx,
            cells: [cells; 3],
        }
    }

    pub fn nodes(&self) -> [usize; 3] {
        [self.cells[0] + 1, self.cells[1] + 1, self.cells[2] + 1]
    }

    pub fn node_count(&self) -> usize {
        let n = self.nodes();
        n[0] * n[1] * n[2]
    }

    pub fn origin_vec(&self) -> Vector3<f64> {
        Vector3::from(self.origin)
    }

    /// Flat index strides (x slowest, z fastest).
    pub fn strides(&self) -> [usize; 3] {
        let n = self.nodes();
        [n[1] * n[2], n[2], 1]
    }

    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        let s = self.strides();
        i * s[0] + j * s[1] + k
    }

    pub fn node_position(&self, i: usize, j: usize, k: usize) -> Vector3<f64> {
        self.origin_vec() + self.dx * Vector3::new(i as f64, j as f64, k as f64)
    }

    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |why: &str| Err(SimError::InvalidScene(format!("grid: {why}")));
        if !(self.dx.is_finite() && self.dx > 0.0) {
            return bad(&format!(
                "dx must be a positive finite number, got {}",
                self.dx
            ));
        }
        if self.origin.iter().any(|o| !o.is_finite()) {
            return bad("origin must be finite");
        }
        if self.cells.iter().any(|&c| !(4..=1024).contains(&c)) {
            return bad(&format!(
                "cells per axis must be in 4..=1024, got {:?}",
                self.cells
            ));
        }
        Ok(())
    }
}

/// Half-open range of `Bins::order` holding one block's particles.
#[derive(Clone, Copy, Debug)]
pub struct BlockRange {
    pub start: u32,
    pub end: u32,
}

/// Particles sorted into blocks, and the non-empty blocks grouped by colour.
#[derive(Clone, Debug, Default)]
pub struct Bins {
    /// Particle indices, grouped by block, ascending within a block.
    pub order: Vec<u32>,
    /// Non-empty blocks of each of the 8 colours.
    pub colours: [Vec<BlockRange>; 8],
}

impl Bins {
    /// Sorts particles by the block of their stencil base node. Fails on the first (lowest
    /// index) particle that is not finite or whose `support`-wide stencil leaves the grid.
    pub fn build(
        spec: &GridSpec,
        positions: &[Vector3<f64>],
        support: usize,
        step: usize,
    ) -> Result<Bins, SimError> {
        let nodes = spec.nodes();
        let origin = spec.origin_vec();
        let inv_dx = 1.0 / spec.dx;
        let bdims = nodes.map(|n| n.div_ceil(BLOCK));
        // Stencil base node per axis, as in `Stencil::new`.
        let base_of = |x: f64, a: usize| -> f64 {
            let xg = (x - origin[a]) * inv_dx;
            if support == 3 {
                super::kernel::floor(xg - 0.5)
            } else {
                super::kernel::floor(xg) - 1.0
            }
        };
        let block_of: Vec<u32> = positions
            .par_iter()
            .map(|x| {
                let mut blk = 0usize;
                for a in 0..3 {
                    let b = base_of(x[a], a);
                    // Also rejects NaN: every comparison with NaN is false.
                    if !(b >= 0.0 && b + (support as f64) <= nodes[a] as f64) {
                        return u32::MAX;
                    }
                    blk = blk * bdims[a] + (b as usize) / BLOCK;
                }
                blk as u32
            })
            .collect();
        if let Some(p) = block_of.par_iter().position_first(|&b| b == u32::MAX) {
            let x = positions[p];
            return Err(if x.iter().all(|c| c.is_finite()) {
                SimError::OutsideGrid {
                    step,
                    particle: p,
                    position: [x[0], x[1], x[2]],
                }
            } else {
                SimError::NonFinite {
                    step,
                    particle: p,
                    field: "position",
                }
            });
        }
        // Stable counting sort by block.
        let nblocks = bdims[0] * bdims[1] * bdims[2];
        let mut start = vec![0u32; nblocks + 1];
        for &b in &block_of {
            start[b as usize + 1] += 1;
        }
        for b in 0..nblocks {
            start[b + 1] += start[b];
        }
        let mut fill = start.clone();
        let mut order = vec![0u32; positions.len()];
        for (p, &b) in block_of.iter().enumerate() {
            order[fill[b as usize] as usize] = p as u32;
            fill[b as usize] += 1;
        }
        let mut colours: [Vec<BlockRange>; 8] = Default::default();
        for bx in 0..bdims[0] {
            for by in 0..bdims[1] {
                for bz in 0..bdims[2] {
                    let b = (bx * bdims[1] + by) * bdims[2] + bz;
                    if start[b] < start[b + 1] {
                        let colour = (bx % 2) * 4 + (by % 2) * 2 + bz % 2;
                        colours[colour].push(BlockRange {
                            start: start[b],
                            end: start[b + 1],
                        });
                    }
                }
            }
        }
        Ok(Bins { order, colours })
    }

    /// Calls `f(p)` for every particle, colour by colour; blocks of one colour run in parallel,
    /// particles of a block in ascending order. `f` may add into the grid nodes of particle
    /// `p`'s stencil (and write particle `p`'s own data) through [`SharedMut`].
    pub fn for_each_coloured(&self, f: impl Fn(usize) + Sync) {
        for blocks in &self.colours {
            blocks.par_iter().for_each(|r| {
                for &p in &self.order[r.start as usize..r.end as usize] {
                    f(p as usize);
                }
            });
        }
    }

    /// [`Bins::for_each_coloured`] when `parallel`, else every particle on this thread in the
    /// very same order (so both give identical sums in every node).
    pub fn visit_coloured(&self, parallel: bool, f: impl Fn(usize) + Sync) {
        if parallel {
            self.for_each_coloured(f);
        } else {
            for blocks in &self.colours {
                for r in blocks {
                    for &p in &self.order[r.start as usize..r.end as usize] {
                        f(p as usize);
                    }
                }
            }
        }
    }
}

/// A mutable slice shared across the threads of a coloured scatter.
///
/// Safety rests on the colouring in [`Bins::for_each_coloured`]: concurrent calls only touch
/// disjoint nodes (stencils of blocks of one colour do not overlap) and distinct particles.
pub struct SharedMut<'a, T> {
    ptr: *mut T,
    len: usize,
    _life: std::marker::PhantomData<&'a mut [T]>,
}

unsafe impl<T: Send> Sync for SharedMut<'_, T> {}
unsafe impl<T: Send> Send for SharedMut<'_, T> {}

impl<'a, T> SharedMut<'a, T> {
    pub fn new(slice: &'a mut [T]) -> Self {
        SharedMut {
            ptr: slice.as_mut_ptr(),
            len: slice.len(),
            _life: std::marker::PhantomData,
        }
    }

    /// # Safety
    /// No other thread may access element `i` while the returned reference lives.
    #[inline(always)]
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn get(&self, i: usize) -> &mut T {
        debug_assert!(i < self.len);
        unsafe { &mut *self.ptr.add(i) }
    }

    /// Elements `start..start + len`.
    ///
    /// # Safety
    /// No other thread may access them while the returned slice lives.
    #[inline(always)]
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn run(&self, start: usize, len: usize) -> &mut [T] {
        assert!(start + len <= self.len);
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), len) }
    }
}
