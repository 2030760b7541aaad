//! Controls that vary at the grid's scale, not the particles'.
//!
//! The morph's loss lives on the simulation grid, so it cannot see how particles are arranged
//! within a cell. Optimized per particle, each control entry takes Adam's full step whatever
//! its gradient, and neighbouring particles get unrelated controls: the body's order below
//! the grid is lost and its particles clump and leave gaps (docs/morph.md). With a
//! [`ControlBasis`] the optimizer moves one control per grid node instead, and each particle's
//! control is the quadratic B-spline interpolation of its nodes' at the particle's position
//! when the segment starts: `Fc_p = Fc0_p + sum_i w_ip theta_i`. The controls are then smooth
//! across the body by construction, and the gradient is `dL/dtheta_i = sum_p w_ip dL/dFc_p`.

use crate::engine::mpm::kernel::Stencil;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Where a segment's optimizer places its free control values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ControlResolution {
    /// One control per grid node, interpolated to the particles (default).
    #[default]
    Grid,
    /// One control per particle (the reference).
    Particle,
}

impl ControlResolution {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [ControlResolution; 2] = [ControlResolution::Grid, ControlResolution::Particle];
}

/// Nodes of a quadratic B-spline stencil.
const STENCIL: usize = 27;

/// The interpolation from control nodes to particles.
pub struct ControlBasis {
    /// Per particle: its stencil's (node, weight), nodes numbered in lattice order.
    entries: Vec<[(u32, f64); STENCIL]>,
    nodes: usize,
}

impl ControlBasis {
    /// The basis for particles at `x` on a lattice of spacing `dx` through `origin`: only the
    /// nodes some particle's stencil touches get a control.
    pub fn new(x: &[Vector3<f64>], origin: &Vector3<f64>, dx: f64) -> ControlBasis {
        let stencils: Vec<Stencil<3>> = x.iter().map(|p| Stencil::new(p, origin, dx)).collect();
        // Number the touched nodes in lattice order (deterministic, thread-count free).
        let mut index: BTreeMap<[i64; 3], u32> = BTreeMap::new();
        for s in &stencils {
            for_each_node(s, |key, _| {
                index.insert(key, 0);
            });
        }
        for (i, v) in index.values_mut().enumerate() {
            *v = i as u32;
        }
        let entries = stencils
            .iter()
            .map(|s| {
                let mut e = [(0u32, 0.0); STENCIL];
                let mut k = 0;
                for_each_node(s, |key, w| {
                    e[k] = (index[&key], w);
                    k += 1;
                });
                e
            })
            .collect();
        ControlBasis {
            entries,
            nodes: index.len(),
        }
    }

    /// Control nodes.
    pub fn nodes(&self) -> usize {
        self.nodes
    }

    /// `base_p + sum_i w_ip theta_i` for every particle.
    pub fn to_particles(&self, theta: &[Matrix3<f64>], base: &[Matrix3<f64>]) -> Vec<Matrix3<f64>> {
        assert_eq!(theta.len(), self.nodes);
        self.entries
            .iter()
            .zip(base)
            .map(|(e, b)| {
                e.iter()
                    .fold(*b, |acc, &(i, w)| acc + w * theta[i as usize])
            })
            .collect()
    }

    /// The reverse of [`ControlBasis::to_particles`]: `sum_p w_ip g_p` per node (summed in
    /// particle order, so the same for any thread count).
    pub fn to_nodes(&self, grad: &[Matrix3<f64>]) -> Vec<Matrix3<f64>> {
        let mut out = vec![Matrix3::zeros(); self.nodes];
        for (e, g) in self.entries.iter().zip(grad) {
            for &(i, w) in e {
                out[i as usize] += w * g;
            }
        }
        out
    }
}

/// `f(node key, weight)` over the stencil's 27 nodes.
fn for_each_node(s: &Stencil<3>, mut f: impl FnMut([i64; 3], f64)) {
    for a in 0..3 {
        for b in 0..3 {
            for c in 0..3 {
                let key = [
                    s.base[0] + a as i64,
                    s.base[1] + b as i64,
                    s.base[2] + c as i64,
                ];
                f(key, s.w[0][a] * s.w[1][b] * s.w[2][c]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_and_its_reverse_are_adjoint() {
        let x: Vec<Vector3<f64>> = (0..50)
            .map(|i| {
                let t = i as f64;
                Vector3::new((0.37 * t).sin() * 2.0, (0.23 * t).cos() * 1.5, 0.05 * t)
            })
            .collect();
        let basis = ControlBasis::new(&x, &Vector3::new(-4.0, -4.0, -4.0), 0.7);
        let theta: Vec<Matrix3<f64>> = (0..basis.nodes())
            .map(|i| Matrix3::from_fn(|r, c| ((i * 9 + r * 3 + c) as f64 * 0.61).sin()))
            .collect();
        let g: Vec<Matrix3<f64>> = (0..x.len())
            .map(|p| Matrix3::from_fn(|r, c| ((p * 9 + r * 3 + c) as f64 * 0.43).cos()))
            .collect();
        let zero = vec![Matrix3::zeros(); x.len()];
        // <B theta, g> = <theta, B^T g>.
        let lhs: f64 = basis
            .to_particles(&theta, &zero)
            .iter()
            .zip(&g)
            .map(|(a, b)| a.dot(b))
            .sum();
        let rhs: f64 = theta
            .iter()
            .zip(basis.to_nodes(&g))
            .map(|(a, b)| a.dot(&b))
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-10 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
        // A constant field interpolates to itself (the weights sum to one).
        let one = vec![Matrix3::identity(); basis.nodes()];
        for m in basis.to_particles(&one, &zero) {
            assert!((m - Matrix3::identity()).amax() < 1e-12);
        }
    }
}
