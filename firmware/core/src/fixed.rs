//! Fixed-point number types for the core: the same algorithms, one type parameter.
//!
//! Every algorithm of the core is generic over [`Real`]; these types implement it with
//! integers, so `Controller<Q32>` compiles as the whole core (prefilters, regressors,
//! estimators, contact detector, depth controller, excitation, modes) in fixed point, with no
//! second copy. They are for boards without an FPU and for results that are bit-exact by
//! construction on every target.
//!
//! **The entry point.** `Controller::step` takes and returns SI values (metres), converting
//! with factors of 10⁹ and 10⁻⁹ that no single Q format holds both of (Q31.32 stores 10⁻⁹ as
//! 4 LSB, a 7 % error: through `step`, Q32 was off by 79–869 % of each maximum). The
//! fixed-point path uses `Controller::step_internal` (D in nm), `u_internal`/`xy_internal` (or
//! the DAC codes) and `estimates_internal`, with SI conversions at the edge. Measured in closed
//! loop on the cell phantom (`host-sim/tests/fixed_point.rs`): Q32 within 0.06 % (DIVE) and
//! 0.26 % (SVE) of each property's maximum of the f64 reference, both estimators; Q24 within
//! 0.1 % (DIVE) but 6 % (SVE); Q16 off by 7–118 %.
//!
//! * [`Q32`]: Q31.32 in an `i64` (range ±2.1×10⁹, resolution 2.3×10⁻¹⁰). In the core's
//!   internal units (nm, nN, µs) positions, forces and parameters sit far inside the range and
//!   far above the resolution.
//! * [`Q24`], [`Q16`]: the same storage with 24 and 16 fractional bits, for the error against
//!   word length.
//!
//! Arithmetic: + and − saturate (never wrap); × rounds to nearest (ties away from zero) and
//! saturates, exactly as a 128-bit product would, computed with 32×32→64-bit partial products;
//! ÷ rounds to nearest and saturates, exactly as a 128-bit division would, computed as a long
//! division in 32-bit digits (the 128-bit forms are the reference of `tests/fixed_arith.rs`);
//! a division by zero gives the saturated value of the dividend's sign (0/0 gives 0) — never a
//! panic. There is no NaN or ∞: [`Real::is_finite`] is always true, and a saturated value is
//! the fixed-point image of an overflow.

use crate::excitation::{SineTable, SIN_TABLE_F64, TABLE_SIZE};
use crate::real::Real;
use core::num::NonZeroU32;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// The full 128-bit product of two `u64`, as (high, low) words, from four 32×32→64-bit
/// partial products: one `UMULL` each on a 32-bit Arm core, where a `u128` product would
/// call compiler-builtins' `__multi3`.
#[inline(always)]
fn mul_u64_wide(a: u64, b: u64) -> (u64, u64) {
    const LO: u64 = 0xffff_ffff;
    let (a0, a1) = (a & LO, a >> 32);
    let (b0, b1) = (b & LO, b >> 32);
    // Each partial product is at most (2³² − 1)², below 2⁶⁴.
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    // Bits 32..: at most 3·(2³² − 1), no overflow.
    let mid = (p00 >> 32) + (p01 & LO) + (p10 & LO);
    let lo = (mid << 32) | (p00 & LO);
    // Every partial sum is at most the final high word, which is below 2⁶⁴ because the
    // product is below 2¹²⁸: no overflow.
    let hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
    (hi, lo)
}

