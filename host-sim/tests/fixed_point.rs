//! The fixed-point core (issue 8): `Controller<Q32>` is the same code as `Controller<f32>`, one
//! type parameter apart, driven through the internal-unit entry point (`step_internal`). On the
//! paper's DIVE and SVE cases (reduced: 3 × 3 taps, one SVE line on the cell phantom) in closed
//! loop with the plant, the estimates at each record are compared with the f64 reference, in %
//! of each property's maximum; the error against word length is printed
//! (`cargo test --release -p visco --test fixed_point -- --nocapture`). The runs are
//! `visco::experiment::fixed_point`, which `cargo xtask firmware-report` uses too.

use visco::experiment::fixed_point::{error_pct, record_estimates};
use visco_core::fixed::{Q16, Q24, Q32};
use visco_core::{EstimatorKind, Mode};

#[test]
fn fixed_point_against_f64() {
    for (mode, kind) in [
        (Mode::Dive, EstimatorKind::Gradient),
        (Mode::Sve, EstimatorKind::Gradient),
        (Mode::Dive, EstimatorKind::LeastSquares),
        (Mode::Sve, EstimatorKind::LeastSquares),
    ] {
        let reference = record_estimates::<f64>(mode, kind);
        assert!(
            reference.len() >= 9,
            "{mode:?}: {} records",
            reference.len()
        );
        println!(
            "{mode:?} {kind:?} ({} records), max error vs f64 in % of max h / c / k:",
            reference.len()
        );
        let errors = [
            (
                "f32",
                error_pct(&record_estimates::<f32>(mode, kind), &reference),
            ),
            (
                "Q32",
                error_pct(&record_estimates::<Q32>(mode, kind), &reference),
            ),
            (
                "Q24",
                error_pct(&record_estimates::<Q24>(mode, kind), &reference),
            ),
            (
                "Q16",
                error_pct(&record_estimates::<Q16>(mode, kind), &reference),
            ),
        ];
        for (name, e) in errors {
            println!("  {name}: {:.4} / {:.4} / {:.4}", e[2], e[0], e[1]);
        }
        // Issue 8's goal: within 0.5 % of each maximum (f32, for scale, is held to the same).
        for (name, e) in &errors[..2] {
            assert!(
                e.iter().all(|&v| v <= 0.5),
                "{mode:?} {kind:?} {name}: {e:?}"
            );
        }
        // Word length matters: 16 fractional bits are far off (the study is not vacuous).
        assert!(
            errors[3].1.iter().any(|&v| v > 1.0),
            "{mode:?} {kind:?} Q16: {:?}",
            errors[3].1
        );
    }
}
