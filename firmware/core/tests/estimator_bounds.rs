#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]
//! Stability of the discretised laws and the bounds the estimator keeps for any input.

use proptest::prelude::*;
use visco_core::estimator::{Estimator, EstimatorKind, EstimatorParams};

fn params(kind: EstimatorKind, alpha: f64, r0: f64, gain: f64) -> EstimatorParams<f64, 3> {
    EstimatorParams {
        kind,
        period: 1.0,
        inv_period: 1.0,
        alpha,
        forget: 1.0 + 1e-3,
        r0,
        p0: [r0 / 4.0; 3],
        gain: [gain; 3],
        theta_min: [0.0, 0.01, -1e4],
        theta_max: [1e3, 10.0, 1e4],
    }
}

/// A persistently exciting regressor sequence with a large, slowly varying size: the
/// normalisation keeps T·Pφφᵀ/m² near T·‖P‖/α, the worst case of the stability conditions.
fn regressor(k: usize) -> [f64; 3] {
    let t = k as f64;
    let size = 1e3 * (1.0 + 0.5 * (t * 0.001).sin());
    [
        size * (t * 0.7).sin(),
        size * (t * 0.13).cos(),
        size * (0.5 + 0.3 * (t * 0.031).sin()),
    ]
}

fn truth() -> [f64; 3] {
    [5.0, 0.5, 20.0]
}

/// max that treats NaN as infinitely bad (f64::max would drop it).
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::INFINITY
    } else {
        a.max(b)
    }
}

fn error_after(est: &mut Estimator<f64, 3>, p: &EstimatorParams<f64, 3>, n: usize) -> f64 {
    let th = truth();
    for k in 0..n {
        let phi = regressor(k);
        let w = th[0] * phi[0] + th[1] * phi[1] + th[2] * phi[2];
        est.update(p, w, &phi);
    }
    let e = est.theta();
    (0..3)
        .map(|i| ((e[i] - th[i]) / th[i]).abs())
        .fold(0.0, nan_max)
}

/// Forward Euler of the paper's continuous law, the discretisation we do *not* use: it needs
/// T·R₀/α < 2 and loses positive definiteness beyond 1.
fn euler_error_after(p: &EstimatorParams<f64, 3>, n: usize) -> f64 {
    let th = truth();
    let mut theta = [1.0, 1.0, 1.0];
    let mut pm = [[0.0; 3]; 3];
    for i in 0..3 {
        pm[i][i] = p.p0[i];
    }
    for k in 0..n {
        let phi = regressor(k);
        let w = th[0] * phi[0] + th[1] * phi[1] + th[2] * phi[2];
        let m2 = 1.0 + p.alpha * phi.iter().map(|v| v * v).sum::<f64>();
        let e = (w - (0..3).map(|i| theta[i] * phi[i]).sum::<f64>()) / m2;
        let pphi: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| pm[i][j] * phi[j]).sum())
            .collect();
        for i in 0..3 {
            theta[i] += p.period * pphi[i] * e;
        }
        let tr: f64 = (0..3).map(|i| pm[i][i]).sum();
        if tr <= p.r0 {
            let beta = (p.forget - 1.0) / p.period;
            for i in 0..3 {
                for j in 0..3 {
                    pm[i][j] += p.period * (beta * pm[i][j] - pphi[i] * pphi[j] / m2);
                }
            }
        }
    }
    (0..3)
        .map(|i| ((theta[i] - th[i]) / th[i]).abs())
        .fold(0.0, nan_max)
}

#[test]
fn least_squares_is_stable_at_every_gain_where_euler_is_not() {
    let alpha = 1e-6;
    // T·R₀/α from 0.1 (where Euler works) to 10⁴ (where Euler diverges at once).
    for ratio in [0.1, 1.5, 3.0, 100.0, 1e4] {
        let p = params(EstimatorKind::LeastSquares, alpha, ratio * alpha, 0.0);
        let mut est = Estimator::new(&p, [1.0, 1.0, 1.0]);
        let err = error_after(&mut est, &p, 20_000);
        let tr: f64 = (0..3).map(|i| est.covariance()[i][i]).sum();
        let euler = euler_error_after(&p, 20_000);
        println!("T·R0/α = {ratio}: discrete LS error {err:.2e}, tr P/R0 = {:.3}; forward Euler error {euler:.2e}", tr / p.r0);
        assert!(err < 1e-6, "LS not converged at T·R0/α = {ratio}: {err}");
        assert!(tr <= p.r0 * (1.0 + 1e-12));
        if ratio >= 100.0 {
            assert!(
                !(euler < 1.0),
                "forward Euler should fail at T·R0/α = {ratio} (error {euler})"
            );
        }
        if ratio <= 0.1 {
            assert!(
                euler < 1e-6,
                "forward Euler should work at T·R0/α = {ratio} (error {euler})"
            );
        }
    }
}

