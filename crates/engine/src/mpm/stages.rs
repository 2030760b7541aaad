//! The particle stages both integrators run, written once: the symplectic-Euler step
//! (`step.rs`) and the ODE form's right-hand side (`crate::ode::rhs`) each call them in the
//! same order (stencils, stress, P2G; later the reverse of the stress), and differ only in
//! what a particle scatters and in the grid update between the transfers (a discrete step
//! against rates). Each forward stage stands beside its reverse.
//!
//! Both integrators follow one parallel policy, [`Parallel`]: a pass over a body of at
//! least [`PARALLEL_MIN`] particles splits as finely as rayon likes; a smaller one runs as
//! one task (many small runs go in parallel instead: the rope's controllers, where a
//! fork-join would cost more than the work). Every stage gives the same bits either way.

use super::grid::Bins;
use super::kernel::{Cached, Stencil, StencilCache};
use super::stress::StressInputs;
use super::transfer::{self, Affine, AxisNodes, Node};
use crate::lanes::SimdLevel;
use crate::material::ConstitutiveModel;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Particles a batch holds: the material's vector lanes take a batch's stresses together.
pub const CHUNK: usize = 64;

/// Below this many particles a pass runs as one task (see the module's note).
pub const PARALLEL_MIN: usize = 2048;

/// Whether the passes over one body run on many threads (see the module's note).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Parallel {
    pub on: bool,
}

impl Parallel {
    /// The policy for a body of `particles` particles.
    pub fn for_particles(particles: usize) -> Parallel {
        Parallel {
            on: particles >= PARALLEL_MIN,
        }
    }

    /// The fewest items a parallel task takes: 1, or all of them when off.
    pub fn min_len(self) -> usize {
        if self.on { 1 } else { usize::MAX }
    }

    /// [`Parallel::min_len`] in batches of [`CHUNK`] particles.
    pub fn min_batches(self) -> usize {
        if self.on { 1 } else { usize::MAX }
    }
}

/// Every particle's stencil at positions `x`, built four at a time on vector lanes (the bits
/// of [`Stencil::new`]) into `cache`, for the transfers of one pass to share.
pub fn stencils<'c, const N: usize>(
    simd: SimdLevel,
    x: &[Vector3<f64>],
    origin: &Vector3<f64>,
    dx: f64,
    par: Parallel,
    cache: &'c mut StencilCache,
) -> &'c [Stencil<N>]
where
    Stencil<N>: Cached,
{
    let out = cache.sized::<N>(x.len());
    out.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK))
        .with_min_len(par.min_batches())
        .for_each(|(s, x)| Stencil::fill(simd, x, origin, dx, s));
    out
}

/// The stress stage: each particle's affine term `A_p = m C_p + k P(Fe_p) Fe_p^T` from its
/// elastic gradient `fe` (and `c`, zero where `None`), with `m`, `k` from `inputs(p)`.
/// Batches of [`CHUNK`] particles go to the material together (fixed-corotated runs their
/// SVDs on vector lanes; the same bits as one at a time). With a non-empty `kept`
/// (`kept_per_particle` numbers a particle) it also keeps what spares [`stress_reverse`]
/// its costliest part.
#[allow(clippy::too_many_arguments)]
pub fn stress<'m>(
    material: &dyn ConstitutiveModel,
    simd: SimdLevel,
    fe: &[Matrix3<f64>],
    c: Option<&[Matrix3<f64>]>,
    inputs: impl Fn(usize) -> StressInputs<'m> + Sync,
    par: Parallel,
    affine: &mut [Matrix3<f64>],
    kept: &mut [f64],
) {
    let keep = kept.len() / fe.len().max(1);
    in_batches(
        affine,
        fe.par_chunks(CHUNK),
        kept,
        keep,
        par,
        |k, a, fe, kept| stress_batch(material, simd, k, fe, c, &inputs, a, kept),
    );
}

/// [`stress`] where each batch first writes its particles' elastic gradients into `fe`,
/// `fe[p] = elastic(p)` (the Euler step: `F` after the control), in the same pass.
#[allow(clippy::too_many_arguments)]
pub fn stress_of<'m>(
    material: &dyn ConstitutiveModel,
    simd: SimdLevel,
    elastic: impl Fn(usize) -> Matrix3<f64> + Sync,
    fe: &mut [Matrix3<f64>],
    c: Option<&[Matrix3<f64>]>,
    inputs: impl Fn(usize) -> StressInputs<'m> + Sync,
    par: Parallel,
    affine: &mut [Matrix3<f64>],
    kept: &mut [f64],
) {
    let keep = kept.len() / fe.len().max(1);
    in_batches(
        affine,
        fe.par_chunks_mut(CHUNK),
        kept,
        keep,
        par,
        |k, a, fe: &mut [Matrix3<f64>], kept| {
            for (i, fe) in fe.iter_mut().enumerate() {
                *fe = elastic(k * CHUNK + i);
            }
            stress_batch(material, simd, k, fe, c, &inputs, a, kept)
        },
    );
}