/// `a·b / 2^frac` rounded to nearest, ties away from zero, saturated to `i64`: bit for bit
/// the `i128` computation
/// `sat(if p >= 0 { (p + h) >> frac } else { -((-p + h) >> frac) })` with `p = a·b` and
/// `h = 2^(frac−1)` (the reference in `tests/fixed_arith.rs`), in 64- and 32-bit words.
///
/// The signed product is the unsigned product of the two's-complement words minus
/// `2⁶⁴·(b·[a < 0] + a·[b < 0])` (mod 2¹²⁸). Rounding: for p < 0, `−⌊(−p + h)/2^f⌋ =
/// ⌈(p − h)/2^f⌉ = ⌊(p + h − 1)/2^f⌋`, so both signs are one arithmetic shift of
/// `p + h − [p < 0]` (|p| ≤ 2¹²⁶: no overflow). `frac` must be in 1..=63.
#[inline(always)]
fn mul_round_sat(a: i64, b: i64, frac: u32) -> i64 {
    let (hi, lo) = mul_u64_wide(a as u64, b as u64);
    // All ones when negative.
    let a_neg = (a >> 63) as u64;
    let b_neg = (b >> 63) as u64;
    let hi = hi
        .wrapping_sub(a_neg & b as u64)
        .wrapping_sub(b_neg & a as u64);
    // p + h − [p < 0]: h − [p < 0] ≥ 0 since frac ≥ 1.
    let add = (1u64 << (frac - 1)) - (hi >> 63);
    let (lo, carry) = lo.overflowing_add(add);
    let hi = hi.wrapping_add(carry as u64) as i64;
    // r = p' >> frac fits in i64 iff p' >> (63 + frac), i.e. hi >> (frac − 1), is 0 or −1.
    let top = hi >> (frac - 1);
    if top == 0 || top == -1 {
        ((lo >> frac) | ((hi as u64) << (64 - frac))) as i64
    } else if hi < 0 {
        i64::MIN
    } else {
        i64::MAX
    }
}

/// `(u1·2³² + u0) / v` for a normalised `v` (≥ 2³¹) and `u1 < v`, so the quotient fits in a
/// `u32`: `divlu` of Hacker's Delight in 16-bit digits, each digit one 32-bit division (one
/// `UDIV` on a Cortex-M3, which has no 64-bit divide) and at most two corrections.
#[inline(always)]
fn div_u64_by_u32_norm(u1: u32, u0: u32, v: u32) -> u32 {
    const B: u32 = 1 << 16;
    const LO: u32 = B - 1;
    // v ≥ 2³¹, so v1 ≥ 2¹⁵; the fallback is never taken.
    let Some(v1_nz) = NonZeroU32::new(v >> 16) else {
        return u32::MAX;
    };
    let (v1, v0) = (v >> 16, v & LO);
    let (un1, un0) = (u0 >> 16, u0 & LO);

    // u1 < v < (v1 + 1)·B, so q1 < B + 2. Before q1·v0, q1 < B (< 2³²); before rhat·B,
    // rhat < B (≤ 2³² − B, + un1 < 2³²).
    let mut q1 = u1 / v1_nz;
    let mut rhat = u1 - q1 * v1;
    while q1 >= B || q1 * v0 > (rhat << 16) + un1 {
        q1 -= 1;
        rhat += v1;
        if rhat >= B {
            break;
        }
    }
    // The partial remainder, below v: exact modulo 2³².
    let un21 = (u1 << 16)
        .wrapping_add(un1)
        .wrapping_sub(q1.wrapping_mul(v));

    let mut q0 = un21 / v1_nz;
    let mut rhat = un21 - q0 * v1;
    while q0 >= B || q0 * v0 > (rhat << 16) + un0 {
        q0 -= 1;
        rhat += v1;
        if rhat >= B {
            break;
        }
    }
    (q1 << 16) | q0
}

/// `u / v` for a normalised `v` (≥ 2³¹), so the quotient is below 2³³: the top bit by one
/// comparison, the rest by [`div_u64_by_u32_norm`] (where a `u64` division would call
/// compiler-builtins' `__aeabi_uldivmod`, some 200 instructions on the Cortex-M3).
#[inline(always)]
fn div_u64_by_u32_wide(u: u64, v: u32) -> u64 {
    let (uh, ul) = ((u >> 32) as u32, u as u32);
    // uh < 2³² ≤ 2v, so after one subtraction uh < v.
    let (qh, uh) = if uh >= v { (1u64, uh - v) } else { (0, uh) };
    (qh << 32) | div_u64_by_u32_norm(uh, ul, v) as u64
}

