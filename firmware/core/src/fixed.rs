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
//! saturates, computed in 128 bits; ÷ rounds to nearest and saturates, and a division by zero
//! gives the saturated value of the dividend's sign (0/0 gives 0) — never a panic. There is no
//! NaN or ∞: [`Real::is_finite`] is always true, and a saturated value is the fixed-point
//! image of an overflow.

use crate::excitation::{SineTable, SIN_TABLE_F64, TABLE_SIZE};
use crate::real::Real;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

macro_rules! fixed {
    ($name:ident, $frac:expr, $table:ident, $doc:expr) => {
        #[doc = $doc]
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(pub i64);

        impl $name {
            /// Fractional bits.
            pub const FRAC: u32 = $frac;
            const SCALE: f64 = (1u64 << $frac) as f64;

            #[inline(always)]
            fn sat(x: i128) -> Self {
                $name(if x > i64::MAX as i128 {
                    i64::MAX
                } else if x < i64::MIN as i128 {
                    i64::MIN
                } else {
                    x as i64
                })
            }

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
                let p = self.0 as i128 * o.0 as i128;
                // Round to nearest, ties away from zero: add half an LSB of the magnitude.
                let half = 1i128 << ($frac - 1);
                let r = if p >= 0 {
                    (p + half) >> $frac
                } else {
                    -((-p + half) >> $frac)
                };
                Self::sat(r)
            }
        }
        impl Div for $name {
            type Output = Self;
            #[inline(always)]
            fn div(self, o: Self) -> Self {
                if o.0 == 0 {
                    return $name(if self.0 > 0 {
                        i64::MAX
                    } else if self.0 < 0 {
                        i64::MIN
                    } else {
                        0
                    });
                }
                // |n| < 2^127 and |d| ≥ 1: neither overflows nor divides by zero.
                let n = (self.0 as i128) << $frac;
                let d = o.0 as i128;
                let (na, da) = (n.unsigned_abs(), d.unsigned_abs());
                let q = (na + da / 2) / da;
                let q = if q > i128::MAX as u128 {
                    i128::MAX
                } else {
                    q as i128
                };
                Self::sat(if (n < 0) != (d < 0) { -q } else { q })
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
