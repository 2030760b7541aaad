//! The background grid and the deterministic parallel scatter.
//!
//! Scatters (P2G, and the transpose of G2P in the reverse pass) are where parallel MPM codes
//! usually lose determinism: several threads add into the same node in whatever order they run.
//! Here particles are sorted into blocks of `BLOCK^3` cells by a counting sort (stable, so each
//! block keeps ascending particle order). A scatter then runs in two phases:
//!
//! 1. **Tiles.** Every non-empty block, all of them in parallel, adds its particles (in
//!    ascending order) into a tile of its own: the `TILE^3` nodes its particles' stencils can
//!    reach, starting from zeros. No two tasks write the same memory, and there is no barrier
//!    between blocks (GPU MPM codes do the same in shared memory).
//! 2. **Sum.** Every grid node is written once, as the sum of the tiles that reach it, taken
//!    in ascending block order (at most 8 tiles: the block the node lies in and its lower
//!    neighbours along each axis), in parallel over columns of blocks.
//!
//! Every node therefore receives the same additions in the same order whatever the thread
//! count: results are bitwise identical for any number of threads.
//!
//! **The region.** A tile reaches its own block and the next one along each axis, so the
//! nodes any particle's stencil touches lie in the *region*: every non-empty block and its
//! upper neighbours. Phase 2 writes the region's nodes alone, and every grid pass of both
//! integrators (the grid update, the effects, the changes of layout) visits them alone:
//! the cost of a step follows the body, not the domain. Outside the region a grid array
//! holds whatever an earlier step left there, and nothing reads it.

use super::error::SimError;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Cells per block edge. Must be at least `N - 1` for the widest kernel (cubic, N = 4).
pub const BLOCK: usize = 4;

/// Nodes along each axis of a block's tile: the `BLOCK + N - 1` nodes its particles'
/// stencils reach (7 for the cubic kernel), padded to 8 so that a node lies at most two
/// tiles deep along an axis (its own block's and the block below).
pub const TILE: usize = 8;
/// Nodes in a tile.
pub const TILE_NODES: usize = TILE * TILE * TILE;
const _: () = assert!(TILE >= BLOCK + 4 - 1 && TILE <= 2 * BLOCK);
/// Values from one channel of a tile to the next: a tile's nodes and two cache lines, so that
/// a node's channels are not a multiple of 4 KiB apart (loads then wait on stores to another
/// channel: "4K aliasing").
const CHANNEL: usize = TILE_NODES + 16;

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

/// One non-empty block: its particles (a half-open range of `Bins::order`) and its block
/// coordinates (its first cell is `BLOCK * coords`).
#[derive(Clone, Copy, Debug)]
pub struct Block {
    pub start: u32,
    pub end: u32,
    pub coords: [u32; 3],
}

impl Block {
    /// How many particles the block holds.
    pub fn particle_count(&self) -> usize {
        (self.end - self.start) as usize
    }
}

/// Particles sorted into blocks.
#[derive(Clone, Debug, Default)]
pub struct Bins {
    /// Particle indices, grouped by block, ascending within a block.
    pub order: Vec<u32>,
    /// The non-empty blocks, in ascending block index (x slowest).
    pub blocks: Vec<Block>,
    /// Blocks per axis (enough to cover every node).
    dims: [usize; 3],
    /// Nodes per axis.
    nodes: [usize; 3],
    /// For every block of the lattice, its place in `blocks`, or [`NO_BLOCK`].
    slot: Vec<u32>,
    /// The region's blocks (see the module's note), as lattice indices in ascending order.
    region: Vec<u32>,
}

const NO_BLOCK: u32 = u32::MAX;

/// Where one block's scatter lands: its tile, `channels` arrays of [`TILE_NODES`] values
/// (for example mass, then each field's three axes), the nodes of a row side by side.
pub struct Tile<'a> {
    data: &'a mut [f64],
    /// The tile's first node as a flat index under [`Tile::STRIDES`].
    offset: usize,
}

