//! Four lanes across a stencil row: the transfers' vector form.
//!
//! A cubic stencil's innermost axis has four nodes, side by side in memory (the grid's
//! fastest axis). The transfers take them as the four lanes of one value: one load brings a
//! row of a grid field, and every product and sum over the row's nodes is one vector
//! instruction. The quadratic kernel's three nodes leave the last lane zero.
//!
//! The compiler does not make four-lane code out of `[f64; 4]` loops on its own (it chose
//! two-lane SSE2 even with AVX enabled, measured in the disassembly), so [`Avx`] spells the
//! instructions out; [`Portable`] is the same arithmetic on plain arrays, for every other
//! CPU. Both add, multiply and sum in the same order, lane by lane ([`Rows::sum`] in one fixed
//! order), so they give the same bits.

use super::SimdLevel;

/// Four f64 lanes and the operations the transfers need. Implementations must round every
/// lane as the scalar operation does (no fused multiply-add).
pub trait Rows: Copy {
    type V: Copy;
    fn splat(self, x: f64) -> Self::V;
    fn zero(self) -> Self::V {
        self.splat(0.0)
    }
    /// The first four values of `src`.
    fn load(self, src: &[f64]) -> Self::V;
    fn array(self, a: [f64; 4]) -> Self::V;
    /// Writes the four lanes into the first four values of `dst`.
    fn store(self, dst: &mut [f64], v: Self::V);
    fn to_array(self, v: Self::V) -> [f64; 4];
    fn add(self, a: Self::V, b: Self::V) -> Self::V;
    fn sub(self, a: Self::V, b: Self::V) -> Self::V;
    fn mul(self, a: Self::V, b: Self::V) -> Self::V;
    fn div(self, a: Self::V, b: Self::V) -> Self::V;
    /// `-a` (the sign bit flipped, as the scalar `-a`).
    fn neg(self, a: Self::V) -> Self::V;
    /// The largest integer not above each lane, as [`floor`] (never `-0.0`).
    fn floor(self, a: Self::V) -> Self::V;
    /// `a + b c`, rounded twice (a product, then a sum).
    #[inline(always)]
    fn add_mul(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V {
        self.add(a, self.mul(b, c))
    }
    /// `sum(a b)`.
    #[inline(always)]
    fn dot(self, a: Self::V, b: Self::V) -> f64 {
        self.sum(self.mul(a, b))
    }
    /// The sum of the lanes, `(v0 + v1) + (v2 + v3)` on every backend.
    #[inline(always)]
    fn sum(self, v: Self::V) -> f64 {
        let a = self.to_array(v);
        (a[0] + a[1]) + (a[2] + a[3])
    }
    /// The first `n` lanes of `src` (n <= 4), the rest zero: a quadratic stencil's row.
    #[inline(always)]
    fn load_first(self, src: &[f64], n: usize) -> Self::V {
        if n == 4 {
            self.load(src)
        } else {
            let mut a = [0.0; 4];
            a[..n].copy_from_slice(&src[..n]);
            self.array(a)
        }
    }
    /// Adds the lanes of `v` into `dst` (its first `dst.len()` lanes, at most 4).
    #[inline(always)]
    fn add_into(self, dst: &mut [f64], v: Self::V) {
        if dst.len() == 4 {
            let sum = self.add(self.load(dst), v);
            self.store(dst, sum);
        } else {
            let a = self.to_array(v);
            for (d, x) in dst.iter_mut().zip(a) {
                *d += x;
            }
        }
    }
}

/// Plain arrays, for any CPU.
#[derive(Clone, Copy, Debug, Default)]
pub struct Portable;

impl Rows for Portable {
    type V = [f64; 4];
    #[inline(always)]
    fn splat(self, x: f64) -> [f64; 4] {
        [x; 4]
    }
    #[inline(always)]
    fn load(self, src: &[f64]) -> [f64; 4] {
        [src[0], src[1], src[2], src[3]]
    }
    #[inline(always)]
    fn array(self, a: [f64; 4]) -> [f64; 4] {
        a
    }
    #[inline(always)]
    fn store(self, dst: &mut [f64], v: [f64; 4]) {
        dst[..4].copy_from_slice(&v);
    }
    #[inline(always)]
    fn to_array(self, v: [f64; 4]) -> [f64; 4] {
        v
    }
    #[inline(always)]
    fn add(self, a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
        [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]
    }
    #[inline(always)]
    fn sub(self, a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3]]
    }
    #[inline(always)]
    fn mul(self, a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
        [a[0] * b[0], a[1] * b[1], a[2] * b[2], a[3] * b[3]]
    }
    #[inline(always)]
    fn div(self, a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
        [a[0] / b[0], a[1] / b[1], a[2] / b[2], a[3] / b[3]]
    }
    #[inline(always)]
    fn neg(self, a: [f64; 4]) -> [f64; 4] {
        [-a[0], -a[1], -a[2], -a[3]]
    }
    #[inline(always)]
    fn floor(self, a: [f64; 4]) -> [f64; 4] {
        [floor(a[0]), floor(a[1]), floor(a[2]), floor(a[3])]
    }
}