/// `(u1·2⁶⁴ + u0) / v` for `u1 < v` (so the quotient fits in a `u64`): long division in 32-bit
/// digits with a normalised divisor (Knuth's algorithm D as `divlu` in Hacker's Delight,
/// 2nd ed., fig. 9–3), so each quotient digit is one 64-by-32-bit division
/// ([`div_u64_by_u32_wide`]) and at most two corrections, where a `u128` division expands to a
/// bit-by-bit loop on a 32-bit core.
#[inline(always)]
fn div_u128_by_u64(u1: u64, u0: u64, v: u64) -> u64 {
    const B: u64 = 1 << 32;
    const LO: u64 = B - 1;
    // v > u1 ≥ 0.
    let s = v.leading_zeros();
    let v = v << s;
    let (vn1, vn0) = (v >> 32, v & LO);
    // u1 < v, so u1 << s does not lose bits; (u0 >> 1) >> (63 − s) is u0 >> (64 − s), and 0
    // for s = 0, with no shift by 64.
    let un32 = (u1 << s) | ((u0 >> 1) >> (63 - s));
    let un10 = u0 << s;
    let (un1, un0) = (un10 >> 32, un10 & LO);

    // First digit: q̂ from the top two digits (un32 < v < (vn1 + 1)·B, so q̂ < B + 2),
    // corrected at most twice; vn1 ≥ 2³¹, as `div_u64_by_u32_wide` needs.
    let mut q1 = div_u64_by_u32_wide(un32, vn1 as u32);
    let mut rhat = un32 - q1 * vn1;
    // q1 < B before q1·vn0 (< 2⁶⁴); rhat < B before B·rhat (≤ 2⁶⁴ − B, + un1 < 2⁶⁴).
    while q1 >= B || q1 * vn0 > (rhat << 32) + un1 {
        q1 -= 1;
        rhat += vn1;
        if rhat >= B {
            break;
        }
    }
    // The partial remainder, below v: exact modulo 2⁶⁴.
    let un21 = (un32 << 32)
        .wrapping_add(un1)
        .wrapping_sub(q1.wrapping_mul(v));

    // Second digit (un21 < v, as un32 above).
    let mut q0 = div_u64_by_u32_wide(un21, vn1 as u32);
    let mut rhat = un21 - q0 * vn1;
    while q0 >= B || q0 * vn0 > (rhat << 32) + un0 {
        q0 -= 1;
        rhat += vn1;
        if rhat >= B {
            break;
        }
    }
    (q1 << 32) | q0
}

/// `a·2^frac / d` rounded to nearest (ties away from zero) and saturated to `i64`, a division
/// by zero giving the saturated value of `a`'s sign (0/0 = 0): bit for bit the `i128`
/// computation `q = (|n| + |d|/2) / |d|` with `n = a·2^frac`, negated when the signs differ,
/// then saturated (the reference in `tests/fixed_arith.rs`). `frac` must be in 1..=63.
#[inline(always)]
fn div_round_sat(a: i64, d: i64, frac: u32) -> i64 {
    if d == 0 {
        return if a > 0 {
            i64::MAX
        } else if a < 0 {
            i64::MIN
        } else {
            0
        };
    }
    let (na, da) = (a.unsigned_abs(), d.unsigned_abs());
    let neg = (a < 0) != (d < 0);
    // N = |a|·2^frac + ⌊|d|/2⌋ < 2⁹⁶ as (hi, lo); hi < 2^frac, so hi + 1 does not overflow.
    let (lo, carry) = (na << frac).overflowing_add(da >> 1);
    let hi = (na >> (64 - frac)) + carry as u64;
    // hi ≥ |d| means a quotient of at least 2⁶⁴: saturated either way.
    let q = if hi >= da {
        u64::MAX
    } else {
        div_u128_by_u64(hi, lo, da)
    };
    if neg {
        // −q ≥ i64::MIN iff q ≤ 2⁶³ (q = 2⁶³ gives i64::MIN itself).
        if q > 1 << 63 {
            i64::MIN
        } else {
            (q as i64).wrapping_neg()
        }
    } else if q > i64::MAX as u64 {
        i64::MAX
    } else {
        q as i64
    }
}