/// Runs `batch(k, affine, fe, kept)` on every batch `k` of [`CHUNK`] particles in parallel
/// (at least `min_len` particles a task): the batch's affine terms, its part of `fe`, and its
/// part of `kept` (`keep` numbers a particle; empty when 0).
fn in_batches<T: Send>(
    affine: &mut [Matrix3<f64>],
    fe: impl IndexedParallelIterator<Item = T>,
    kept: &mut [f64],
    keep: usize,
    par: Parallel,
    batch: impl Fn(usize, &mut [Matrix3<f64>], T, &mut [f64]) + Sync + Send,
) {
    let batches = affine
        .par_chunks_mut(CHUNK)
        .zip(fe)
        .with_min_len(par.min_batches());
    if keep > 0 {
        batches
            .zip(kept.par_chunks_mut(CHUNK * keep))
            .enumerate()
            .for_each(|(k, ((a, fe), kept))| batch(k, a, fe, kept));
    } else {
        batches
            .enumerate()
            .for_each(|(k, (a, fe))| batch(k, a, fe, &mut []));
    }
}

/// One batch of the stress stage: particles `k * CHUNK ..`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn stress_batch<'m>(
    material: &dyn ConstitutiveModel,
    simd: SimdLevel,
    k: usize,
    fe: &[Matrix3<f64>],
    c: Option<&[Matrix3<f64>]>,
    inputs: &impl Fn(usize) -> StressInputs<'m>,
    a: &mut [Matrix3<f64>],
    kept: &mut [f64],
) {
    if kept.is_empty() {
        material.stress_batch(simd, fe, a);
    } else {
        material.stress_batch_keeping(simd, fe, a, kept);
    }
    for (i, (a, fe)) in a.iter_mut().zip(fe).enumerate() {
        let p = k * CHUNK + i;
        let c = c.map_or_else(Matrix3::zeros, |c| c[p]);
        *a = inputs(p).affine_from_stress(&c, fe, a);
    }
}

/// Reverse of [`stress`] for one batch of particles `p0..p0 + fe.len()` (at most
/// [`CHUNK`]): from dL/dA (`grad_a`) it writes dL/dC and dL/dFe of each. The material takes
/// the batch's stress differentials together, from what the forward stage kept when `kept`
/// holds it (the same bits either way).
#[allow(clippy::too_many_arguments)]
pub fn stress_reverse<'m>(
    material: &dyn ConstitutiveModel,
    simd: SimdLevel,
    p0: usize,
    fe: &[Matrix3<f64>],
    kept: &[f64],
    inputs: impl Fn(usize) -> StressInputs<'m>,
    grad_a: &[Matrix3<f64>],
    mut out: impl FnMut(usize, Matrix3<f64>, Matrix3<f64>),
) {
    let len = fe.len();
    debug_assert!(len <= CHUNK && grad_a.len() == len);
    let mut grad_p = [Matrix3::zeros(); CHUNK];
    for (i, g) in grad_p[..len].iter_mut().enumerate() {
        *g = inputs(p0 + i).stress_adjoint(&fe[i], &grad_a[i]);
    }
    let mut stress = [Matrix3::zeros(); CHUNK];
    let mut d_stress = [Matrix3::zeros(); CHUNK];
    if kept.is_empty() {
        material.stress_and_differential_batch(
            simd,
            fe,
            &grad_p[..len],
            &mut stress[..len],
            &mut d_stress[..len],
        );
    } else {
        material.stress_and_differential_batch_kept(
            simd,
            fe,
            kept,
            &grad_p[..len],
            &mut stress[..len],
            &mut d_stress[..len],
        );
    }
    for i in 0..len {
        let (g_c, g_fe) =
            inputs(p0 + i).affine_momentum_reverse_with(&grad_a[i], &stress[i], &d_stress[i]);
        out(i, g_c, g_fe);
    }
}

/// P2G: each particle's mass and its `K` affine fields (`fields(p)`) scattered to the grid
/// nodes through its stencil, block by block into tiles and then summed (in parallel, or on
/// this thread in the very same order: identical sums in every node either way; see
/// [`Bins::scatter`]), into `nodes` (on the region of `bins`).
#[allow(clippy::too_many_arguments)]
pub fn p2g<const N: usize, const K: usize>(
    simd: SimdLevel,
    bins: &Bins,
    stencils: &[Stencil<N>],
    mass: &[f64],
    par: Parallel,
    fields: impl Fn(usize) -> [Affine; K] + Sync,
    axes: &mut AxisNodes<K>,
    nodes: &mut Vec<Node<K>>,
    node_count: usize,
) {
    axes.scatter(bins, par.on, node_count, |tile, p| {
        transfer::scatter(simd, &stencils[p], mass[p], &fields(p), tile);
    });
    axes.write_nodes(nodes, bins, par.on);
}