impl Tile<'_> {
    /// Flat index strides within a tile (x slowest, z fastest).
    pub const STRIDES: [usize; 3] = [TILE * TILE, TILE, 1];

    /// The tile-local index of the first node of stencil `s` (whose particle is in this
    /// tile's block).
    #[inline(always)]
    pub fn base<const N: usize>(&self, s: &super::kernel::Stencil<N>) -> usize {
        s.base_index(&Self::STRIDES) - self.offset
    }

    /// Channel `c` of the tile.
    #[inline(always)]
    pub fn channel(&mut self, c: usize) -> &mut [f64] {
        &mut self.data[c * CHANNEL..c * CHANNEL + TILE_NODES]
    }

    /// `len` nodes of channel `c` from tile-local index `start`.
    #[inline(always)]
    pub fn run(&mut self, c: usize, start: usize, len: usize) -> &mut [f64] {
        &mut self.channel(c)[start..start + len]
    }
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
        // Each particle's block: that of its stencil base node, `floor(xg - 0.5)` (quadratic)
        // or `floor(xg) - 1` (cubic) as in `Stencil::new`, where `xg` is its position in
        // cells. With `y = xg - 0.5` (or `xg - 1`, exact for `xg >= 1`) the stencil lies on
        // the grid iff `0 <= y < nodes + 1 - support`, and there the floor is the truncation,
        // so the check comes first and no floor (a branch) is taken. NaN fails the check.
        let shift = if support == 3 { 0.5 } else { 1.0 };
        let ends = nodes.map(|n| (n + 1) as f64 - support as f64);
        let block_of: Vec<u32> = positions
            .par_iter()
            .map(|x| {
                let mut blk = 0usize;
                for a in 0..3 {
                    let y = (x[a] - origin[a]) * inv_dx - shift;
                    if !(y >= 0.0 && y < ends[a]) {
                        return u32::MAX;
                    }
                    blk = blk * bdims[a] + (y as usize) / BLOCK;
                }
                blk as u32
            })
            .collect();
        // A serial scan: rayon's `position_first` checked a shared flag at every particle and
        // cost a third of the build.
        if let Some(p) = block_of.iter().position(|&b| b == u32::MAX) {
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
        let mut blocks = Vec::new();
        let mut slot = vec![NO_BLOCK; nblocks];
        for bx in 0..bdims[0] {
            for by in 0..bdims[1] {
                for bz in 0..bdims[2] {
                    let b = (bx * bdims[1] + by) * bdims[2] + bz;
                    if start[b] < start[b + 1] {
                        slot[b] = blocks.len() as u32;
                        blocks.push(Block {
                            start: start[b],
                            end: start[b + 1],
                            coords: [bx as u32, by as u32, bz as u32],
                        });
                    }
                }
            }
        }
        let region = region_of(&blocks, bdims);
        Ok(Bins {
            order,
            blocks,
            dims: bdims,
            nodes,
            slot,
            region,
        })
    }

    /// The region's nodes (see the module's note), row by row: `row(start, len)` for each
    /// run of `len` consecutive node indices from `start` (one block's row along z), on many
    /// threads when `parallel`. Rows are disjoint, so writers may share their arrays
    /// ([`SharedMut`]).
    pub fn for_each_region_row(&self, parallel: bool, row: impl Fn(usize, usize) + Sync) {
        let [nx, ny, nz] = self.nodes;
        self.for_each_region_block(parallel, |block| {
            let [x0, y0, z0] = block.map(|c| c * BLOCK);
            let len = BLOCK.min(nz - z0);
            for x in x0..(x0 + BLOCK).min(nx) {
                for y in y0..(y0 + BLOCK).min(ny) {
                    row((x * ny + y) * nz + z0, len);
                }
            }
        });
    }

    /// `f(coords)` for every block of the region (its lattice coordinates), on many threads
    /// when `parallel`.
    fn for_each_region_block(&self, parallel: bool, f: impl Fn([usize; 3]) + Sync) {
        let one = |&b: &u32| f(self.block_coords(b as usize));
        if parallel {
            self.region
                .par_iter()
                .with_min_len(REGION_BLOCKS_PER_TASK)
                .for_each(one);
        } else {
            self.region.iter().for_each(one);
        }
    }

    /// [`Bins::for_each_region_row`] node by node: `node(i)` for every node of the region.
    pub fn for_each_region_node(&self, parallel: bool, node: impl Fn(usize) + Sync) {
        self.for_each_region_row(parallel, |start, len| (start..start + len).for_each(&node));
    }

    /// How many nodes the region holds.
    pub fn region_nodes(&self) -> usize {
        let count = std::sync::atomic::AtomicUsize::new(0);
        self.for_each_region_row(false, |_, len| {
            count.fetch_add(len, std::sync::atomic::Ordering::Relaxed);
        });
        count.into_inner()
    }

    /// Lattice coordinates of block `b` (a flat index, x slowest).
    fn block_coords(&self, b: usize) -> [usize; 3] {
        let [_, dy, dz] = self.dims;
        [b / (dy * dz), (b / dz) % dy, b % dz]
    }

    /// A scatter into `out` (its `channels` grid arrays, one value a node): `f(tile, p)`
    /// adds particle `p` into its block's `tile` (zeros to start with; see [`Tile`]), a
    /// block's particles in ascending order, every non-empty block in parallel when
    /// `parallel`; then every node of the region in `out` is overwritten with the sum of the
    /// tiles that reach it, in ascending block order (zero where none does; nodes outside
    /// the region are left as they were). `tiles` is scratch (kept by the caller to spare allocating it
    /// each time). The same bits whatever the thread count, and with `parallel` off.
    pub fn scatter(
        &self,
        parallel: bool,
        tiles: &mut Vec<f64>,
        out: &mut [&mut [f64]],
        f: impl Fn(&mut Tile, usize) + Sync,
    ) {
        let channels = out.len();
        let per_tile = channels * CHANNEL;
        // Grown when short, and zeroed tile by tile in the tasks (a serial fill of a large
        // body's tiles would cost a tenth of a parallel scatter).
        let need = self.blocks.len() * per_tile;
        if tiles.len() < need {
            tiles.resize(need, 0.0);
        }
        let tiles = &mut tiles[..need];
        let one = |(data, block): (&mut [f64], &Block)| {
            data.fill(0.0);
            let c = block.coords.map(|c| c as usize * BLOCK);
            let mut tile = Tile {
                data,
                offset: c[0] * Tile::STRIDES[0] + c[1] * Tile::STRIDES[1] + c[2],
            };
            for &p in &self.order[block.start as usize..block.end as usize] {
                f(&mut tile, p as usize);
            }
        };
        if parallel {
            tiles
                .par_chunks_mut(per_tile)
                .zip(self.blocks.par_iter())
                .with_max_len(1)
                .for_each(one);
        } else {
            tiles.chunks_mut(per_tile).zip(&self.blocks).for_each(one);
        }
        self.sum_tiles(parallel, tiles, out);
    }

    /// Phase 2 of [`Bins::scatter`]: each node of the region in `out` from the tiles, in
    /// parallel over the region's blocks, which write disjoint nodes.
    fn sum_tiles(&self, parallel: bool, tiles: &[f64], out: &mut [&mut [f64]]) {
        let per_tile = out.len() * CHANNEL;
        let [nx, ny, nz] = self.nodes;
        for o in out.iter() {
            assert_eq!(o.len(), nx * ny * nz, "a scatter's grid array");
        }
        let shared: Vec<SharedMut<f64>> = out.iter_mut().map(|o| SharedMut::new(o)).collect();
        self.for_each_region_block(parallel, |block| {
            let reach = self.tiles_reaching(block);
            let [x0, y0, z0] = block.map(|c| c * BLOCK);
            let len = BLOCK.min(nz - z0);
            for x in x0..(x0 + BLOCK).min(nx) {
                for y in y0..(y0 + BLOCK).min(ny) {
                    let row = (x * ny + y) * nz + z0;
                    for (c, out) in shared.iter().enumerate() {
                        let mut sum = [0.0; BLOCK];
                        for &(s, o) in &reach {
                            let local = (x - o[0] * BLOCK) * Tile::STRIDES[0]
                                + (y - o[1] * BLOCK) * Tile::STRIDES[1]
                                + (z0 - o[2] * BLOCK);
                            let t = &tiles[s * per_tile + c * CHANNEL + local..][..BLOCK];
                            for r in 0..BLOCK {
                                sum[r] += t[r];
                            }
                        }
                        // SAFETY: a block's nodes belong to it alone.
                        let dst = unsafe { out.run(row, len) };
                        // A whole row of a block is one fixed-size store; a slice copy
                        // called memmove once a row (2% of a morph).
                        match <&mut [f64; BLOCK]>::try_from(&mut *dst) {
                            Ok(whole) => *whole = sum,
                            Err(_) => dst.copy_from_slice(&sum[..len]),
                        }
                    }
                }
            }
        });
    }

    /// The tiles that reach block `b`'s nodes: at most 8 (its own and its lower neighbours'),
    /// in ascending block order, each with its block coordinates.
    fn tiles_reaching(&self, [bx, by, bz]: [usize; 3]) -> Vec<(usize, [usize; 3])> {
        let dims = self.dims;
        let mut reach = Vec::with_capacity(8);
        for ox in bx.saturating_sub(1)..=bx {
            for oy in by.saturating_sub(1)..=by {
                for oz in bz.saturating_sub(1)..=bz {
                    let s = self.slot[(ox * dims[1] + oy) * dims[2] + oz];
                    if s != NO_BLOCK {
                        reach.push((s as usize, [ox, oy, oz]));
                    }
                }
            }
        }
        reach
    }
}