macro_rules! fixed {
    ($name:ident, $frac:expr, $table:ident, $doc:expr) => {
        #[doc = $doc]
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(pub i64);

        impl $name {
            /// Fractional bits.
            pub const FRAC: u32 = $frac;
            const SCALE: f64 = (1u64 << $frac) as f64;

            const fn from_f64_const(x: f64) -> Self {
                let v = x * Self::SCALE;
                // Round half away from zero; `as` saturates.
                $name(if v >= 0.0 {
                    (v + 0.5) as i64
                } else {
                    (v - 0.5) as i64
                })
            }
        }

        impl Add for $name {
            type Output = Self;
            #[inline(always)]
            fn add(self, o: Self) -> Self {
                $name(self.0.saturating_add(o.0))
            }
        }
        impl Sub for $name {
            type Output = Self;
            #[inline(always)]
            fn sub(self, o: Self) -> Self {
                $name(self.0.saturating_sub(o.0))
            }
        }
        impl Neg for $name {
            type Output = Self;
            #[inline(always)]
            fn neg(self) -> Self {
                $name(self.0.saturating_neg())
            }
        }
        impl Mul for $name {
            type Output = Self;
            #[inline(always)]
            fn mul(self, o: Self) -> Self {
                $name(mul_round_sat(self.0, o.0, $frac))
            }
        }
        impl Div for $name {
            type Output = Self;
            #[inline(always)]
            fn div(self, o: Self) -> Self {
                $name(div_round_sat(self.0, o.0, $frac))
            }
        }
        impl AddAssign for $name {
            #[inline(always)]
            fn add_assign(&mut self, o: Self) {
                *self = *self + o;
            }
        }
        impl SubAssign for $name {
            #[inline(always)]
            fn sub_assign(&mut self, o: Self) {
                *self = *self - o;
            }
        }
        impl MulAssign for $name {
            #[inline(always)]
            fn mul_assign(&mut self, o: Self) {
                *self = *self * o;
            }
        }

        impl Real for $name {
            const ZERO: Self = $name(0);
            const ONE: Self = $name(1 << $frac);
            #[inline(always)]
            fn from_f64(x: f64) -> Self {
                if x != x {
                    return $name(0);
                }
                Self::from_f64_const(x)
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self.0 as f64 / Self::SCALE
            }
            #[inline(always)]
            fn from_i32(x: i32) -> Self {
                $name((x as i64) << $frac)
            }
            #[inline(always)]
            fn round_i32(self) -> i32 {
                let half = 1i64 << ($frac - 1);
                let r = if self.0 >= 0 {
                    self.0.saturating_add(half) >> $frac
                } else {
                    -(self.0.saturating_neg().saturating_add(half) >> $frac)
                };
                r.clamp(i32::MIN as i64, i32::MAX as i64) as i32
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                true
            }
            const LOWEST: Self = $name(i64::MIN);
            const HIGHEST: Self = $name(i64::MAX);
            fn rank(self) -> i64 {
                self.0
            }
            fn from_rank(r: i64) -> Self {
                $name(r)
            }
        }

        static $table: [$name; TABLE_SIZE] = {
            let mut t = [$name(0); TABLE_SIZE];
            let mut i = 0;
            while i < TABLE_SIZE {
                t[i] = $name::from_f64_const(SIN_TABLE_F64[i]);
                i += 1;
            }
            t
        };

        impl SineTable for $name {
            // The table at every sample: see `SineTable::RECURSIVE`.
            const RECURSIVE: bool = false;
            #[inline(always)]
            fn sine_table() -> &'static [Self; TABLE_SIZE] {
                &$table
            }
        }
    };
}

