//! The concealed-effect suite, reduced: three recordings per effect and three clean ones,
//! over all six setups (`ci_jobs`: tap-liquid and curve-soft included), each effect at
//! 3–10× the noise RMS (the full suite, 20 seeds per
//! class, is `cargo run --release -- concealed --seeds 20`; its figures are in the README).
//!
//! Asserted: nothing is named on the clean recordings; the top-1 name is right on at least
//! 26 of the 30 with an effect (these seeds give 27 since issue 13's fitted initial state
//! and calibrations — 28 before: two small plastic deformations are absorbed by the nominal
//! fit, and now a second eigenmode at 5.3× the noise on tap-air seed 3 too);
//! where it is right, the model's systematic misfit against the noise-free truth is cut at
//! least 2× (median over the effects), and the extended model never fits the held-out data
//! worse than the nominal one.

use visco::diagnose::search::SearchOptions;
use visco::experiment::concealed::{ci_jobs, run_jobs, setup_of, setups, SuiteReport};

fn suite() -> SuiteReport {
    let opts = SearchOptions::default();
    let jobs = ci_jobs();
    // Every setup is met, by the clean recordings and by the effects.
    for s in setups() {
        assert!(
            jobs.iter().any(|&(e, seed)| setup_of(e, seed) == s.name),
            "the CI subset never runs {}",
            s.name
        );
    }
    run_jobs(&jobs, 2, &opts, &|_, _, _| {})
}

#[test]
fn concealed_effects_are_named_and_clean_recordings_are_not() {
    let report = suite();
    let mut lines = Vec::new();
    for r in &report.rows {
        lines.push(format!(
            "{:<20} seed {} {:<14} {:>5.1}× noise: named {:?}{}, truth misfit {:.3e} → {:.3e} m",
            r.effect.map_or("clean", |k| k.as_str()),
            r.seed,
            r.setup,
            r.ratio,
            r.named.iter().map(|k| k.as_str()).collect::<Vec<_>>(),
            if r.extra_wrong() {
                " (extra wrong)"
            } else {
                ""
            },
            r.truth_error_before_m,
            r.truth_error_after_m
        ));
    }
    let table = lines.join("\n");
    println!(
        "{table}\n{}\n{}",
        report.confusion_markdown(),
        report.per_class_markdown()
    );
    // The per-class counts add up to the rows.
    let per = report.per_class();
    assert_eq!(
        per.iter().map(|c| c.recordings).sum::<usize>(),
        report.rows.len()
    );
    for c in &per {
        if c.class.is_some() {
            // Right first: either exactly right or with an extra wrong finding.
            assert_eq!(c.exact + c.extra_wrong, c.top1_right, "{c:?}");
        } else {
            assert_eq!(c.extra_wrong, 0);
            assert_eq!(c.top1_right + c.any_wrong, c.recordings, "{c:?}");
        }
    }
    let clean: Vec<_> = report.rows.iter().filter(|r| r.effect.is_none()).collect();
    assert_eq!(clean.len(), 3);
    for r in &clean {
        assert!(
            r.named.is_empty(),
            "false alarm on clean seed {}:\n{table}",
            r.seed
        );
    }
    let with: Vec<_> = report.rows.iter().filter(|r| r.effect.is_some()).collect();
    assert_eq!(with.len(), 30);
    for r in &with {
        // Generated at the stated magnitude.
        assert!(
            r.ratio > 2.9 && r.ratio < 10.3,
            "magnitude {} off 3–10 for {:?} seed {}",
            r.ratio,
            r.effect,
            r.seed
        );
        assert!(r.rms_after_m <= r.rms_before_m * 1.0001, "{table}");
    }
    let right = with.iter().filter(|r| r.correct()).count();
    assert!(right >= 26, "top-1 right on {right}/30:\n{table}");
    let mut cuts: Vec<f64> = with
        .iter()
        .filter(|r| r.correct())
        .map(|r| r.truth_error_before_m / r.truth_error_after_m)
        .collect();
    cuts.sort_by(f64::total_cmp);
    let median = cuts[cuts.len() / 2];
    assert!(
        median >= 2.0,
        "median cut of the hidden misfit {median}:\n{table}"
    );
}
