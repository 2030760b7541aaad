//! Points bucketed in cubes, for radius and nearest-point queries (the quality judge, the
//! reach cost).

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

/// Particles bucketed in cubes of side `cell`, for radius and nearest-point queries.
pub struct PointGrid<'a> {
    points: &'a [Vector3<f64>],
    cell: f64,
    buckets: FxHashMap<[i64; 3], Vec<u32>>,
}

impl<'a> PointGrid<'a> {
    pub fn new(points: &'a [Vector3<f64>], cell: f64) -> Self {
        let mut buckets: FxHashMap<[i64; 3], Vec<u32>> = FxHashMap::default();
        for (i, p) in points.iter().enumerate() {
            buckets
                .entry(Self::key(p, cell))
                .or_default()
                .push(i as u32);
        }
        PointGrid {
            points,
            cell,
            buckets,
        }
    }

    fn key(p: &Vector3<f64>, cell: f64) -> [i64; 3] {
        [0, 1, 2].map(|a| (p[a] / cell).floor() as i64)
    }

    /// Distance from `q` to the nearest point, if one lies within `rings` cells.
    pub fn nearest(&self, q: &Vector3<f64>, rings: i64) -> Option<f64> {
        self.nearest_point(q, rings).map(|(_, d)| d)
    }

    /// The nearest point to `q` (the lowest index among equals) and its distance, if one
    /// lies within `rings` cells.
    pub fn nearest_point(&self, q: &Vector3<f64>, rings: i64) -> Option<(usize, f64)> {
        let c = Self::key(q, self.cell);
        let mut best: Option<(usize, f64)> = None;
        for r in 0..=rings {
            // Everything beyond ring r is at least (r - 1) cells away.
            if best.is_some_and(|(_, d)| d <= (r as f64 - 1.0).max(0.0) * self.cell) {
                break;
            }
            for dx in -r..=r {
                for dy in -r..=r {
                    for dz in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        let key = [c[0] + dx, c[1] + dy, c[2] + dz];
                        for &i in self.buckets.get(&key).into_iter().flatten() {
                            let (i, d) = (i as usize, (self.points[i as usize] - q).norm());
                            if best.is_none_or(|(j, e)| d < e || (d == e && i < j)) {
                                best = Some((i, d));
                            }
                        }
                    }
                }
            }
        }
        best
    }

    /// The indices of the points in the 27 cubes around `q`'s, cube by cube in a fixed order
    /// and in index order within a cube (sums over them come out the same bits every time).
    fn around<'g>(&'g self, q: &Vector3<f64>) -> impl Iterator<Item = usize> + 'g {
        let c = Self::key(q, self.cell);
        (-1..=1)
            .flat_map(|dx| (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| [dx, dy, dz])))
            .flat_map(move |[dx, dy, dz]| {
                self.buckets
                    .get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                    .into_iter()
                    .flatten()
                    .map(|&i| i as usize)
            })
    }

    /// Calls `visit` with the index of every point closer than `radius` (at most one cell)
    /// to `q`, in [`PointGrid::around`]'s order.
    pub fn for_each_within(&self, q: &Vector3<f64>, radius: f64, mut visit: impl FnMut(usize)) {
        for i in self.around(q) {
            if (self.points[i] - q).norm() < radius {
                visit(i);
            }
        }
    }

    /// Whether some point lies within `radius` (at most one cell) of `q`.
    pub fn any_within(&self, q: &Vector3<f64>, radius: f64) -> bool {
        self.any_within_except(q, radius, usize::MAX)
    }

    /// [`PointGrid::any_within`], not counting point `skip`.
    pub fn any_within_except(&self, q: &Vector3<f64>, radius: f64, skip: usize) -> bool {
        self.around(q)
            .any(|i| i != skip && (self.points[i] - q).norm() <= radius)
    }
}
