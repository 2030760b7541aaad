//! Generalized winding numbers (Jacobson et al. 2013) evaluated fast with a bounding-volume
//! hierarchy and a far-field dipole approximation (Barill et al. 2018).
//!
//! The winding number w(q) = (1/4pi) * sum of the signed solid angles of the triangles seen
//! from q. It is 1 inside and 0 outside a closed, outward mesh, and degrades gracefully on
//! open meshes (about 1/2 in front of a hole), which is why `w > 1/2` is the inside test of
//! choice for the meshes artists hand over. A cluster of triangles seen from farther than
//! `BETA` times its radius is replaced by its area-weighted normal (a dipole) at its
//! area-weighted centroid, plus the first-moment correction of the expansion; closer clusters
//! are opened, leaves summed exactly.

use super::mesh::TriMesh;
use nalgebra::{Matrix3, Vector3};

/// Opening criterion: a node is approximated when |q - centre| > BETA * radius.
const BETA: f64 = 2.0;
const LEAF_SIZE: usize = 8;

#[derive(Clone, Debug)]
struct Node {
    /// Area-weighted centroid of the node's triangles.
    centre: Vector3<f64>,
    /// Largest distance from `centre` to a vertex of the node's triangles.
    radius: f64,
    /// Sum of the triangles' area vectors (1/2 (b - a) x (c - a)).
    dipole: Vector3<f64>,
    /// First moment sum_t (c_t - centre) A_t^T of the area vectors about `centre`.
    moment: Matrix3<f64>,
    /// Second moments: `second[i] = sum_t n_ti * integral over t of e e^T dA`, e = x - centre.
    second: [Matrix3<f64>; 3],
    /// Leaf: range in `order`. Inner: `start` is the left child (right child follows the
    /// left subtree), `len == 0`.
    start: u32,
    len: u32,
    right: u32,
}

/// A mesh prepared for fast winding-number queries.
pub struct WindingNumber {
    nodes: Vec<Node>,
    /// Triangle corners in BVH leaf order.
    tris: Vec<[Vector3<f64>; 3]>,
}

impl WindingNumber {
    pub fn new(mesh: &TriMesh) -> Self {
        let tris: Vec<[Vector3<f64>; 3]> = mesh.triangles.iter().map(|t| mesh.corners(t)).collect();
        let centroids: Vec<Vector3<f64>> =
            tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF_SIZE + 1);
        build(&mut nodes, &tris, &centroids, &mut order, 0);
        let tris = order.iter().map(|&i| tris[i as usize]).collect();
        WindingNumber { nodes, tris }
    }

    /// The winding number at `q`.
    pub fn at(&self, q: &Vector3<f64>) -> f64 {
        let mut total = 0.0;
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            let d = node.centre - q;
            let dist2 = d.norm_squared();
            if dist2 > (BETA * node.radius).powi(2) {
                // Far field: the solid-angle kernel K(r) = r / |r|^3 expanded about the
                // centre, K(d + e) ~ K(d) + (I / |d|^3 - 3 d d^T / |d|^5) e.
                //   + 1/2 H_ijk e_j e_k, H_ijk = -3 (d_ij r_k + d_ik r_j + d_jk r_i) / |d|^5
                //   + 15 r_i r_j r_k / |d|^7 (the error then falls as (radius / |d|)^3).
                let inv2 = 1.0 / dist2;
                let inv3 = inv2 / dist2.sqrt();
                let m = &node.moment;
                let order1 = node.dipole.dot(&d) + m.trace() - 3.0 * d.dot(&(m * d)) * inv2;
                let c = &node.second;
                let mut diag_k = 0.0; // sum_jk C_jjk d_k
                let mut trace_i = 0.0; // sum_i d_i tr(C_i)
                let mut cubic = 0.0; // sum_ijk C_ijk d_i d_j d_k
                for i in 0..3 {
                    diag_k += c[i].row(i).dot(&d.transpose());
                    trace_i += d[i] * c[i].trace();
                    cubic += d[i] * d.dot(&(c[i] * d));
                }
                let order2 = 0.5 * (-3.0 * (2.0 * diag_k + trace_i) + 15.0 * cubic * inv2) * inv2;
                total += inv3 * (order1 + order2);
            } else if node.len > 0 {
                let (s, e) = (node.start as usize, (node.start + node.len) as usize);
                for t in &self.tris[s..e] {
                    total += solid_angle(t, q);
                }
            } else {
                stack[top] = node.start;
                stack[top + 1] = node.right;
                top += 2;
            }
        }
        total / (4.0 * std::f64::consts::PI)
    }
}