/// Region blocks a parallel task takes: a block is 64 nodes, too little work alone.
const REGION_BLOCKS_PER_TASK: usize = 8;

/// The region of `blocks` on a lattice of `dims` blocks: each non-empty block and its upper
/// neighbours along every axis, as flat lattice indices in ascending order.
fn region_of(blocks: &[Block], dims: [usize; 3]) -> Vec<u32> {
    let mut inside = vec![false; dims[0] * dims[1] * dims[2]];
    for b in blocks {
        let [bx, by, bz] = b.coords.map(|c| c as usize);
        for x in bx..(bx + 2).min(dims[0]) {
            for y in by..(by + 2).min(dims[1]) {
                for z in bz..(bz + 2).min(dims[2]) {
                    inside[(x * dims[1] + y) * dims[2] + z] = true;
                }
            }
        }
    }
    (0..inside.len() as u32)
        .filter(|&b| inside[b as usize])
        .collect()
}

/// A mutable slice shared across threads that write disjoint elements (distinct particles,
/// disjoint nodes): each use states why its elements are its own.
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mpm::kernel::Stencil;

    /// A grid with an uneven number of cells along each axis, off the origin.
    fn test_grid() -> GridSpec {
        GridSpec {
            origin: [-1.0, -0.5, -2.0],
            dx: 0.25,
            cells: [13, 9, 17],
        }
    }

    /// A particle goes to the block of its stencil's base node, and is refused exactly
    /// when its stencil leaves the grid or it is not finite: positions on and next to every
    /// bound, for both kernels.
    #[test]
    fn blocks_follow_the_stencil_base_and_its_bounds() {
        let spec = test_grid();
        let (origin, dx, nodes) = (spec.origin_vec(), spec.dx, spec.nodes());
        let bdims = nodes.map(|n| n.div_ceil(BLOCK));
        // Along x, cell coordinates on, just below and just above every half cell.
        let mut xs = Vec::new();
        for i in -4..=2 * nodes[0] as i64 + 4 {
            let g = 0.5 * i as f64;
            for v in [g, g.next_down(), g.next_up()] {
                xs.push(Vector3::new(origin[0] + v * dx, 0.6, 0.1));
            }
        }
        xs.push(Vector3::new(f64::NAN, 0.6, 0.1));
        xs.push(Vector3::new(f64::INFINITY, 0.6, 0.1));
        fn check<const N: usize>(
            spec: &GridSpec,
            x: &Vector3<f64>,
            origin: &Vector3<f64>,
            dx: f64,
            nodes: [usize; 3],
            bdims: [usize; 3],
        ) -> usize
        where
            Stencil<N>: crate::mpm::kernel::Cached,
        {
            let inside = x.iter().all(|c| c.is_finite()) && {
                let s = Stencil::<N>::new(x, origin, dx);
                (0..3).all(|a| s.base[a] >= 0 && s.base[a] as usize + N <= nodes[a])
            };
            match Bins::build(spec, std::slice::from_ref(x), N, 0) {
                Ok(bins) => {
                    assert!(inside, "{x:?} taken with support {N}");
                    let s = Stencil::<N>::new(x, origin, dx);
                    let c = bins.blocks[0].coords;
                    let expected = s.base.map(|b| (b / BLOCK as i64) as u32);
                    assert_eq!(c, expected, "{x:?}, support {N}");
                    assert!((0..3).all(|a| (c[a] as usize) < bdims[a]));
                    1
                }
                Err(_) => {
                    assert!(!inside, "{x:?} refused with support {N}");
                    0
                }
            }
        }
        let mut taken = [0, 0];
        for x in &xs {
            taken[0] += check::<3>(&spec, x, &origin, dx, nodes, bdims);
            taken[1] += check::<4>(&spec, x, &origin, dx, nodes, bdims);
        }
        // Both kinds of answer were seen.
        assert!(
            taken.iter().all(|&t| t > 10 && t < xs.len() - 10),
            "{taken:?}"
        );
    }

    /// Particles scattered by blocks into tiles: every node holds the sum of its particles'
    /// weighted masses (as a plain loop over the particles gives, up to rounding), the same
    /// bits on one thread, on several and sequentially, and zeros where no particle reaches.
    #[test]
    fn scatter_sums_every_particle_whatever_the_threads() {
        let spec = test_grid();
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        // Away from the walls (a cubic stencil needs a cell and a half), unevenly dense.
        let (lo, hi) = (
            2.0 * spec.dx,
            [13.0, 9.0, 17.0].map(|c| (c - 2.0) * spec.dx),
        );
        let x: Vec<Vector3<f64>> = (0..3000)
            .map(|_| {
                let u = [0.4 * next(), next().powi(2), next()];
                Vector3::from_fn(|a, _| spec.origin[a] + lo + u[a] * (hi[a] - lo))
            })
            .collect();
        let m: Vec<f64> = (0..x.len()).map(|_| 0.5 + next()).collect();
        let bins = Bins::build(&spec, &x, 4, 0).unwrap();
        assert!(bins.blocks.len() > 8);
        let (origin, dx) = (spec.origin_vec(), spec.dx);
        let scatter = |parallel: bool| {
            let mut out = vec![f64::NAN; spec.node_count()];
            let mut twice = vec![f64::NAN; spec.node_count()];
            bins.scatter(
                parallel,
                &mut Vec::new(),
                &mut [&mut out, &mut twice],
                |t, p| {
                    let s = Stencil::<4>::new(&x[p], &origin, dx);
                    let (t0, ts) = (t.base(&s), Tile::STRIDES);
                    s.for_each_node(&ts, |_, w, _, (a, b, c)| {
                        let i = t0 + a * ts[0] + b * ts[1] + c;
                        t.channel(0)[i] += w * m[p];
                        t.channel(1)[i] += 2.0 * w * m[p];
                    });
                },
            );
            (out, twice)
        };
        let (par, twice) = scatter(true);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| scatter(true));
        let (seq, _) = scatter(false);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&par), bits(&seq));
        assert_eq!(bits(&par), bits(&one.0));
        let mut plain = vec![0.0; spec.node_count()];
        for (p, x) in x.iter().enumerate() {
            Stencil::<4>::new(x, &origin, dx)
                .for_each_node(&spec.strides(), |i, w, _, _| plain[i] += w * m[p]);
        }
        let total: f64 = m.iter().sum();
        // The region holds every node with mass; the scatter leaves the others as they were.
        let mut in_region = vec![false; spec.node_count()];
        let mark = SharedMut::new(&mut in_region);
        // SAFETY: region nodes are visited once each.
        bins.for_each_region_node(false, |i| unsafe { *mark.get(i) = true });
        let mut outside = 0;
        for (i, (&a, &b)) in par.iter().zip(&plain).enumerate() {
            if !in_region[i] {
                assert!(
                    a.is_nan() && b == 0.0,
                    "node {i} outside the region: {a}, {b}"
                );
                outside += 1;
                continue;
            }
            assert!((a - b).abs() <= 1e-12 * total, "node {i}: {a} against {b}");
            assert_eq!(twice[i], 2.0 * a, "node {i}");
            assert_eq!(a == 0.0, b == 0.0, "node {i}");
        }
        assert_eq!(bins.region_nodes(), spec.node_count() - outside);
        assert!(outside > 100, "{outside} nodes outside the region");
        let sum: f64 = par.iter().filter(|v| !v.is_nan()).sum();
        assert!((sum - total).abs() < 1e-9 * total);
    }
}
