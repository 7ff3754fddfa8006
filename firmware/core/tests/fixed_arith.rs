//! The fixed-point product (32×32→64-bit partial products) and quotient (long division in
//! 32-bit digits) against the `i128` forms they replaced: bit for bit, rounding ties,
//! saturation and division by zero included.

use proptest::prelude::*;
use visco_core::fixed::{Q16, Q24, Q32};

/// The reference: the exact `i128` product, rounded to nearest (ties away from zero), then
/// saturated to `i64` — the implementation of `Mul` before the 32-bit-limb version.
fn reference(a: i64, b: i64, frac: u32) -> i64 {
    let p = a as i128 * b as i128;
    let half = 1i128 << (frac - 1);
    let r = if p >= 0 {
        (p + half) >> frac
    } else {
        -((-p + half) >> frac)
    };
    if r > i64::MAX as i128 {
        i64::MAX
    } else if r < i64::MIN as i128 {
        i64::MIN
    } else {
        r as i64
    }
}

/// The reference quotient: the `i128` division, rounded to nearest, saturated, a division by
/// zero giving the saturated dividend's sign — the implementation of `Div` before the 32-bit
/// long division.
fn reference_div(a: i64, d: i64, frac: u32) -> i64 {
    if d == 0 {
        return if a > 0 {
            i64::MAX
        } else if a < 0 {
            i64::MIN
        } else {
            0
        };
    }
    let n = (a as i128) << frac;
    let d = d as i128;
    let (na, da) = (n.unsigned_abs(), d.unsigned_abs());
    let q = (na + da / 2) / da;
    let q = if q > i128::MAX as u128 {
        i128::MAX
    } else {
        q as i128
    };
    let r = if (n < 0) != (d < 0) { -q } else { q };
    if r > i64::MAX as i128 {
        i64::MAX
    } else if r < i64::MIN as i128 {
        i64::MIN
    } else {
        r as i64
    }
}

fn check_div(a: i64, d: i64) {
    assert_eq!(
        (Q32(a) / Q32(d)).0,
        reference_div(a, d, 32),
        "Q32 {a} / {d}"
    );
    assert_eq!(
        (Q24(a) / Q24(d)).0,
        reference_div(a, d, 24),
        "Q24 {a} / {d}"
    );
    assert_eq!(
        (Q16(a) / Q16(d)).0,
        reference_div(a, d, 16),
        "Q16 {a} / {d}"
    );
}

fn check(a: i64, b: i64) {
    check_div(a, b);
    assert_eq!((Q32(a) * Q32(b)).0, reference(a, b, 32), "Q32 {a} × {b}");
    assert_eq!((Q24(a) * Q24(b)).0, reference(a, b, 24), "Q24 {a} × {b}");
    assert_eq!((Q16(a) * Q16(b)).0, reference(a, b, 16), "Q16 {a} × {b}");
    let mut m = Q32(a);
    m *= Q32(b);
    assert_eq!(m.0, reference(a, b, 32), "Q32 {a} *= {b}");
}

/// Values where the limb arithmetic has its edges: signs, carries between the 32-bit limbs,
/// the rounding bit, and the saturation boundary of each format.
fn adversarial() -> Vec<i64> {
    let mut v = vec![
        0,
        1,
        -1,
        2,
        -2,
        i64::MAX,
        i64::MIN,
        i64::MAX - 1,
        i64::MIN + 1,
        u32::MAX as i64,
        -(u32::MAX as i64),
        i32::MAX as i64,
        i32::MIN as i64,
        0x8000_0000,
        -0x8000_0000,
        0x1_0000_0001,
        -0x1_0000_0001,
        0xffff_ffff_ffff,
        0x7fff_ffff_8000_0000,
        -0x7fff_ffff_8000_0000,
    ];
    for k in 0..63 {
        let p = 1i64 << k;
        v.extend([p, -p, p - 1, -(p - 1), p + 1, -(p + 1)]);
    }
    // Square roots of the saturation thresholds 2^(63+frac) of each format, and around them:
    // products that land just inside or just outside the range.
    for frac in [16u32, 24, 32] {
        let limit = 2f64.powi(63 + frac as i32);
        let s = limit.sqrt() as i64;
        for d in -3..=3 {
            v.extend([s + d, -(s + d)]);
        }
    }
    v.push(i64::MIN);
    v
}

