//! Vector lanes: the same per-particle arithmetic on several particles at once.
//!
//! A kernel written over [`F64s<L>`] (L particles, one per lane) does, in every lane, exactly
//! the operations the one-particle code does, in the same order: additions, multiplications,
//! divisions and square roots are correctly rounded in IEEE arithmetic whatever the vector
//! width, a comparison and a select pick values without rounding, and Rust never fuses a
//! multiplication and an addition into an FMA on its own. So a lane kernel gives the bits of
//! the scalar code on every width, and results do not depend on the machine
//! (`tests/integration/determinism.rs` runs both integrators, forward and reverse, at each width this CPU
//! has and compares the bits).
//!
//! [`dispatch`] runs a kernel compiled for the widest instruction set the CPU has (or the one
//! a [`SimdLevel`] names): `pulp` detects the CPU and enables the target features for the
//! kernel's body, where the compiler turns each `[f64; L]` operation into vector
//! instructions. The width `L` a level runs is [`SimdLevel::lanes`]. Everything a kernel
//! calls in its hot loop must be inlined into it (`#[inline(always)]`, plain loops rather than
//! iterator chains): a function compiled apart runs without the kernel's instruction set.

mod row;
#[cfg(target_arch = "x86_64")]
pub use row::Avx;
pub use row::{Portable, RowKernel, Rows, dispatch_rows, floor};

use serde::{Deserialize, Serialize};
use std::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

/// An instruction set the lane kernels can be compiled for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SimdLevel {
    /// The widest this CPU has (decided once, at run time).
    #[default]
    Auto,
    /// The x86-64 baseline (SSE2: two f64 a register), or the target's own on other CPUs.
    Baseline,
    /// AVX2 (x86-64-v3: four f64 a register; its FMA is never used).
    Avx2,
    /// AVX-512 (x86-64-v4: eight f64 a register).
    Avx512,
}

impl SimdLevel {
    pub const ALL: [SimdLevel; 4] = [
        SimdLevel::Auto,
        SimdLevel::Baseline,
        SimdLevel::Avx2,
        SimdLevel::Avx512,
    ];

    pub fn name(self) -> &'static str {
        match self {
            SimdLevel::Auto => "auto",
            SimdLevel::Baseline => "baseline",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the level.
    pub fn available(self) -> bool {
        match self {
            SimdLevel::Auto | SimdLevel::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => pulp::x86::V3::is_available(),
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => pulp::x86::V4::is_available(),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The levels this CPU can run, widest last (without `Auto`).
    pub fn available_levels() -> Vec<SimdLevel> {
        [SimdLevel::Baseline, SimdLevel::Avx2, SimdLevel::Avx512]
            .into_iter()
            .filter(|l| l.available())
            .collect()
    }

    /// `Auto` resolved on this CPU; an unavailable level falls back to the widest available
    /// below it.
    /// Without allocating: [`dispatch`] resolves the level on every call, on the hot path
    /// (the availability checks are pulp's cached flags).
    pub fn resolved(self) -> SimdLevel {
        match self {
            SimdLevel::Auto | SimdLevel::Avx512 if SimdLevel::Avx512.available() => {
                SimdLevel::Avx512
            }
            SimdLevel::Auto | SimdLevel::Avx512 | SimdLevel::Avx2
                if SimdLevel::Avx2.available() =>
            {
                SimdLevel::Avx2
            }
            _ => SimdLevel::Baseline,
        }
    }

    /// Particles a lane kernel takes at once at this level: four vectors' worth (8 f64 in
    /// two SSE2 registers, 16 in four AVX2, 32 in four AVX-512), so that four independent
    /// chains of divisions and square roots overlap (measured on the Jacobi sweeps:
    /// one vector's worth ran at half the speed).
    pub fn lanes(self) -> usize {
        match self.resolved() {
            SimdLevel::Avx512 => 32,
            SimdLevel::Avx2 => 16,
            _ => 8,
        }
    }
}

/// A kernel generic over its lane count, for [`dispatch`].
pub trait LaneKernel {
    type Output;
    fn run<const L: usize>(self) -> Self::Output;
}

/// Runs `kernel` with the lanes and instruction set of `level` (resolved on this CPU).
#[inline]
pub fn dispatch<K: LaneKernel>(level: SimdLevel, kernel: K) -> K::Output {
    match level.resolved() {
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx512 => pulp::Simd::vectorize(
            pulp::x86::V4::try_new().expect("resolved to an available level"),
            Width::<K, 32>(kernel),
        ),
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 => pulp::Simd::vectorize(
            pulp::x86::V3::try_new().expect("resolved to an available level"),
            Width::<K, 16>(kernel),
        ),
        _ => kernel.run::<8>(),
    }
}

/// A kernel at `L` lanes, as pulp runs it: `with_simd` is inlined into pulp's function with
/// the instruction set's target features, and the kernel's `run` into it. (pulp's
/// closure form left the closure's body a function of its own, compiled without them:
/// not one AVX-512 instruction in the kernels, measured in the disassembly.)
struct Width<K, const L: usize>(K);

impl<K: LaneKernel, const L: usize> pulp::WithSimd for Width<K, L> {
    type Output = K::Output;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> K::Output {
        self.0.run::<L>()
    }
}

/// `L` f64 values, one per lane.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(transparent)]
pub struct F64s<const L: usize>(pub [f64; L]);

/// `L` truth values, one per lane.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(transparent)]
pub struct Mask<const L: usize>(pub [bool; L]);

// Plain index loops over the lanes: the form the compiler vectorizes without fail.
#[allow(clippy::needless_range_loop)]
impl<const L: usize> F64s<L> {
    #[inline(always)]
    pub fn splat(x: f64) -> Self {
        F64s([x; L])
    }

    #[inline(always)]
    pub fn from_fn(mut f: impl FnMut(usize) -> f64) -> Self {
        let mut out = [0.0; L];
        for (l, o) in out.iter_mut().enumerate() {
            *o = f(l);
        }
        F64s(out)
    }

    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let mut out = self.0;
        for o in &mut out {
            *o = f(*o);
        }
        F64s(out)
    }

    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f64, f64) -> f64) -> Self {
        let mut out = self.0;
        for l in 0..L {
            out[l] = f(out[l], o.0[l]);
        }
        F64s(out)
    }

