//! `diagnose` on the real recordings of `shared/data/real/`, end to end (import, diagnose,
//! report, figures).
//!
//! The stress-relaxation recording (a cell held at constant height for 30 s) and the creep
//! recording (a gel held at constant force) relax in ways a Kelvin–Voigt element cannot: the
//! diagnosis must name stress relaxation, and the extension must cut the misfit at least 2×
//! — where it acts and over the whole held-out half for the relaxation recording, where it
//! is named first; in the hold for the creep recording, whose retract is dominated by tether
//! ruptures (named first, as adhesion on unloading). On the force–distance curves it reports
//! what it finds, with a valid report whose every finding improves the held-out fit where it
//! acts; on the NT-MDT gel curve (recorded for its adhesion) it names adhesion.
//!
//! Values the files lack, supplied as a user would (as `identify_real`): tip radius 5 µm;
//! AFM Workshop and NT-MDT 0.1 N/m at 1 kHz, NT-MDT 50 nm/nA.

mod identify_support;

use identify_support::{real, real_import_options, CC, MAP, NTMDT, SPOT3, SR, WORKSHOP};
use visco::diagnose::{diagnose, Options};
use visco::identify::Json;
use visco::plant::effects::EffectKind;
use visco::recording::import::import_all;

/// Imports every curve of `name`, diagnoses each; (curve, report JSON, summary).
fn diagnose_file(name: &str) -> Vec<(usize, Json, String)> {
    let all = import_all(&real(name), &real_import_options(name)).unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    all.into_iter()
        .map(|(curve, rec)| {
            let path = dir.path().join(format!("curve{curve}.csv"));
            rec.write(&path).unwrap();
            let json = dir.path().join(format!("curve{curve}.json"));
            let d = diagnose(&path, &Options::new(&json)).unwrap_or_else(|e| panic!("{e}"));
            let j = Json::parse(&std::fs::read_to_string(&json).unwrap()).unwrap();
            // Every figure listed was written.
            for f in j.get("figures").and_then(|v| v.as_array()).unwrap() {
                assert!(std::path::Path::new(f.as_str().unwrap()).is_file());
            }
            let summary = d.summary();
            println!("{name} curve {curve}: {summary}");
            (curve, j, summary)
        })
        .collect()
}

fn num(j: &Json, path: &str) -> f64 {
    j.at(path).and_then(|v| v.as_f64()).unwrap_or(f64::NAN)
}

fn effects(j: &Json) -> Vec<String> {
    j.get("left_out")
        .and_then(|v| v.as_array())
        .unwrap()
        .iter()
        .map(|e| {
            e.get("effect")
                .and_then(|v| v.as_str())
                .unwrap()
                .to_string()
        })
        .collect()
}

/// Every finding improves the held-out fit where it acts, and the whole fit never worsens.
fn check_report(name: &str, j: &Json) {
    let before = num(j, "rms_before_m");
    let after = num(j, "rms_after_m");
    assert!(after <= before * 1.0001, "{name}: {after} > {before}");
    for e in j.get("left_out").and_then(|v| v.as_array()).unwrap() {
        let kind = e.get("effect").and_then(|v| v.as_str()).unwrap();
        assert!(EffectKind::parse(kind).is_some(), "{kind}");
        let (b, a) = (num(e, "rms_before_m"), num(e, "rms_after_m"));
        assert!(
            a < b,
            "{name}: {kind} does not improve where it acts: {b} → {a}"
        );
        assert!(e
            .get("explanation")
            .and_then(|v| v.as_str())
            .is_some_and(|s| s.len() > 40));
        assert!(num(e, "evidence.p_value") < num(e, "evidence.level"));
    }
}

/// The finding of effect `kind` in report `j`.
fn finding(j: &Json, kind: &str, summary: &str) -> Json {
    j.get("left_out")
        .and_then(|v| v.as_array())
        .unwrap()
        .iter()
        .find(|e| e.get("effect").and_then(|v| v.as_str()) == Some(kind))
        .unwrap_or_else(|| panic!("{kind} not named: {summary}"))
        .clone()
}

/// The report of a held-stress recording and its stress-relaxation finding.
fn relaxation_named(name: &str) -> (Json, Json, String) {
    let r = diagnose_file(name);
    let (_, j, summary) = &r[0];
    check_report(name, j);
    let sr = finding(j, "stress-relaxation", &format!("{name}: {summary}"));
    (j.clone(), sr, summary.clone())
}

/// Held-out RMS before and after a finding in one phase.
fn phase_rms(finding: &Json, phase: &str) -> (f64, f64) {
    let p = finding
        .get("phases")
        .and_then(|v| v.as_array())
        .unwrap()
        .iter()
        .find(|p| p.get("phase").and_then(|v| v.as_str()) == Some(phase))
        .unwrap_or_else(|| panic!("no {phase} in {finding:?}"));
    (num(p, "rms_before_m"), num(p, "rms_after_m"))
}

#[test]
fn stress_relaxation_recording_relaxes_beyond_kelvin_voigt() {
    let (j, sr, summary) = relaxation_named(SR);
    assert_eq!(effects(&j)[0], "stress-relaxation", "{summary}");
    let cut = num(&sr, "rms_before_m") / num(&sr, "rms_after_m");
    assert!(cut >= 2.0, "cut where it acts {cut}: {summary}");
    let whole = num(&j, "rms_before_m") / num(&j, "rms_after_m");
    assert!(whole >= 2.0, "whole held-out cut {whole}: {summary}");
    let (b, a) = phase_rms(&sr, "dwell");
    assert!(b / a >= 2.0, "the hold: {b} → {a}");
    // A relaxation time of seconds: the 30 s hold shows it whole.
    let tau = num(&sr, "parameters.arm1_relaxation_time_s");
    assert!(tau > 0.5 && tau < 30.0, "τ = {tau}");
}

#[test]
fn creep_recording_relaxes_beyond_kelvin_voigt() {
    let (j, sr, summary) = relaxation_named(CC);
    // The hold at constant force: a Kelvin–Voigt bed creeps with one time constant, fixed by
    // the approach; the misfit left there is cut at least 2×.
    let (b, a) = phase_rms(&sr, "dwell");
    assert!(b / a >= 2.0, "the hold: {b} → {a}: {summary}");
    // The retract's tether ruptures: adhesion that pulls once the contact unloads.
    let adhesion = finding(&j, "adhesion", &summary);
    assert_eq!(num(&adhesion, "parameters.on_unloading_only"), 1.0);
}

#[test]
fn force_distance_curves_report_what_they_find() {
    for name in [SPOT3, MAP, WORKSHOP, NTMDT] {
        for (curve, j, summary) in diagnose_file(name) {
            check_report(&format!("{name} curve {curve}"), &j);
            if name == NTMDT {
                assert!(effects(&j).iter().any(|e| e == "adhesion"), "{summary}");
            }
        }
    }
}
