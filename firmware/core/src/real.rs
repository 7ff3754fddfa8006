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
    /// The nearest integer as a DAC code, saturated to `i32` (NaN gives 0), exact over the
    /// codes of a DAC of up to [`Self::CODE_BITS_MAX`] bits (f32: |x| < 2²²). Ties: the floats round to even (their own rounding, by
    /// adding and subtracting 1.5·2^(p−1): two additions, where the half away from zero took
    /// the sign's ½ by integer operations; issue 14 round 16); the fixed-point types away
    /// from zero.
    #[inline(always)]
    fn round_code(self) -> i32 {
        self.round_i32()
    }
    /// The widest DAC (bits) whose codes [`Self::round_code`] rounds exactly: every code of a
    /// b-bit DAC and its neighbourhood lie within ±2^(b−1) + 1.
    const CODE_BITS_MAX: u32 = 24;
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
    fn round_code(self) -> i32 {
        // |x| < 2²²: x + 1.5·2²³ lies in [2²³, 2²⁴), where the spacing of f32 is 1, so the sum
        // is x rounded to the nearest integer (ties to even) plus the constant, and the
        // subtraction is exact. Outside, the result stays within a spacing of x, so the code
        // saturates to the same side; NaN gives 0.
        const M: f32 = 12_582_912.0;
        ((self + M) - M) as i32
    }
    /// 2²² bounds the exact range: a 22-bit DAC's codes (±2²¹) with room.
    const CODE_BITS_MAX: u32 = 22;
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
    fn round_code(self) -> i32 {
        // As for f32, with 1.5·2⁵² (exact for |x| < 2⁵¹): the same ties to even.
        const M: f64 = 6_755_399_441_055_744.0;
        ((self + M) - M) as i32
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

#[cfg(test)]
mod tests {
    use super::Real;

    /// The nearest integer with ties to even, from the value's exact binary expansion (an
    /// oracle that shares nothing with `round_code`: the integer part by truncation, the
    /// fraction compared with ½ exactly, f64 holding every f32 exactly).
    fn nearest_even(x: f64) -> f64 {
        let t = x.trunc();
        let frac = (x - t).abs();
        let away = t + x.signum();
        if frac > 0.5 || (frac == 0.5 && t % 2.0 != 0.0) {
            away
        } else {
            t
        }
    }

    #[test]
    fn round_code_is_the_nearest_integer_with_ties_to_even() {
        // Ties, the values next to them (where x + ½ used to round up in f32: 0.49999997),
        // zeros, and a DAC's range.
        let below_half = f32::from_bits(0.5f32.to_bits() - 1);
        let cases: [f32; 12] = [
            0.5,
            1.5,
            2.5,
            -0.5,
            -2.5,
            below_half,
            -below_half,
            0.0,
            -0.0,
            32767.5,
            -32768.5,
            4_194_303.5,
        ];
        // A deterministic spread over ±2²² (an LCG), as the DAC grid sees after scaling.
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let spread = (0..100_000).map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f64 / (1u64 << 24) as f64 * 2.0 - 1.0) as f32 * 4_194_303.0
        });
        for x in cases.into_iter().chain(spread) {
            let want = nearest_even(x as f64);
            let c = x.round_code();
            assert_eq!(c as f64, want, "{x}");
            // The f64 reference rounds alike.
            assert_eq!((x as f64).round_code(), c, "{x}");
        }
    }

    #[test]
    fn round_code_saturates_to_the_right_side_outside_its_range() {
        for (x, side) in [
            (1e9f32, i32::MAX),
            (-1e9, i32::MIN),
            (-12_582_913.0, i32::MIN),
            (f32::INFINITY, i32::MAX),
            (f32::NEG_INFINITY, i32::MIN),
        ] {
            let c = x.round_code();
            // Beyond ±2²² the code is x's integer or saturated: on x's side, beyond any DAC's.
            assert!(
                c.signum() == side.signum() && c.unsigned_abs() >= 1 << 22,
                "{x}: {c}"
            );
        }
        assert_eq!(f32::NAN.round_code(), 0);
        assert_eq!(f64::NAN.round_code(), 0);
    }
}