/// `v.floor()` without the library call: the default x86-64 target has no rounding
/// instruction, and `floor` was 2% of a step. Equal to `v.floor()` for every finite `v` (and
/// NaN for NaN), except that it gives `0.0` where `v.floor()` gives `-0.0`.
#[inline(always)]
pub fn floor(v: f64) -> f64 {
    if v.abs() < 4.0e15 {
        let t = v as i64 as f64;
        if t > v { t - 1.0 } else { t }
    } else {
        v.floor()
    }
}

/// AVX: one 256-bit register. Only [`dispatch_rows`] makes one, inside a function compiled
/// with AVX enabled, where these intrinsics inline.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Avx(());

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{Avx, Rows};
    use std::arch::x86_64::*;

    // SAFETY (every method): an `Avx` exists only where the CPU has AVX (`dispatch_rows`).
    impl Rows for Avx {
        type V = __m256d;
        #[inline(always)]
        fn splat(self, x: f64) -> __m256d {
            unsafe { _mm256_set1_pd(x) }
        }
        #[inline(always)]
        fn load(self, src: &[f64]) -> __m256d {
            let src = &src[..4];
            unsafe { _mm256_loadu_pd(src.as_ptr()) }
        }
        #[inline(always)]
        fn array(self, a: [f64; 4]) -> __m256d {
            unsafe { _mm256_loadu_pd(a.as_ptr()) }
        }
        #[inline(always)]
        fn store(self, dst: &mut [f64], v: __m256d) {
            let dst = &mut dst[..4];
            unsafe { _mm256_storeu_pd(dst.as_mut_ptr(), v) }
        }
        #[inline(always)]
        fn to_array(self, v: __m256d) -> [f64; 4] {
            let mut a = [0.0; 4];
            unsafe { _mm256_storeu_pd(a.as_mut_ptr(), v) };
            a
        }
        #[inline(always)]
        fn add(self, a: __m256d, b: __m256d) -> __m256d {
            unsafe { _mm256_add_pd(a, b) }
        }
        #[inline(always)]
        fn sub(self, a: __m256d, b: __m256d) -> __m256d {
            unsafe { _mm256_sub_pd(a, b) }
        }
        #[inline(always)]
        fn mul(self, a: __m256d, b: __m256d) -> __m256d {
            unsafe { _mm256_mul_pd(a, b) }
        }
        #[inline(always)]
        fn div(self, a: __m256d, b: __m256d) -> __m256d {
            unsafe { _mm256_div_pd(a, b) }
        }
        #[inline(always)]
        fn neg(self, a: __m256d) -> __m256d {
            unsafe { _mm256_xor_pd(a, _mm256_set1_pd(-0.0)) }
        }
        #[inline(always)]
        fn floor(self, a: __m256d) -> __m256d {
            // Adding +0 turns a -0 into +0, as the scalar floor gives.
            unsafe {
                let f = _mm256_round_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(a);
                _mm256_add_pd(f, _mm256_setzero_pd())
            }
        }
    }
}

