//! The number type the core computes in.
//!
//! Every algorithm in the core is written once, generic over [`Real`]. `f32` is what runs on
//! the Cortex-M7's single-precision FPU; `f64` is the host reference that the f32 results are
//! checked against. Only IEEE-754 operations that are correctly rounded on every target are
//! used (+, −, ×, ÷, comparisons): no fused multiply–add and no transcendental functions in
//! the loop, so the f32 core gives bit-identical results on the host and on the target.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// A real number type for the loop-rate core.
pub trait Real:
    Copy
    + Debug
    + Default
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// 0
    const ZERO: Self;
    /// 1
    const ONE: Self;
    /// A division costs about as much as a product (one FPU instruction), so that skipping an
    /// exact one (`x / 1 = x`) by a test would cost more than it saves; false for the fixed-point
    /// types, whose quotient is a long division of some 200 instructions on the Cortex-M3.
    const CHEAP_DIV: bool = false;
    /// Conversion from a configuration value (done once, outside the loop).
    fn from_f64(x: f64) -> Self;
    /// Conversion for reporting.
    fn to_f64(self) -> f64;
    /// Conversion of a DAC/ADC code.
    fn from_i32(x: i32) -> Self;
    /// Round half away from zero and saturate to `i32` (NaN gives 0).
    fn round_i32(self) -> i32;
    /// False for NaN and ±∞.
    fn is_finite(self) -> bool;
    /// The lowest value (−∞ for the floats).
    const LOWEST: Self;
    /// The highest value (+∞ for the floats).
    const HIGHEST: Self;
    /// The value's rank among all the type's values: `a < b` ⟺ `a.rank() < b.rank()` (NaN
    /// excluded; −0 and +0 share rank 0), so that a search over the values between two is a
    /// search over integers (exact thresholds, found once per tap, off the per-sample path).
    fn rank(self) -> i64;
    /// The value of a rank from `LOWEST.rank()` to `HIGHEST.rank()`.
    fn from_rank(r: i64) -> Self;

    /// |x|
    #[inline(always)]
    fn abs(self) -> Self {
        if self < Self::ZERO {
            -self
        } else {
            self
        }
    }
    /// `−b < self < b`, i.e. `|self| < b` (false for NaN). The floats take `|self|` in one
    /// instruction (the sign of a zero does not change a comparison, so the result is the
    /// same); the default compares twice.
    #[inline(always)]
    fn abs_lt(self, b: Self) -> bool {
        self < b && self > -b
    }
    /// The value limited to `[lo, hi]`; a NaN becomes `lo`.
    #[inline(always)]
    fn clamp_to(self, lo: Self, hi: Self) -> Self {
        if self > hi {
            hi
        } else if self >= lo {
            self
        } else {
            lo
        }
    }
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const CHEAP_DIV: bool = true;
    #[inline(always)]
    fn abs_lt(self, b: Self) -> bool {
        f32::abs(self) < b
    }
    #[inline(always)]
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn from_i32(x: i32) -> Self {
        x as f32
    }
    #[inline(always)]
    fn round_i32(self) -> i32 {
        // `as` saturates and maps NaN to 0: no undefined behaviour, no panic. Adding ±0.5 by
        // the sign (no branch) is `if x >= 0 { x + 0.5 } else { x − 0.5 }` in every case: for
        // −0.0 both truncate to 0, for NaN both give 0.
        (self + 0.5f32.copysign(self)) as i32
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    const LOWEST: Self = f32::NEG_INFINITY;
    const HIGHEST: Self = f32::INFINITY;
    fn rank(self) -> i64 {
        // IEEE-754 orders the magnitudes of one sign as their bit patterns.
        let b = self.to_bits();
        let m = i64::from(b & 0x7FFF_FFFF);
        if b >> 31 != 0 {
            -m
        } else {
            m
        }
    }
    fn from_rank(r: i64) -> Self {
        let m = r.unsigned_abs().min(0x7FFF_FFFF) as u32;
        f32::from_bits(if r < 0 { m | 0x8000_0000 } else { m })
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const CHEAP_DIV: bool = true;
    #[inline(always)]
    fn abs_lt(self, b: Self) -> bool {
        f64::abs(self) < b
    }
    #[inline(always)]
    fn from_f64(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn from_i32(x: i32) -> Self {
        x as f64
    }
    #[inline(always)]
    fn round_i32(self) -> i32 {
        // As for f32.
        (self + 0.5f64.copysign(self)) as i32
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    const LOWEST: Self = f64::NEG_INFINITY;
    const HIGHEST: Self = f64::INFINITY;
    fn rank(self) -> i64 {
        // As for f32.
        let b = self.to_bits();
        let m = (b & 0x7FFF_FFFF_FFFF_FFFF) as i64;
        if b >> 63 != 0 {
            -m
        } else {
            m
        }
    }
    fn from_rank(r: i64) -> Self {
        let m = r.unsigned_abs() & 0x7FFF_FFFF_FFFF_FFFF;
        f64::from_bits(if r < 0 { m | (1 << 63) } else { m })
    }
}