    #[inline(always)]
    fn test(self, o: Self, f: impl Fn(f64, f64) -> bool) -> Mask<L> {
        let mut out = [false; L];
        for l in 0..L {
            out[l] = f(self.0[l], o.0[l]);
        }
        Mask(out)
    }

    #[inline(always)]
    pub fn sqrt(self) -> Self {
        self.map(f64::sqrt)
    }

    #[inline(always)]
    pub fn abs(self) -> Self {
        self.map(f64::abs)
    }

    /// The magnitude of `self` with the sign of `sign`.
    #[inline(always)]
    pub fn copysign(self, sign: Self) -> Self {
        self.zip(sign, f64::copysign)
    }

    #[inline(always)]
    pub fn le(self, o: Self) -> Mask<L> {
        self.test(o, |a, b| a <= b)
    }

    #[inline(always)]
    pub fn lt(self, o: Self) -> Mask<L> {
        self.test(o, |a, b| a < b)
    }

    #[inline(always)]
    pub fn eq(self, o: Self) -> Mask<L> {
        self.test(o, |a, b| a == b)
    }

    /// Per lane: `self` where `m` holds, else `other`.
    #[inline(always)]
    pub fn select(m: Mask<L>, yes: Self, no: Self) -> Self {
        let mut out = no.0;
        for l in 0..L {
            if m.0[l] {
                out[l] = yes.0[l];
            }
        }
        F64s(out)
    }
}

#[allow(clippy::needless_range_loop)]
impl<const L: usize> Mask<L> {
    #[inline(always)]
    pub fn splat(b: bool) -> Self {
        Mask([b; L])
    }

    #[inline(always)]
    pub fn and(self, o: Self) -> Self {
        let mut out = self.0;
        for l in 0..L {
            out[l] &= o.0[l];
        }
        Mask(out)
    }

    #[inline(always)]
    pub fn or(self, o: Self) -> Self {
        let mut out = self.0;
        for l in 0..L {
            out[l] |= o.0[l];
        }
        Mask(out)
    }

    #[inline(always)]
    pub fn negate(self) -> Self {
        let mut out = self.0;
        for o in &mut out {
            *o = !*o;
        }
        Mask(out)
    }

    #[inline(always)]
    pub fn all(self) -> bool {
        self.0.iter().all(|&b| b)
    }

    #[inline(always)]
    pub fn any(self) -> bool {
        self.0.iter().any(|&b| b)
    }
}

macro_rules! lane_op {
    ($trait:ident, $f:ident, $op:tt, $assign:ident, $af:ident) => {
        impl<const L: usize> $trait for F64s<L> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                self.zip(o, |a, b| a $op b)
            }
        }
        impl<const L: usize> $trait<f64> for F64s<L> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: f64) -> Self {
                self.map(|a| a $op o)
            }
        }
        impl<const L: usize> $trait<F64s<L>> for f64 {
            type Output = F64s<L>;
            #[inline(always)]
            fn $f(self, o: F64s<L>) -> F64s<L> {
                o.map(|b| self $op b)
            }
        }
        impl<const L: usize> $assign for F64s<L> {
            #[inline(always)]
            fn $af(&mut self, o: Self) {
                *self = *self $op o;
            }
        }
    };
}

lane_op!(Add, add, +, AddAssign, add_assign);
lane_op!(Sub, sub, -, SubAssign, sub_assign);
lane_op!(Mul, mul, *, MulAssign, mul_assign);
lane_op!(Div, div, /, DivAssign, div_assign);

impl<const L: usize> Neg for F64s<L> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|a| -a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct SumOfSquares<'a>(&'a [f64]);
    impl LaneKernel for SumOfSquares<'_> {
        type Output = Vec<f64>;
        fn run<const L: usize>(self) -> Vec<f64> {
            self.0
                .chunks_exact(L)
                .map(|c| {
                    let x = F64s::<L>::from_fn(|l| c[l]);
                    let y = (x * x + 1.0).sqrt() / x.abs().copysign(x);
                    y.0.iter().sum::<f64>()
                })
                .collect()
        }
    }

    #[test]
    fn every_level_resolves_to_one_this_cpu_runs() {
        for level in SimdLevel::ALL {
            assert!(level.resolved().available(), "{level:?}");
            assert!([8, 16, 32].contains(&level.lanes()));
        }
        assert_ne!(SimdLevel::Auto.resolved(), SimdLevel::Auto);
    }

    #[test]
    fn a_kernel_runs_at_every_available_level() {
        let x: Vec<f64> = (1..=64).map(|i| i as f64 * 0.37 - 9.0).collect();
        for level in SimdLevel::available_levels() {
            let out = dispatch(level, SumOfSquares(&x));
            assert_eq!(out.len(), 64 / level.lanes(), "{level:?}");
            let scalar: f64 = x.iter().map(|&v| (v * v + 1.0).sqrt() / v).sum();
            let total: f64 = out.iter().sum();
            assert!((total - scalar).abs() < 1e-9, "{level:?}");
        }
    }
}