/// A kernel over stencil rows, for [`dispatch_rows`].
pub trait RowKernel {
    type Output;
    fn run<R: Rows>(self, rows: R) -> Self::Output;
}

/// Runs `kernel` on four-lane registers where `level` (resolved on this CPU) has them, on
/// plain arrays otherwise. The same bits either way.
#[inline(always)]
pub fn dispatch_rows<K: RowKernel>(level: SimdLevel, kernel: K) -> K::Output {
    match level.resolved() {
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 | SimdLevel::Avx512 => pulp::Simd::vectorize(
            pulp::x86::V3::try_new().expect("resolved to an available level"),
            WithAvx(kernel),
        ),
        _ => kernel.run(Portable),
    }
}

/// `kernel.run(Avx)` inlined into pulp's function compiled with AVX2's features.
#[cfg(target_arch = "x86_64")]
struct WithAvx<K>(K);

#[cfg(target_arch = "x86_64")]
impl<K: RowKernel> pulp::WithSimd for WithAvx<K> {
    type Output = K::Output;
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> K::Output {
        self.0.run(Avx(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Mix<'a>(&'a [f64]);
    impl RowKernel for Mix<'_> {
        type Output = Vec<f64>;
        fn run<R: Rows>(self, r: R) -> Vec<f64> {
            self.0
                .windows(4)
                .map(|w| {
                    let v = r.load(w);
                    let t = r.add_mul(r.splat(0.1), v, r.sub(v, r.splat(1.0 / 3.0)));
                    r.sum(r.mul(t, r.load_first(w, 3)))
                })
                .collect()
        }
    }

    struct Rounding<'a>(&'a [f64]);
    impl RowKernel for Rounding<'_> {
        type Output = Vec<f64>;
        fn run<R: Rows>(self, r: R) -> Vec<f64> {
            let mut out = Vec::new();
            for w in self.0.chunks_exact(4) {
                let v = r.load(w);
                out.extend(r.to_array(r.floor(v)));
                out.extend(r.to_array(r.neg(r.div(v, r.splat(6.0)))));
            }
            out
        }
    }

    #[test]
    fn floor_division_and_negation_match_the_scalar_ones() {
        let x = [
            -0.0,
            0.0,
            -0.3,
            0.3,
            -1.0,
            2.0,
            -2.5,
            1e15,
            -3.99e15,
            5e15,
            -7e20,
            0.999_999_999,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            1e300,
            -1e-300,
        ];
        for level in SimdLevel::available_levels() {
            let out = dispatch_rows(level, Rounding(&x));
            for (c, w) in x.chunks_exact(4).enumerate() {
                for l in 0..4 {
                    let (fl, ng) = (out[8 * c + l], out[8 * c + 4 + l]);
                    assert_eq!(
                        fl.to_bits(),
                        floor(w[l]).to_bits(),
                        "{level:?} floor {}",
                        w[l]
                    );
                    assert_eq!(fl, w[l].floor(), "{level:?} floor {}", w[l]);
                    assert_eq!(ng.to_bits(), (-(w[l] / 6.0)).to_bits(), "{level:?}");
                }
            }
        }
    }

    #[test]
    fn every_level_gives_the_same_bits() {
        let x: Vec<f64> = (0..40).map(|i| (i as f64 * 0.731).sin() * 1e3).collect();
        let reference = dispatch_rows(SimdLevel::Baseline, Mix(&x));
        for level in SimdLevel::available_levels() {
            let out = dispatch_rows(level, Mix(&x));
            let bits = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&out), bits(&reference), "{level:?}");
        }
        let w = &x[5..9];
        let t: Vec<f64> = w.iter().map(|v| 0.1 + v * (v - 1.0 / 3.0)).collect();
        let scalar = (t[0] * w[0] + t[1] * w[1]) + (t[2] * w[2] + 0.0 * t[3]);
        assert_eq!(reference[5].to_bits(), scalar.to_bits());
    }
}
