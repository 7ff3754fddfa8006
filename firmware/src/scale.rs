//! Code ↔ metres at the edge of the loop. The core computes in metres (f32) or nm (fixed
//! point, [`crate::core_number`]); the converters speak codes. Each conversion is a single
//! correctly rounded operation on an exact integer, so the host build reproduces it bit for
//! bit (replay feeds codes through the same path).

use crate::core_glue::{AdcScale, LoopReal, Number};

/// Metres per code of a converter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scale {
    /// Metres per code (may be negative to flip the axis).
    pub metres_per_code: f32,
    /// Codes per metre (its reciprocal, precomputed outside the loop).
    pub codes_per_metre: f32,
    /// Smallest code.
    pub min_code: i32,
    /// Largest code.
    pub max_code: i32,
    /// What [`Self::to_input`] needs besides `metres_per_code` (nothing in f32).
    pub input: AdcScale,
}

impl Scale {
    /// A 16-bit signed converter with `metres_per_code`; `None` for a zero or non-finite
    /// factor, or one the core's number type cannot hold (validated once, outside the loop).
    pub fn new_16bit(metres_per_code: f32) -> Option<Self> {
        if !metres_per_code.is_finite() || metres_per_code == 0.0 {
            return None;
        }
        Some(Self {
            metres_per_code,
            codes_per_metre: 1.0 / metres_per_code,
            min_code: -32768,
            max_code: 32767,
            input: Number::adc_scale(metres_per_code)?,
        })
    }

    /// The deflection the core's `step` takes for a code: `code as f32 * metres_per_code`
    /// (f32), or the exact nm of the code in Q31.32 (fixed point).
    #[inline(always)]
    pub fn to_input(&self, code: i32) -> Number {
        Number::from_code(&self.input, self.metres_per_code, code)
    }

    /// Metres for a code: `code as f32 * metres_per_code` (exact for |code| < 2²⁴).
    #[inline(always)]
    pub fn to_metres(&self, code: i32) -> f32 {
        code as f32 * self.metres_per_code
    }

    /// The nearest code for `m` (ties away from zero), clamped; NaN gives 0.
    #[inline(always)]
    pub fn to_code(&self, m: f32) -> i32 {
        let c = m * self.codes_per_metre;
        // `as i32` saturates and maps NaN to 0: no undefined or panicking path.
        let r = if c >= 0.0 {
            (c + 0.5) as i32
        } else {
            (c - 0.5) as i32
        };
        // max/min, not `clamp`: `clamp` asserts min ≤ max, a panic path in the loop.
        r.max(self.min_code).min(self.max_code)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_clamp() {
        let s = Scale::new_16bit(1e-9).unwrap();
        for c in [-32768, -1, 0, 1, 12345, 32767] {
            assert_eq!(s.to_code(s.to_metres(c)), c);
        }
        assert_eq!(s.to_code(1.0), 32767);
        assert_eq!(s.to_code(-1.0), -32768);
        assert_eq!(s.to_code(f32::NAN), 0);
        assert_eq!(s.to_code(f32::INFINITY), 32767);
        assert!(Scale::new_16bit(0.0).is_none());
        assert!(Scale::new_16bit(f32::NAN).is_none());
    }
}
