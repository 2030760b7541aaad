//! The deformation of the material around a particle, fitted to its rest neighbours: the
//! least-squares `F` with `x_j - x_i = F (X_j - X_i)` over the neighbours `j` within a radius
//! at rest, and the fit's rms residual (large where the neighbours parted or mixed). It is the
//! total deformation since rest, which a particle's own `F` is not once the plastic control
//! has folded the flow into the rest shape. The sharp surface's planes follow it
//! (`features.rs`) and the judge's material cover is made from it (`morph/quality.rs`).

use super::point_grid::PointGrid;
use nalgebra::{Matrix3, Vector3};

/// Rest neighbours within this many particle spacings fit a particle's deformation (about 14
/// of them in a full neighbourhood: enough to span the space at a surface too, few enough to
/// see the deformation at a particle's own scale).
pub const FIT_SPACINGS: f64 = 1.5;

/// A particle's rest neighbours and their rest offsets' inverse Gram matrix, made once.
#[derive(Clone, Debug)]
pub struct RestNeighbourhood {
    neighbours: Vec<u32>,
    gram_inverse: Matrix3<f64>,
}

impl RestNeighbourhood {
    /// Particle `i`'s neighbours within `radius` at rest (`grid` over `rest`, its cells at
    /// least `radius` wide); `None` where they are fewer than four or do not span the space.
    pub fn new(
        rest: &[Vector3<f64>],
        grid: &PointGrid,
        i: usize,
        radius: f64,
    ) -> Option<RestNeighbourhood> {
        let mut neighbours = Vec::new();
        let mut gram = Matrix3::zeros();
        grid.for_each_within(&rest[i], radius, |j| {
            if j != i {
                let d = rest[j] - rest[i];
                neighbours.push(j as u32);
                gram += d * d.transpose();
            }
        });
        let gram_inverse = gram.try_inverse().filter(|_| neighbours.len() >= 4)?;
        Some(RestNeighbourhood {
            neighbours,
            gram_inverse,
        })
    }

    /// The fitted deformation of particle `i` from `rest` to `x` and the fit's rms residual
    /// (in the positions' units).
    pub fn fit(&self, rest: &[Vector3<f64>], x: &[Vector3<f64>], i: usize) -> (Matrix3<f64>, f64) {
        self.fit_offsets(rest, i, |j| x[j] - x[i])
    }

    /// The fitted displacement gradient `F - I` of particle `i` from `rest` to `x`, and the
    /// same residual as [`Self::fit`]. Fitted to the displacements themselves, so a frame at
    /// rest gives exactly zero (the carried surface's first frame is the source bit for bit).
    pub fn fit_displacement(
        &self,
        rest: &[Vector3<f64>],
        x: &[Vector3<f64>],
        i: usize,
    ) -> (Matrix3<f64>, f64) {
        let moved = |j: usize| x[j] - rest[j];
        self.fit_offsets(rest, i, |j| moved(j) - moved(i))
    }

    /// The least-squares `M` with `offset(j) = M (X_j - X_i)` over the neighbours, and its rms
    /// residual.
    fn fit_offsets(
        &self,
        rest: &[Vector3<f64>],
        i: usize,
        offset: impl Fn(usize) -> Vector3<f64>,
    ) -> (Matrix3<f64>, f64) {
        let ri = rest[i];
        let mut moment = Matrix3::zeros();
        for &j in &self.neighbours {
            moment += offset(j as usize) * (rest[j as usize] - ri).transpose();
        }
        let m = moment * self.gram_inverse;
        let residual = self
            .neighbours
            .iter()
            .map(|&j| (offset(j as usize) - m * (rest[j as usize] - ri)).norm_squared())
            .sum::<f64>()
            / self.neighbours.len() as f64;
        (m, residual.sqrt())
    }
}
