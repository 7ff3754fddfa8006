//! The published JSON Schemas (`host-sim/schemas/`) are the ones the report structs derive,
//! and the reports no other test writes (concealed, faults, sweep) validate against theirs.
//! The identify, diagnose and demo reports are validated where their tests write them.

mod report_support;

use report_support::{committed_schema, validate};
use visco::experiment::concealed::{ConcealedReport, SuiteReport, SuiteRow};
use visco::experiment::faults::{run_fault, FaultClass, FaultsReport};
use visco::experiment::sweep::{SweepPoint, SweepReport};
use visco::plant::effects::EffectKind;
use visco::report::{schema, REPORTS};

#[test]
fn committed_schemas_are_the_generated_ones() {
    let mut stale = Vec::new();
    for (name, _) in REPORTS {
        let generated = schema(name).unwrap_or_else(|| panic!("no schema for {name}"));
        if committed_schema(name) != generated {
            stale.push(*name);
        }
    }
    assert!(
        stale.is_empty(),
        "host-sim/schemas/ is stale for {stale:?}: run `cargo run -p visco -- schema --write \
         host-sim/schemas` and commit"
    );
}

#[test]
fn every_schema_requires_its_version() {
    for (name, _) in REPORTS {
        let s: serde_json::Value = serde_json::from_str(&committed_schema(name)).unwrap();
        let required = s["required"].as_array().unwrap_or_else(|| panic!("{name}"));
        assert!(
            required.iter().any(|r| r == "schema_version"),
            "{name}: schema_version not required"
        );
    }
}

fn row(effect: Option<EffectKind>, named: Vec<EffectKind>, error: Option<String>) -> SuiteRow {
    SuiteRow {
        effect,
        seed: 3,
        setup: "dive".into(),
        ratio: 4.2,
        noise_m: 1e-10,
        named,
        rms_before_m: 3e-10,
        rms_after_m: 1e-10,
        // Not computable for a refused recording: written null.
        truth_error_before_m: if error.is_some() { f64::NAN } else { 2e-10 },
        truth_error_after_m: if error.is_some() { f64::NAN } else { 5e-11 },
        effect_rms_m: if error.is_some() { f64::NAN } else { 8e-10 },
        held_out_samples: if error.is_some() { 0 } else { 900 },
        span_rms_before_m: f64::NAN,
        span_rms_after_m: f64::NAN,
        wall_s: 1.5,
        error,
    }
}

/// The concealed report in each of its three layouts (plant, independent, both), with a clean
/// row, a right one and a refused one (nulls where nothing could be computed).
#[test]
fn the_concealed_report_matches_its_schema() {
    let suite = SuiteReport {
        rows: vec![
            row(None, vec![], None),
            row(Some(EffectKind::Adhesion), vec![EffectKind::Adhesion], None),
            row(
                Some(EffectKind::ThermalDrift),
                vec![],
                Some("too short".into()),
            ),
        ],
        seeds: 1,
        alpha: 0.01,
    };
    let mut indep = suite.to_json();
    indep.recordings_dir = Some("refsim/out".into());
    let layouts = [
        (Some(suite.to_json()), None, None),
        (None, None, Some(indep.clone())),
        (None, Some(suite.to_json()), Some(indep)),
    ];
    for (top, plant, independent) in layouts {
        let r = ConcealedReport {
            schema_version: visco::experiment::concealed::SCHEMA_VERSION,
            suite: top,
            plant,
            independent,
        };
        let v = serde_json::to_value(&r).unwrap();
        validate("concealed", &v);
        // The typed report reads back what it wrote (null as NaN).
        let back: ConcealedReport = serde_json::from_value(v.clone()).unwrap();
        assert_eq!(serde_json::to_value(&back).unwrap(), v);
    }
}

/// The summary's hidden-misfit share (issue 13's goal) counts the effect recordings named right
/// first, and of those the ones whose misfit against the truth was cut ≥ 2×: not the clean
/// ones (nothing to cut), not the misnamed ones.
#[test]
fn the_hidden_misfit_share_counts_only_effects_named_right_first() {
    let mut weak = row(Some(EffectKind::Adhesion), vec![EffectKind::Adhesion], None);
    weak.truth_error_after_m = 1.5e-10; // cut 2e-10 / 1.5e-10 = 1.33×
    let suite = SuiteReport {
        rows: vec![
            row(None, vec![], None),
            row(Some(EffectKind::Adhesion), vec![EffectKind::Adhesion], None), // cut 4×
            weak,
            row(
                Some(EffectKind::ThermalDrift),
                vec![EffectKind::Adhesion],
                None,
            ),
        ],
        seeds: 1,
        alpha: 0.01,
    };
    assert_eq!(suite.hidden_misfit_cut_at_least_2(), (1, 2));
    let j = suite.to_json();
    assert_eq!(j.hidden_misfit_cut_at_least_2.cut_at_least_2, 1);
    assert_eq!(j.hidden_misfit_cut_at_least_2.named_right_first, 2);
}

/// A real fault run (the force limit: the shortest class) as `visco faults --json` writes it.
#[test]
fn the_faults_report_matches_its_schema() {
    let r = FaultsReport {
        schema_version: visco::experiment::faults::SCHEMA_VERSION,
        runs: vec![run_fault(FaultClass::ForceLimit, 500e3, 1)],
    };
    validate("faults", &serde_json::to_value(&r).unwrap());
}

/// The sweep report's shape, with a point whose errors could not be computed (null).
#[test]
fn the_sweep_report_matches_its_schema() {
    let p = SweepPoint {
        period_s: 0.02,
        pixels_per_s: 2500.0,
        rms_error_pct: [1.0, 2.0, f64::NAN],
        max_error_pct: [3.0, 4.0, 5.0],
        max_error_not_steep_pct: [1.0, 1.5, 2.0],
        paper_rms_error_pct: [1.0, 2.0, 3.0],
        worst_rms_pct: f64::NAN,
        failed: 0,
        simulated_s: 1.0,
        block_samples: 16,
    };
    let r = SweepReport {
        schema_version: visco::experiment::sweep::SCHEMA_VERSION,
        sve: vec![p.clone()],
        dive: vec![],
        sve_fastest_meeting_goal: Some(p),
        dive_fastest_meeting_goal: None,
        excitation: vec![],
        notes: vec!["a note".into()],
    };
    validate("sweep", &serde_json::to_value(&r).unwrap());
}

/// A report missing a required field, or with a string where a number goes, is refused: the
/// schemas are not vacuous.
#[test]
fn the_schemas_refuse_a_broken_report() {
    let r = FaultsReport {
        schema_version: visco::experiment::faults::SCHEMA_VERSION,
        runs: vec![run_fault(FaultClass::ForceLimit, 500e3, 1)],
    };
    let good = serde_json::to_value(&r).unwrap();
    let s: serde_json::Value = serde_json::from_str(&committed_schema("faults")).unwrap();
    let v = jsonschema::validator_for(&s).unwrap();
    assert!(v.is_valid(&good));
    let mut missing = good.clone();
    missing.as_object_mut().unwrap().remove("schema_version");
    assert!(!v.is_valid(&missing));
    let mut wrong = good;
    wrong["runs"][0]["max_force_n"] = "large".into();
    assert!(!v.is_valid(&wrong));
}
