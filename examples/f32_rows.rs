//! What f32 would buy the transfers (issue 33, "f32 where it pays"): the G2P gather of a
//! cubic stencil, written as the engine writes it on AVX rows (`crates/engine/src/lanes/row.rs`), once in
//! f64 (a row of 4 nodes is one 4-lane register) and once in f32 (two rows in one 8-lane
//! register), on the same random particles and grid. Both without fused multiply-adds, as
//! the engine. Prints nanoseconds a particle and the ratio, best of several rounds, one thread.
//!
//!     cargo run --release --example f32_rows [-- PARTICLES [ROUNDS]]
//!
//! It measures the arithmetic form alone: the engine's other stages, the bits and the
//! accuracy are docs/engine.md's ("f32, measured").

use std::time::Instant;

const CELLS: usize = 40;

/// One particle's cubic stencil: the base node and the weights along each axis, with the
/// offsets `x_i - x_p` in cells.
#[derive(Clone, Copy)]
struct Stencil {
    base: [usize; 3],
    w: [[f64; 4]; 3],
    d: [[f64; 4]; 3],
}

fn cubic(t: f64) -> f64 {
    let t = t.abs();
    if t < 1.0 {
        0.5 * t * t * t - t * t + 2.0 / 3.0
    } else if t < 2.0 {
        let u = 2.0 - t;
        u * u * u / 6.0
    } else {
        0.0
    }
}

fn stencils(n: usize) -> Vec<Stencil> {
    // A deterministic scramble (no dependency): particles spread over the inner cells.
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut out: Vec<Stencil> = (0..n)
        .map(|_| {
            let mut st = Stencil {
                base: [0; 3],
                w: [[0.0; 4]; 3],
                d: [[0.0; 4]; 3],
            };
            for a in 0..3 {
                let x = 4.0 + next() * (CELLS as f64 - 8.0);
                let b = x.floor() as usize - 1;
                st.base[a] = b;
                for k in 0..4 {
                    let d = (b + k) as f64 - x;
                    st.d[a][k] = d;
                    st.w[a][k] = cubic(d);
                }
            }
            st
        })
        .collect();
    // The engine gathers in particle order from particles that lie near one another.
    out.sort_by_key(|s| (s.base[0], s.base[1], s.base[2]));
    out
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{CELLS, Stencil};
    use std::arch::x86_64::*;

    #[inline(always)]
    unsafe fn hsum_pd(v: __m256d) -> f64 {
        let mut a = [0.0; 4];
        unsafe { _mm256_storeu_pd(a.as_mut_ptr(), v) };
        (a[0] + a[1]) + (a[2] + a[3])
    }

    /// Velocity and affine matrix of every particle, f64 rows, in the engine's order
    /// (`transfer::gather_affine_rows`: sums per lane through the rows, then the planes, the
    /// lane weights last); returns the sum of all outputs.
    #[target_feature(enable = "avx2")]
    pub unsafe fn gather_f64(st: &[Stencil], grid: &[Vec<f64>; 3]) -> f64 {
        let mut total = 0.0;
        for s in st {
            let z = [_mm256_setzero_pd(); 3];
            let (mut acc, mut acc0, mut acc1) = (z, z, z);
            for a in 0..4 {
                let (mut sa, mut sa1) = (z, z);
                for b in 0..4 {
                    let at = ((s.base[0] + a) * CELLS + s.base[1] + b) * CELLS + s.base[2];
                    let wb = _mm256_set1_pd(s.w[1][b]);
                    let wbd = _mm256_set1_pd(s.w[1][b] * s.d[1][b]);
                    for k in 0..3 {
                        let v = unsafe { _mm256_loadu_pd(grid[k].as_ptr().add(at)) };
                        sa[k] = _mm256_add_pd(sa[k], _mm256_mul_pd(wb, v));
                        sa1[k] = _mm256_add_pd(sa1[k], _mm256_mul_pd(wbd, v));
                    }
                }
                let wa = _mm256_set1_pd(s.w[0][a]);
                let wad = _mm256_set1_pd(s.w[0][a] * s.d[0][a]);
                for k in 0..3 {
                    acc[k] = _mm256_add_pd(acc[k], _mm256_mul_pd(wa, sa[k]));
                    acc0[k] = _mm256_add_pd(acc0[k], _mm256_mul_pd(wad, sa[k]));
                    acc1[k] = _mm256_add_pd(acc1[k], _mm256_mul_pd(wa, sa1[k]));
                }
            }
            let wc = unsafe { _mm256_loadu_pd(s.w[2].as_ptr()) };
            let wcd = _mm256_mul_pd(wc, unsafe { _mm256_loadu_pd(s.d[2].as_ptr()) });
            for k in 0..3 {
                unsafe {
                    total += hsum_pd(_mm256_mul_pd(wc, acc[k]))
                        + hsum_pd(_mm256_mul_pd(wc, acc0[k]))
                        + hsum_pd(_mm256_mul_pd(wc, acc1[k]))
                        + hsum_pd(_mm256_mul_pd(wcd, acc[k]));
                }
            }
        }
        total
    }

    /// The same in f32 on 8 lanes: rows `b` and `b + 2` of a plane side by side in one
    /// register (so a plane is two loads of paired rows a component), the two halves summed
    /// at the plane's end.
    #[target_feature(enable = "avx2")]
    pub unsafe fn gather_f32(st: &[Stencil32], grid: &[Vec<f32>; 3]) -> f64 {
        let mut total = 0.0f64;
        for s in st {
            let z = [_mm_setzero_ps(); 3];
            let (mut acc, mut acc0, mut acc1) = (z, z, z);
            for a in 0..4 {
                let z8 = [_mm256_setzero_ps(); 3];
                let (mut sa, mut sa1) = (z8, z8);
                for b in 0..2 {
                    let at = ((s.base[0] + a) * CELLS + s.base[1] + b) * CELLS + s.base[2];
                    let (w0, w1) = (s.w[1][b], s.w[1][b + 2]);
                    let wb = _mm256_set_m128(_mm_set1_ps(w1), _mm_set1_ps(w0));
                    let (d0, d1) = (w0 * s.d[1][b], w1 * s.d[1][b + 2]);
                    let wbd = _mm256_set_m128(_mm_set1_ps(d1), _mm_set1_ps(d0));
                    for k in 0..3 {
                        let p = grid[k].as_ptr();
                        let v = unsafe { _mm256_loadu2_m128(p.add(at + 2 * CELLS), p.add(at)) };
                        sa[k] = _mm256_add_ps(sa[k], _mm256_mul_ps(wb, v));
                        sa1[k] = _mm256_add_ps(sa1[k], _mm256_mul_ps(wbd, v));
                    }
                }
                let wa = _mm_set1_ps(s.w[0][a]);
                let wad = _mm_set1_ps(s.w[0][a] * s.d[0][a]);
                for k in 0..3 {
                    let half = |v: __m256| {
                        _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1))
                    };
                    let (s4, s41) = (half(sa[k]), half(sa1[k]));
                    acc[k] = _mm_add_ps(acc[k], _mm_mul_ps(wa, s4));
                    acc0[k] = _mm_add_ps(acc0[k], _mm_mul_ps(wad, s4));
                    acc1[k] = _mm_add_ps(acc1[k], _mm_mul_ps(wa, s41));
                }
            }
            let wc = unsafe { _mm_loadu_ps(s.w[2].as_ptr()) };
            let wcd = _mm_mul_ps(wc, unsafe { _mm_loadu_ps(s.d[2].as_ptr()) });
            let hsum = |v: __m128| {
                let mut x = [0.0f32; 4];
                unsafe { _mm_storeu_ps(x.as_mut_ptr(), v) };
                (x[0] + x[1]) + (x[2] + x[3])
            };
            for k in 0..3 {
                total += (hsum(_mm_mul_ps(wc, acc[k]))
                    + hsum(_mm_mul_ps(wc, acc0[k]))
                    + hsum(_mm_mul_ps(wc, acc1[k]))
                    + hsum(_mm_mul_ps(wcd, acc[k]))) as f64;
            }
        }
        total
    }

    /// [`Stencil`] in f32.
    #[derive(Clone, Copy)]
    pub struct Stencil32 {
        pub base: [usize; 3],
        pub w: [[f32; 4]; 3],
        pub d: [[f32; 4]; 3],
    }
}