fixed!(
    Q32,
    32,
    SIN_TABLE_Q32,
    "Q31.32 in an `i64`: the fixed-point core's default format."
);
fixed!(
    Q24,
    24,
    SIN_TABLE_Q24,
    "Q39.24 in an `i64` (the error against word length)."
);
fixed!(
    Q16,
    16,
    SIN_TABLE_Q16,
    "Q47.16 in an `i64` (the error against word length)."
);

#[cfg(test)]
mod tests {
    use super::*;

    /// The long division's building blocks against `u128` division on their whole contract
    /// (`u1 < v`, any `v`), beyond the operands the Q formats give them.
    #[test]
    fn long_division_matches_u128() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            // xorshift64*
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            x.wrapping_mul(0x2545_f491_4f6c_dd1d)
        };
        for i in 0..200_000u32 {
            // Divisors of every length, and words near the digit boundaries.
            let v = match i % 4 {
                0 => next() >> (next() % 64),
                1 => next() | 1 << 63,
                2 => (1u64 << (next() % 64))
                    .wrapping_add(next() % 3)
                    .wrapping_sub(1),
                _ => next() >> 32,
            }
            .max(1);
            let u1 = match i % 3 {
                0 => next() % v,
                1 => v - 1,
                _ => (next() >> (next() % 64)) % v,
            };
            let u0 = if i % 5 == 0 { u64::MAX } else { next() };
            let n = (u1 as u128) << 64 | u0 as u128;
            assert_eq!(
                div_u128_by_u64(u1, u0, v) as u128,
                n / v as u128,
                "{u1:#x}:{u0:#x} / {v:#x}"
            );
            let w = (v >> 32) as u32 | 1 << 31;
            assert_eq!(
                div_u64_by_u32_wide(u0, w),
                u0 / w as u64,
                "{u0:#x} / {w:#x}"
            );
        }
    }

    #[test]
    fn arithmetic_rounds_to_nearest_and_saturates() {
        let a = Q32::from_f64(1.5);
        let b = Q32::from_f64(-2.25);
        assert_eq!((a * b).to_f64(), -3.375);
        assert_eq!((a / b).to_f64(), Q32::from_f64(-1.5 / 2.25).to_f64());
        assert_eq!((a + b).to_f64(), -0.75);
        // Saturation, never wrap-around.
        let big = Q32(i64::MAX - 1);
        assert_eq!((big + big).0, i64::MAX);
        assert_eq!((big * big).0, i64::MAX);
        assert_eq!((-big * big).0, i64::MIN);
        assert_eq!((-big - big).0, i64::MIN);
        assert_eq!((Q32(i64::MIN)).abs().0, i64::MAX);
        // Division by zero: the dividend's sign, saturated; 0/0 = 0.
        assert_eq!((a / Q32::ZERO).0, i64::MAX);
        assert_eq!((b / Q32::ZERO).0, i64::MIN);
        assert_eq!((Q32::ZERO / Q32::ZERO).0, 0);
        assert_eq!(Q32(i64::MIN) / Q32(-1), Q32(i64::MAX));
        // One LSB of rounding error at most, against f64.
        let lsb = 1.0 / (1u64 << 32) as f64;
        for (x, y) in [
            (3.1e3, 7.3e-4),
            (-0.37, 1234.5),
            (1e-5, -3e-5),
            (2.0e4, 2.0e4),
        ] {
            let (qx, qy) = (Q32::from_f64(x), Q32::from_f64(y));
            let exact = qx.to_f64() * qy.to_f64();
            assert!(((qx * qy).to_f64() - exact).abs() <= 0.5 * lsb + exact.abs() * 1e-15);
            let exact = qx.to_f64() / qy.to_f64();
            assert!(((qx / qy).to_f64() - exact).abs() <= 0.5 * lsb + exact.abs() * 1e-15);
        }
        assert_eq!(Q32::from_f64(2.5).round_i32(), 3);
        assert_eq!(Q32::from_f64(-2.5).round_i32(), -3);
        assert_eq!(Q32::from_f64(1e12).round_i32(), i32::MAX);
        assert_eq!(Q16::from_f64(-7.49).round_i32(), -7);
    }
}