#[test]
fn adversarial_pairs_match_the_i128_reference() {
    // Both products and quotients (`check` runs both).
    let v = adversarial();
    for &a in &v {
        for &b in &v {
            check(a, b);
        }
    }
}

#[test]
fn rounding_ties_and_saturation_edges() {
    // Exact ties: ±(k + ½) LSB, away from zero.
    for frac in [16u32, 24, 32] {
        let half = 1i64 << (frac - 1);
        for k in -5i64..=5 {
            // (2k+1)·2^(frac−1) · 1 (= 2^0 raw) is a product of (2k+1)·half and 1 raw unit.
            let a = (2 * k + 1) * half;
            check(a, 1);
            check(1, a);
            check(a, -1);
            check(a - 1, 1);
            check(a + 1, 1);
        }
    }
    // Products just at i64::MAX and i64::MIN after rounding, for Q32: 2^63·2^32 = 2^95.
    let a = 1i64 << 48;
    for b in [
        (1i64 << 47) - 1,
        1i64 << 47,
        -(1i64 << 47),
        -(1i64 << 47) - 1,
    ] {
        check(a, b);
    }
    // Quotients at the rounding tie and at the saturation boundary: a·2^32 / d near 2^63.
    for d in [
        1i64,
        2,
        3,
        4,
        5,
        7,
        1 << 31,
        (1 << 32) - 1,
        1 << 32,
        (1 << 32) + 1,
    ] {
        for a in [d / 2, d / 2 + 1, d + d / 2, -(d / 2), -(d + d / 2), 3 * d] {
            check_div(a, d);
            check_div(a, -d);
        }
        for k in -3i64..=3 {
            // a ≈ d·2^31: the quotient ≈ 2^63.
            let a = d.saturating_mul(1 << 31).saturating_add(k);
            check_div(a, d);
            check_div(-a, d);
            check_div(a, -d);
        }
    }
}

fn interesting() -> impl Strategy<Value = i64> {
    prop_oneof![
        any::<i64>(),
        // Typical magnitudes of the core's internal units, in Q31.32.
        (-(1i64 << 45)..(1i64 << 45)),
        // Near the square root of the Q32 saturation threshold (2^47.5).
        (-(1i64 << 48)..(1i64 << 48)),
        // Powers of two and their neighbours.
        (0u32..63, -2i64..=2, any::<bool>()).prop_map(|(k, d, neg)| {
            let v = (1i64 << k).wrapping_add(d);
            if neg {
                v.wrapping_neg()
            } else {
                v
            }
        }),
        // The low limb at the rounding edge: bit 31 patterns.
        (
            any::<i32>(),
            prop_oneof![
                Just(0x8000_0000u32),
                Just(0x7fff_ffff),
                Just(0xffff_ffff),
                Just(0)
            ]
        )
            .prop_map(|(h, l)| ((h as i64) << 32) | l as i64),
        Just(i64::MIN),
        Just(i64::MAX),
        Just(0i64),
        Just(1i64),
        Just(-1i64),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn product_matches_the_i128_reference(a in interesting(), b in interesting()) {
        check(a, b);
    }

    #[test]
    fn uniform_product_matches_the_i128_reference(a in any::<i64>(), b in any::<i64>()) {
        check(a, b);
    }

    /// Quotients that do not saturate: divisors of every size, dividends at most 2^31 times
    /// the divisor, so the 32-bit long division is exercised on every digit.
    #[test]
    fn unsaturated_quotient_matches_the_i128_reference(
        d in interesting(),
        shift in 0u32..64,
        m in any::<i64>(),
    ) {
        // a = d·m / 2^(shift mod 32) with |m| < 2^31: |a·2^32 / d| < 2^63 (when a fits), a
        // spread of quotient sizes.
        let a = (d as i128 * (m as i32) as i128) >> (shift % 32);
        let a = i64::try_from(a).unwrap_or(m);
        check_div(a, d);
        check_div(d, a);
        check_div(a >> (shift % 8), d);
    }
}