#[cfg(target_arch = "x86_64")]
fn main() {
    use avx::Stencil32;
    let mut args = std::env::args().skip(1);
    let n: usize = args
        .next()
        .map_or(17_256, |a| a.parse().expect("PARTICLES"));
    let rounds: usize = args.next().map_or(20, |a| a.parse().expect("ROUNDS"));
    if !is_x86_feature_detected!("avx2") {
        eprintln!("f32_rows: this CPU has no AVX2");
        std::process::exit(1);
    }
    let st = stencils(n);
    let st32: Vec<Stencil32> = st
        .iter()
        .map(|s| Stencil32 {
            base: s.base,
            w: s.w.map(|r| r.map(|x| x as f32)),
            d: s.d.map(|r| r.map(|x| x as f32)),
        })
        .collect();
    let nodes = CELLS * CELLS * CELLS;
    let grid: [Vec<f64>; 3] = std::array::from_fn(|a| {
        (0..nodes)
            .map(|i| ((i * 7 + a * 13) % 101) as f64 / 50.0 - 1.0)
            .collect()
    });
    let grid32: [Vec<f32>; 3] =
        std::array::from_fn(|a| grid[a].iter().map(|&x| x as f32).collect());
    let (mut best64, mut best32) = (f64::INFINITY, f64::INFINITY);
    let (mut sum64, mut sum32) = (0.0, 0.0);
    for _ in 0..rounds {
        let t = Instant::now();
        sum64 = unsafe { avx::gather_f64(&st, &grid) };
        best64 = best64.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        sum32 = unsafe { avx::gather_f32(&st32, &grid32) };
        best32 = best32.min(t.elapsed().as_secs_f64());
    }
    println!(
        "{n} particles, cubic gather (velocity and affine), best of {rounds}: f64 {:.1} ns a particle, f32 {:.1} ns, f64/f32 {:.2}x (outputs summed: {sum64:.6} / {sum32:.6}, relative difference {:.1e})",
        best64 * 1e9 / n as f64,
        best32 * 1e9 / n as f64,
        best64 / best32,
        ((sum64 - sum32) / sum64).abs()
    );
}

#[cfg(not(target_arch = "x86_64"))]
fn main() {
    eprintln!("f32_rows: x86-64 only");
}