/// Signed solid angle of triangle `t` seen from `q` (Van Oosterom and Strackee 1983).
/// Positive when q is behind the triangle (the side its normal points away from).
pub fn solid_angle(t: &[Vector3<f64>; 3], q: &Vector3<f64>) -> f64 {
    let (a, b, c) = (t[0] - q, t[1] - q, t[2] - q);
    let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
    let det = a.dot(&b.cross(&c));
    let div = la * lb * lc + a.dot(&b) * lc + b.dot(&c) * la + c.dot(&a) * lb;
    2.0 * det.atan2(div)
}

/// Builds the subtree over `order` (triangle ids) and returns its node index. Splits at the
/// median centroid along the longest axis of the centroids' box.
fn build(
    nodes: &mut Vec<Node>,
    tris: &[[Vector3<f64>; 3]],
    centroids: &[Vector3<f64>],
    order: &mut [u32],
    offset: u32,
) -> u32 {
    let mut area_sum = 0.0;
    let mut weighted = Vector3::zeros();
    let mut dipole = Vector3::zeros();
    for &i in order.iter() {
        let t = &tris[i as usize];
        let n = 0.5 * (t[1] - t[0]).cross(&(t[2] - t[0]));
        let area = n.norm();
        area_sum += area;
        weighted += area * centroids[i as usize];
        dipole += n;
    }
    let centre = if area_sum > 0.0 {
        weighted / area_sum
    } else {
        order
            .iter()
            .map(|&i| centroids[i as usize])
            .sum::<Vector3<f64>>()
            / order.len() as f64
    };
    let mut moment = Matrix3::zeros();
    let mut second = [Matrix3::zeros(); 3];
    for &i in order.iter() {
        let t = &tris[i as usize];
        let n = 0.5 * (t[1] - t[0]).cross(&(t[2] - t[0]));
        let e = centroids[i as usize] - centre;
        moment += e * n.transpose();
        // Integral of e e^T over the triangle: area/12 (sum_v p_v p_v^T + 9 e e^T).
        let mut q = 9.0 * e * e.transpose();
        for v in t {
            let p = v - centre;
            q += p * p.transpose();
        }
        q /= 12.0;
        // n_hat_i * area * q = A_i * q.
        for (a, s) in second.iter_mut().enumerate() {
            *s += n[a] * q;
        }
    }
    let radius = order
        .iter()
        .flat_map(|&i| tris[i as usize].iter())
        .map(|p| (p - centre).norm())
        .fold(0.0, f64::max);
    let index = nodes.len() as u32;
    nodes.push(Node {
        centre,
        radius,
        dipole,
        moment,
        second,
        start: offset,
        len: order.len() as u32,
        right: 0,
    });
    if order.len() <= LEAF_SIZE {
        return index;
    }
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for &i in order.iter() {
        lo = lo.inf(&centroids[i as usize]);
        hi = hi.sup(&centroids[i as usize]);
    }
    let axis = (hi - lo).imax();
    let mid = order.len() / 2;
    order.select_nth_unstable_by(mid, |&a, &b| {
        centroids[a as usize][axis]
            .total_cmp(&centroids[b as usize][axis])
            .then(a.cmp(&b))
    });
    let (left, right) = order.split_at_mut(mid);
    let l = build(nodes, tris, centroids, left, offset);
    let r = build(nodes, tris, centroids, right, offset + mid as u32);
    let node = &mut nodes[index as usize];
    node.start = l;
    node.len = 0;
    node.right = r;
    index
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::assets;

    #[test]
    fn one_inside_zero_outside_a_closed_mesh() {
        let mesh = assets::uv_sphere(1.0, 24, 48, |_, _| 1.0);
        let w = WindingNumber::new(&mesh);
        for q in [Vector3::zeros(), Vector3::new(0.3, -0.2, 0.5)] {
            assert!((w.at(&q) - 1.0).abs() < 5e-3, "{}", w.at(&q));
        }
        for q in [Vector3::new(1.5, 0.0, 0.0), Vector3::new(3.0, 2.0, -1.0)] {
            assert!(w.at(&q).abs() < 5e-3, "{}", w.at(&q));
        }
    }

    #[test]
    fn far_field_matches_exact_sum() {
        let mesh = assets::torus(1.0, 0.4, 32, 16);
        let w = WindingNumber::new(&mesh);
        let mut rng = 12345u64;
        for _ in 0..200 {
            let mut r = || {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (rng >> 11) as f64 / (1u64 << 53) as f64 * 4.0 - 2.0
            };
            let q = Vector3::new(r(), r(), r());
            let exact: f64 = mesh
                .triangles
                .iter()
                .map(|t| solid_angle(&mesh.corners(t), &q))
                .sum::<f64>()
                / (4.0 * std::f64::consts::PI);
            assert!(
                (w.at(&q) - exact).abs() < 5e-3,
                "{q:?}: {} vs {exact}",
                w.at(&q)
            );
        }
    }
}
