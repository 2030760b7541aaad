//! The shape the schedule puts the body at between two keyframes, as nodal masses.
//!
//! A cross-fade of the two shapes' masses, `(1-w) m_a + w m_b`, is a double exposure, not a
//! shape: no body of the body's volume fits it, and the log mass loss against it is least
//! when the body mostly stays as it is until `w` is near 1/2. Morphs scored against it lagged
//! their easing curve by a segment and then caught up (issue 27, docs/morph.md).
//!
//! The in-between shape here blends the two shapes' signed distances instead, the classic
//! shape interpolation: its boundary sweeps from one shape's to the other's as `w` goes from
//! 0 to 1. Its level is shifted so that it holds the same mass as the cross-fade (the body's),
//! and what the smooth profile of a signed distance does not capture of each shape (the
//! kernel's exact boundary layer, small details) is carried over from the cross-fade, so `w = 0`
//! and `w = 1` give the two shapes' masses exactly and the blend is continuous in `w`.
//!
//! Distances are in node spacings, from an exact Euclidean distance transform of each shape's
//! inside (nodes at least half full), by the separable lower-envelope algorithm of
//! Felzenszwalb and Huttenlocher (a few dozen lines; no maintained crate does 3D f64 grids
//! without pulling in an image stack).

/// Masses between shape `a` and shape `b` (nodal masses on one grid of `nodes` nodes per
/// axis, x slowest), at weight `w` of `b`. `full`: the nodal mass of a node deep inside a body.
pub fn in_between(nodes: [usize; 3], a: &[f64], b: &[f64], w: f64, full: f64) -> Vec<f64> {
    assert_eq!(a.len(), nodes.iter().product::<usize>());
    assert_eq!(a.len(), b.len());
    let crossfade = || {
        a.iter()
            .zip(b)
            .map(|(x, y)| (1.0 - w) * x + w * y)
            .collect()
    };
    if w <= 0.0 {
        return a.to_vec();
    }
    if w >= 1.0 {
        return b.to_vec();
    }
    if !(full > 0.0 && full.is_finite()) {
        return crossfade();
    }
    let (Some(sa), Some(sb)) = (
        signed_distance(nodes, a, full),
        signed_distance(nodes, b, full),
    ) else {
        // A shape with no node half full (or no node outside it) has no boundary to sweep.
        return crossfade();
    };
    let blended: Vec<f64> = sa
        .iter()
        .zip(&sb)
        .map(|(x, y)| (1.0 - w) * x + w * y)
        .collect();
    // What the profiles of the two distances leave out of each shape, cross-faded.
    let residual: Vec<f64> = a
        .iter()
        .zip(b)
        .zip(sa.iter().zip(&sb))
        .map(|((ma, mb), (x, y))| {
            (1.0 - w) * (ma - full * profile(*x)) + w * (mb - full * profile(*y))
        })
        .collect();
    let masses = |c: f64| {
        blended
            .iter()
            .zip(&residual)
            .map(move |(s, r)| (full * profile(s - c) + r).max(0.0))
    };
    // The level `c` that holds the cross-fade's mass, by bisection (the mass grows with `c`
    // from none to every node full).
    let want: f64 = a.iter().zip(b).map(|(x, y)| (1.0 - w) * x + w * y).sum();
    let reach = nodes.iter().map(|&n| n as f64).sum::<f64>();
    let (mut lo, mut hi) = (-reach, reach);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if masses(mid).sum::<f64>() < want {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    masses(0.5 * (lo + hi)).collect()
}

/// Weights a [`ProgressTiming`] table samples between two keyframes (each one in-between:
/// two distance transforms and a bisection).
pub const TIMING_SAMPLES: usize = 16;

/// How far the in-between at each weight has come from shape `a` to shape `b`, as the
/// progress a viewer sees: the gain in IoU of its inside (nodes at least half full) with
/// `b`'s, 0 at `a` and 1 at `b`. Tabulated at `samples` weights, made non-decreasing.
pub struct ProgressTiming {
    /// `(w, progress)` pairs from `(0, 0)` to `(1, 1)`, progress non-decreasing.
    table: Vec<(f64, f64)>,
}

impl ProgressTiming {
    /// The table for shapes `a` and `b` (as [`in_between`] takes them); `None` when the
    /// in-between does not gain on `b` (the same shape, or one with no boundary).
    pub fn new(nodes: [usize; 3], a: &[f64], b: &[f64], full: f64, samples: usize) -> Option<Self> {
        let inside = |m: &[f64]| -> Vec<bool> { m.iter().map(|&x| x >= 0.5 * full).collect() };
        let target = inside(b);
        let iou = |m: &[f64]| {
            let (mut both, mut either) = (0usize, 0usize);
            for (i, t) in inside(m).iter().zip(&target) {
                both += (*i && *t) as usize;
                either += (*i || *t) as usize;
            }
            if either == 0 {
                1.0
            } else {
                both as f64 / either as f64
            }
        };
        let start = iou(a);
        let gain = 1.0 - start;
        if gain.is_nan() || gain <= 1e-3 {
            return None;
        }
        let mut table = vec![(0.0, 0.0)];
        let mut best: f64 = 0.0;
        for k in 1..samples {
            let w = k as f64 / samples as f64;
            let p = ((iou(&in_between(nodes, a, b, w, full)) - start) / gain).clamp(0.0, 1.0);
            best = best.max(p);
            table.push((w, best));
        }
        table.push((1.0, 1.0));
        Some(ProgressTiming { table })
    }

    /// The weight at which the in-between has come `progress` of the way (linear between
    /// the table's samples; where progress stands still, the first weight that reaches it).
    pub fn weight_for(&self, progress: f64) -> f64 {
        let p = progress.clamp(0.0, 1.0);
        let t = &self.table;
        let i = t.iter().position(|&(_, q)| q >= p).unwrap_or(t.len() - 1);
        if i == 0 {
            return 0.0;
        }
        let ((w0, p0), (w1, p1)) = (t[i - 1], t[i]);
        if p1 - p0 <= 0.0 {
            w1
        } else {
            w0 + (w1 - w0) * (p - p0) / (p1 - p0)
        }
    }

    /// The progress at weight `w` (linear between samples), for reports and tests.
    pub fn progress_at(&self, w: f64) -> f64 {
        let w = w.clamp(0.0, 1.0);
        let t = &self.table;
        let i = t
            .iter()
            .position(|&(x, _)| x >= w)
            .unwrap_or(t.len() - 1)
            .max(1);
        let ((w0, p0), (w1, p1)) = (t[i - 1], t[i]);
        p0 + (p1 - p0) * (w - w0) / (w1 - w0)
    }
}

/// The share of a node's full mass at signed distance `s` (node spacings, negative inside)
/// from a body's boundary: 1 deep inside, 1/2 on it, 0 beyond the kernel's reach (a smoothstep
/// over 3 spacings, the width of the masses' own boundary layer).
fn profile(s: f64) -> f64 {
    let u = ((s + 1.5) / 3.0).clamp(0.0, 1.0);
    1.0 - u * u * (3.0 - 2.0 * u)
}

/// Signed distance (node spacings) from each node to the boundary of the nodes at least half
/// `full`: negative inside. `None` when there is no node inside or none outside.
fn signed_distance(nodes: [usize; 3], mass: &[f64], full: f64) -> Option<Vec<f64>> {
    let inside: Vec<bool> = mass.iter().map(|&m| m >= 0.5 * full).collect();
    if !inside.iter().any(|&i| i) || inside.iter().all(|&i| i) {
        return None;
    }
    let to_inside = squared_distance_to(nodes, &inside);
    let outside: Vec<bool> = inside.iter().map(|i| !i).collect();
    let to_outside = squared_distance_to(nodes, &outside);
    // In the boundary layer a node's own fill says where the boundary is (to a fraction of a
    // spacing); farther away, the boundary lies half way between an inside node and its
    // nearest outside one.
    Some(
        mass.iter()
            .zip(&inside)
            .zip(to_inside.iter().zip(&to_outside))
            .map(|((&m, &i), (di, doo))| {
                let fill = m / full;
                if (BAND..=1.0 - BAND).contains(&fill) {
                    inverse_profile(fill)
                } else if i {
                    0.5 - doo.sqrt()
                } else {
                    di.sqrt() - 0.5
                }
            })
            .collect(),
    )
}

/// Fills in `[BAND, 1 - BAND]` are read as distances through the profile.
const BAND: f64 = 0.05;

/// The signed distance at which [`profile`] is `fill` (in `(0, 1)`).
fn inverse_profile(fill: f64) -> f64 {
    // The smoothstep `3u^2 - 2u^3 = y` solved for u in [0, 1].
    let y = 1.0 - fill;
    let u = 0.5 - ((1.0 - 2.0 * y).asin() / 3.0).sin();
    3.0 * u - 1.5
}

/// Squared Euclidean distance (node spacings) from each node to the nearest node where
/// `mask` holds (`f64::INFINITY` when none does), one axis after another.
fn squared_distance_to(nodes: [usize; 3], mask: &[bool]) -> Vec<f64> {
    let mut d: Vec<f64> = mask
        .iter()
        .map(|&m| if m { 0.0 } else { f64::INFINITY })
        .collect();
    let strides = [nodes[1] * nodes[2], nodes[2], 1];
    let longest = nodes.iter().copied().max().unwrap_or(0);
    let mut line = vec![0.0; longest];
    let mut out = vec![0.0; longest];
    let mut scratch = Envelope::with_capacity(longest);
    for axis in 0..3 {
        let n = nodes[axis];
        let stride = strides[axis];
        let others: Vec<usize> = (0..3).filter(|&a| a != axis).collect();
        for i in 0..nodes[others[0]] {
            for j in 0..nodes[others[1]] {
                let start = i * strides[others[0]] + j * strides[others[1]];
                for (t, v) in line[..n].iter_mut().enumerate() {
                    *v = d[start + t * stride];
                }
                scratch.transform(&line[..n], &mut out[..n]);
                for (t, v) in out[..n].iter().enumerate() {
                    d[start + t * stride] = *v;
                }
            }
        }
    }
    d
}

/// The lower envelope of the parabolas `(q - p)^2 + f(p)`: the 1D squared distance transform.
struct Envelope {
    /// Apexes of the parabolas on the envelope.
    apex: Vec<usize>,
    /// Where each of them starts to be the lowest.
    from: Vec<f64>,
}

impl Envelope {
    fn with_capacity(n: usize) -> Self {
        Envelope {
            apex: Vec::with_capacity(n),
            from: Vec::with_capacity(n + 1),
        }
    }

    /// `out[q] = min_p (q - p)^2 + f[p]`.
    fn transform(&mut self, f: &[f64], out: &mut [f64]) {
        self.apex.clear();
        self.from.clear();
        let finite: Vec<usize> = (0..f.len()).filter(|&p| f[p].is_finite()).collect();
        if finite.is_empty() {
            out.fill(f64::INFINITY);
            return;
        }
        // Where the parabolas of apexes p and q (p < q) cross.
        let cross = |p: usize, q: usize| {
            ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64)
        };
        for &q in &finite {
            while let Some(&p) = self.apex.last() {
                let s = cross(p, q);
                if s <= *self.from.last().expect("one start per apex") {
                    self.apex.pop();
                    self.from.pop();
                } else {
                    break;
                }
            }
            let start = match self.apex.last() {
                Some(&p) => cross(p, q),
                None => f64::NEG_INFINITY,
            };
            self.apex.push(q);
            self.from.push(start);
        }
        let mut k = 0;
        for (q, o) in out.iter_mut().enumerate() {
            while k + 1 < self.apex.len() && self.from[k + 1] < q as f64 {
                k += 1;
            }
            let p = self.apex[k];
            let dq = q as f64 - p as f64;
            *o = dq * dq + f[p];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Nodal masses of a ball of radius `r` (node spacings) centred at `c`: the profile of
    /// its exact signed distance.
    fn ball(nodes: [usize; 3], c: [f64; 3], r: f64, full: f64) -> Vec<f64> {
        let mut m = Vec::new();
        for i in 0..nodes[0] {
            for j in 0..nodes[1] {
                for k in 0..nodes[2] {
                    let d = ((i as f64 - c[0]).powi(2)
                        + (j as f64 - c[1]).powi(2)
                        + (k as f64 - c[2]).powi(2))
                    .sqrt();
                    m.push(full * profile(d - r));
                }
            }
        }
        m
    }

    #[test]
    fn the_profile_inverts() {
        for fill in [0.05, 0.2, 0.5, 0.7, 0.95] {
            assert!(
                (profile(inverse_profile(fill)) - fill).abs() < 1e-12,
                "{fill}"
            );
        }
        assert_eq!(inverse_profile(0.5), 0.0);
    }

    #[test]
    fn the_distance_transform_is_exact() {
        let nodes = [7, 5, 6];
        let n: usize = nodes.iter().product();
        let mask: Vec<bool> = (0..n).map(|i| i % 17 == 3 || i == 40).collect();
        let d = squared_distance_to(nodes, &mask);
        let at = |i: usize| [i / 30, (i / 6) % 5, i % 6];
        for (q, got) in d.iter().enumerate() {
            let brute = (0..n)
                .filter(|&p| mask[p])
                .map(|p| {
                    let (a, b) = (at(p), at(q));
                    (0..3)
                        .map(|k| (a[k] as f64 - b[k] as f64).powi(2))
                        .sum::<f64>()
                })
                .fold(f64::INFINITY, f64::min);
            assert_eq!(*got, brute, "node {q}");
        }
        assert!(squared_distance_to(nodes, &vec![false; n])[0].is_infinite());
    }

    #[test]
    fn the_ends_are_the_keyframes_and_the_mass_is_the_crossfades() {
        let nodes = [24, 24, 24];
        let a = ball(nodes, [8.0, 11.5, 11.5], 5.0, 2.0);
        let b = ball(nodes, [15.0, 11.5, 11.5], 6.0, 2.0);
        assert_eq!(in_between(nodes, &a, &b, 0.0, 2.0), a);
        assert_eq!(in_between(nodes, &a, &b, 1.0, 2.0), b);
        for w in [0.1, 0.5, 0.9] {
            let m = in_between(nodes, &a, &b, w, 2.0);
            let want = (1.0 - w) * a.iter().sum::<f64>() + w * b.iter().sum::<f64>();
            let got = m.iter().sum::<f64>();
            assert!(
                (got / want - 1.0).abs() < 1e-3,
                "w {w}: {got} against {want}"
            );
            assert!(m.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
        // Nearly at an end, nearly that end.
        let near = in_between(nodes, &a, &b, 1e-6, 2.0);
        let gap = near
            .iter()
            .zip(&a)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(gap < 1e-3, "{gap}");
    }

    /// Between two balls, the blend is one ball that moves and grows with `w`, not two faint
    /// ones: its centre of mass and its fullest node say so.
    #[test]
    fn between_two_balls_is_a_ball_that_moves() {
        let nodes = [32, 20, 20];
        let full = 1.0;
        let a = ball(nodes, [9.0, 9.5, 9.5], 5.0, full);
        let b = ball(nodes, [22.0, 9.5, 9.5], 5.0, full);
        let centre_x = |m: &[f64]| {
            let total: f64 = m.iter().sum();
            m.iter()
                .enumerate()
                .map(|(i, v)| (i / 400) as f64 * v)
                .sum::<f64>()
                / total
        };
        let mut last = centre_x(&a);
        for w in [0.25, 0.5, 0.75] {
            let m = in_between(nodes, &a, &b, w, full);
            let x = centre_x(&m);
            assert!(x > last, "w {w}: centre {x} after {last}");
            last = x;
            // A node on the line between the balls' centres at the blend's own centre is
            // mostly full (a cross-fade leaves it nearly empty).
            let mid = m[(x.round() as usize) * 400 + 9 * 20 + 9];
            assert!(mid > 0.8 * full, "w {w}: {mid}");
        }
        let fade: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
        assert!(fade[(15.5_f64.round() as usize) * 400 + 9 * 20 + 9] < 0.1 * full);
    }

    /// The IoU gain of `m`'s inside (nodes at least half full) with `b`'s, from `a`'s.
    fn progress(m: &[f64], a: &[f64], b: &[f64], full: f64) -> f64 {
        let iou = |m: &[f64]| {
            let (mut both, mut either) = (0.0, 0.0);
            for (x, y) in m.iter().zip(b) {
                let (i, t) = (*x >= 0.5 * full, *y >= 0.5 * full);
                both += (i && t) as u8 as f64;
                either += (i || t) as u8 as f64;
            }
            both / either
        };
        (iou(m) - iou(a)) / (1.0 - iou(a))
    }

    /// The distance blend's IoU with a ball that grows lags its weight (the gain comes late:
    /// the union shrinks as the inside grows); re-timed, the in-between has come as far as
    /// asked, and the table runs from (0, 0) to (1, 1) without stepping back.
    #[test]
    fn progress_timing_makes_the_in_between_come_as_far_as_asked() {
        let nodes = [28, 28, 28];
        let full = 1.0;
        let a = ball(nodes, [11.0, 13.5, 13.5], 5.0, full);
        let b = ball(nodes, [15.0, 13.5, 13.5], 9.0, full);
        let t = ProgressTiming::new(nodes, &a, &b, full, 16).expect("the shapes differ");
        assert_eq!(t.progress_at(0.0), 0.0);
        assert_eq!(t.progress_at(1.0), 1.0);
        let mut last = 0.0;
        for k in 0..=20 {
            let p = t.progress_at(k as f64 / 20.0);
            assert!(p >= last, "step back at {k}: {p} < {last}");
            last = p;
        }
        // The plain blend lags: halfway by weight is well short of halfway by progress.
        let half = progress(&in_between(nodes, &a, &b, 0.5, full), &a, &b, full);
        assert!(half < 0.48, "{half}");
        for want in [0.25, 0.5, 0.75] {
            let w = t.weight_for(want);
            assert!(w > want, "re-timed ahead: {w} for {want}");
            let got = progress(&in_between(nodes, &a, &b, w, full), &a, &b, full);
            assert!(
                (got - want).abs() < 0.05,
                "asked {want}, came {got} at w {w}"
            );
        }
        assert_eq!(t.weight_for(0.0), 0.0);
        assert_eq!(t.weight_for(1.0), 1.0);
        // One shape twice: nothing to time.
        assert!(ProgressTiming::new(nodes, &a, &a, full, 16).is_none());
    }
}