#[test]
fn gradient_law_is_stable_below_its_bound_and_not_above() {
    // α·φᵀφ ≫ 1 here, so φᵀφ/m² is close to its supremum 1/α: the bound is tight.
    let alpha = 1e-3;
    // T·γ/α < 2 is the bound (φᵀφ/m² < 1/α); validation asks for ≤ 1.
    for (ratio, stable) in [
        (0.5, true),
        (1.0, true),
        (1.9, true),
        (2.5, false),
        (4.0, false),
    ] {
        let p = params(EstimatorKind::Gradient, alpha, 1.0, ratio * alpha);
        let mut est = Estimator::new(&p, [1.0, 1.0, 1.0]);
        let th = truth();
        let mut worst_growth = 0.0f64;
        let initial = 19.0; // |1 − 20|, the largest initial error
        for k in 0..20_000 {
            let phi = regressor(k);
            let w = th[0] * phi[0] + th[1] * phi[1] + th[2] * phi[2];
            est.update(&p, w, &phi);
            let e = est.theta();
            worst_growth =
                worst_growth.max((0..3).map(|i| (e[i] - th[i]).abs()).fold(0.0, nan_max));
        }
        println!("T·γ/α = {ratio}: largest parameter error {worst_growth:.3e}");
        let e = est.theta();
        let final_err = (0..3).map(|i| (e[i] - th[i]).abs()).fold(0.0, nan_max);
        if stable {
            // Bounded near its start and converging.
            assert!(
                worst_growth <= 1.5 * initial,
                "unstable at T·γ/α = {ratio}: {worst_growth}"
            );
            assert!(
                final_err < 1e-3 * initial,
                "not converging at T·γ/α = {ratio}: {final_err}"
            );
        } else {
            // Driven to the projection box's walls.
            assert!(
                worst_growth > 100.0,
                "expected divergence at T·γ/α = {ratio}: {worst_growth}"
            );
        }
    }
}

fn arb_value() -> impl Strategy<Value = f64> {
    prop_oneof![
        -1e30f64..1e30,
        -1e3f64..1e3,
        -1e-6f64..1e-6,
        Just(0.0),
        Just(f64::MAX),
        Just(-f64::MAX),
        Just(f64::MIN_POSITIVE),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// For any finite data: tr P ≤ R₀, P's diagonal positive, k̂ and every θ̂ inside the box,
    /// everything finite — in f32, the type the board runs.
    #[test]
    fn least_squares_bounds_hold_for_adversarial_finite_inputs(
        data in proptest::collection::vec((arb_value(), arb_value(), arb_value(), arb_value()), 1..400),
        gradient in any::<bool>(),
    ) {
        let p64 = params(if gradient { EstimatorKind::Gradient } else { EstimatorKind::LeastSquares }, 1e-4, 1e3, 1e-5);
        let p = EstimatorParams::<f32, 3> {
            kind: p64.kind,
            period: 1.0,
            inv_period: 1.0,
            alpha: p64.alpha as f32,
            forget: p64.forget as f32,
            r0: p64.r0 as f32,
            p0: p64.p0.map(|v| v as f32),
            gain: p64.gain.map(|v| v as f32),
            theta_min: p64.theta_min.map(|v| v as f32),
            theta_max: p64.theta_max.map(|v| v as f32),
        };
        let mut est = Estimator::<f32, 3>::new(&p, [1.0, 1.0, 1.0]);
        for (w, a, b, c) in data {
            est.update(&p, w as f32, &[a as f32, b as f32, c as f32]);
            let th = est.theta();
            let cov = est.covariance();
            let tr: f32 = (0..3).map(|i| cov[i][i]).sum();
            prop_assert!(tr.is_finite() && tr <= p.r0 * 1.000_01, "tr P = {}", tr);
            for i in 0..3 {
                prop_assert!(cov[i][i] > 0.0);
                prop_assert!(th[i].is_finite());
                prop_assert!(th[i] >= p.theta_min[i] && th[i] <= p.theta_max[i], "θ{} = {}", i, th[i]);
            }
        }
    }
}
