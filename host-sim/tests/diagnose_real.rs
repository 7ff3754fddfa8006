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
mod report_support;

use identify_support::pins::Pins;
use identify_support::{real, real_import_options, CC, MAP, NTMDT, SPOT3, SR, WORKSHOP};
use serde_json::Value as Json;
use visco::diagnose::{diagnose, Options};
use visco::plant::effects::EffectKind;
use visco::recording::import::import_all;
use visco::recording::Recording;
use visco::report::at;

// ------------------------------------------------------------------ what README.md quotes

/// The table of README.md's "Real recordings" section, figure for figure as quoted: per file
/// and curve, the held-out RMS nominal → extended (nm), and every finding in the order named,
/// with its quoted parameters (report key, SI per quoted unit, figure), its held-out RMS where
/// it acts and, for relaxation, in the hold (nm). A re-measure (a change of `diagnose`)
/// changes these figures and README.md, nothing else: the tolerances follow from the noise
/// (`se_*` below) and the quoted digits (`pins`).
#[rustfmt::skip]
const QUOTED: &[Quoted] = &[
    Quoted { file: SR, curve: 0, rms: ("33.3", "9.9"), findings: &[
        Finding { effect: "stress-relaxation", params: &[("arm1_relaxation_time_s", 1.0, "4.7"), ("arm1_stiffness_ratio", 1.0, "1.24")], rms: ("44.7", "14.7"), hold: Some(("57.2", "13.5")) },
        Finding { effect: "nonlinear-stiffness", params: &[("shallow_force_depth_exponent", 1.0, "3.0")], rms: ("9.4", "7.7"), hold: None },
    ] },
    Quoted { file: CC, curve: 0, rms: ("29.6", "11.7"), findings: &[
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-9, "6.5"), ("reach_m", 1e-6, "3.7"), ("on_unloading_only", 1.0, "1")], rms: ("108", "38"), hold: None },
        Finding { effect: "stress-relaxation", params: &[("arm1_relaxation_time_s", 1.0, "0.65"), ("arm1_stiffness_ratio", 1.0, "0.15")], rms: ("14.0", "12.9"), hold: Some(("6.85", "1.27")) },
    ] },
    Quoted { file: SPOT3, curve: 0, rms: ("1.42", "0.92"), findings: &[
        Finding { effect: "plastic-deformation", params: &[("plastic_fraction", 0.01, "24")], rms: ("2.12", "1.90"), hold: None },
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-12, "93"), ("on_unloading_only", 1.0, "1")], rms: ("1.61", "1.21"), hold: None },
    ] },
    Quoted { file: MAP, curve: 0, rms: ("2.47", "1.91"), findings: &[
        Finding { effect: "plastic-deformation", params: &[("plastic_fraction", 0.01, "43")], rms: ("5.97", "5.01"), hold: None },
        Finding { effect: "thermal-drift", params: &[("rate_m_per_s", 1e-9, "0.42")], rms: ("2.49", "2.03"), hold: None },
        Finding { effect: "surface-attraction", params: &[("force_at_contact_n", 1e-12, "63"), ("decay_length_m", 1e-9, "344")], rms: ("7.04", "6.85"), hold: None },
    ] },
    Quoted { file: MAP, curve: 1, rms: ("2.06", "1.41"), findings: &[
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-12, "53"), ("on_unloading_only", 1.0, "1")], rms: ("3.70", "2.13"), hold: None },
        Finding { effect: "plastic-deformation", params: &[("plastic_fraction", 0.01, "31")], rms: ("3.14", "2.52"), hold: None },
        Finding { effect: "thermal-drift", params: &[("rate_m_per_s", 1e-9, "0.33")], rms: ("1.88", "1.45"), hold: None },
    ] },
    Quoted { file: MAP, curve: 2, rms: ("3.63", "1.59"), findings: &[
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-12, "81"), ("on_unloading_only", 1.0, "1")], rms: ("3.68", "1.84"), hold: None },
        Finding { effect: "thermal-drift", params: &[("rate_m_per_s", 1e-9, "−5.3")], rms: ("2.25", "1.65"), hold: None },
    ] },
    Quoted { file: MAP, curve: 3, rms: ("3.60", "1.96"), findings: &[
        Finding { effect: "hydrodynamic-drag", params: &[("drag_ns_per_m", 1e-6, "6.6")], rms: ("3.63", "2.58"), hold: None },
        Finding { effect: "thermal-drift", params: &[("rate_m_per_s", 1e-9, "−1.2")], rms: ("2.70", "2.42"), hold: None },
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-12, "64"), ("reach_m", 1e-6, "0.70"), ("on_unloading_only", 1.0, "1")], rms: ("8.3", "6.3"), hold: None },
    ] },
    Quoted { file: WORKSHOP, curve: 0, rms: ("0.031", "0.015"), findings: &[
        Finding { effect: "nonlinear-stiffness", params: &[("shallow_force_depth_exponent", 1.0, "1.00")], rms: ("0.0086", "0.0023"), hold: None },
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-12, "5.5"), ("reach_m", 1e-6, "0.25"), ("on_unloading_only", 1.0, "0")], rms: ("0.043", "0.022"), hold: None },
    ] },
    Quoted { file: NTMDT, curve: 0, rms: ("8.14", "3.97"), findings: &[
        Finding { effect: "adhesion", params: &[("pull_off_force_n", 1e-9, "2.1"), ("reach_m", 1e-6, "0.45"), ("on_unloading_only", 1.0, "1")], rms: ("18.4", "6.2"), hold: None },
    ] },
];

struct Quoted {
    file: &'static str,
    curve: usize,
    rms: (&'static str, &'static str),
    findings: &'static [Finding],
}

struct Finding {
    effect: &'static str,
    params: &'static [(&'static str, f64, &'static str)],
    rms: (&'static str, &'static str),
    hold: Option<(&'static str, &'static str)>,
}

/// The held-out samples a residual RMS over `n` samples is worth: fewer when the noise is
/// correlated, by the report's AR noise model (innovation σ over the residual's σ, squared).
fn effective(j: &Json, n: f64) -> f64 {
    let innov = num(j, "nominal.noise.innovation_sigma_m");
    let resid = num(j, "nominal.noise.residual_sigma_m");
    (n * (innov / resid).powi(2)).max(1.0)
}

/// Standard error of an RMS over `n` held-out samples with noise σ: the RMS of misfit + noise
/// moves by at most σ/√n_eff.
fn se_rms(j: &Json, sigma: f64, n: f64) -> f64 {
    sigma / effective(j, n).sqrt()
}

/// Relative standard error of a finding's parameters: for an amplitude solved by least
/// squares, σ/‖g‖ over the held-out samples where it acts, with ‖g‖ the misfit it removes
/// there, √n_eff·√(rms_before² − rms_after²). Used for its shape parameters too, as the
/// information the finding carries (an approximation: their own sensitivity is not reported).
fn se_relative(j: &Json, f: &Json) -> f64 {
    let (b, a) = (num(f, "rms_before_m"), num(f, "rms_after_m"));
    let n = effective(j, num(f, "evidence.held_out_samples"));
    num(f, "evidence.noise_rms_m") / (n.sqrt() * (b * b - a * a).max(0.0).sqrt())
}

/// Compares one report with what README.md quotes for it.
fn pin_quoted(name: &str, curve: usize, j: &Json) {
    let q = QUOTED
        .iter()
        .find(|q| q.file == name && q.curve == curve)
        .unwrap_or_else(|| panic!("{name} curve {curve} is not in the README's table"));
    let label = format!("{name} curve {curve}");
    let mut p = Pins::default();
    let nm = 1e-9;
    let n_all = num(j, "held_out.held_out_samples");
    let se_all = se_rms(j, num(j, "nominal.noise.residual_sigma_m"), n_all) / nm;
    p.check(
        "held-out RMS nominal (nm)",
        q.rms.0,
        num(j, "rms_before_m") / nm,
        se_all,
    );
    p.check(
        "held-out RMS extended (nm)",
        q.rms.1,
        num(j, "rms_after_m") / nm,
        se_all,
    );
    let named = effects(j);
    let quoted: Vec<&str> = q.findings.iter().map(|f| f.effect).collect();
    p.equal("findings, in order", &quoted.join(", "), &named.join(", "));
    for (qf, f) in q
        .findings
        .iter()
        .zip(j.get("left_out").and_then(|v| v.as_array()).unwrap())
    {
        if f.get("effect").and_then(|v| v.as_str()) != Some(qf.effect) {
            continue;
        }
        let sigma = num(f, "evidence.noise_rms_m");
        let se_where = se_rms(j, sigma, num(f, "evidence.held_out_samples")) / nm;
        let what = |x: &str| format!("{}: {x}", qf.effect);
        p.check(
            &what("RMS where it acts, before (nm)"),
            qf.rms.0,
            num(f, "rms_before_m") / nm,
            se_where,
        );
        p.check(
            &what("RMS where it acts, after (nm)"),
            qf.rms.1,
            num(f, "rms_after_m") / nm,
            se_where,
        );
        let rel = se_relative(j, f);
        for (key, unit, fig) in qf.params {
            let v = num(f, &format!("parameters.{key}"));
            if *key == "on_unloading_only" {
                p.equal(&what(key), fig, &format!("{v}"));
            } else {
                p.check(&what(key), fig, v / unit, rel * (v / unit).abs());
            }
        }
        if let Some((hb, ha)) = qf.hold {
            let (b, a) = phase_rms(f, "dwell");
            let n_dwell = at(j, "locate.phases")
                .and_then(|v| v.as_array())
                .unwrap()
                .iter()
                .find(|p| p.get("phase").and_then(|v| v.as_str()) == Some("dwell"))
                .map_or(f64::NAN, |p| num(p, "held_out_samples"));
            let se = se_rms(j, sigma, n_dwell) / nm;
            p.check(&what("RMS in the hold, before (nm)"), hb, b / nm, se);
            p.check(&what("RMS in the hold, after (nm)"), ha, a / nm, se);
        }
    }
    p.finish(&label);
}

/// Imports every curve of `name`, diagnoses each; (curve, report JSON, summary).
fn diagnose_file(name: &str) -> Vec<(usize, Json, String)> {
    let all = import_all(&real(name), &real_import_options(name)).unwrap_or_else(|e| panic!("{e}"));
    all.into_iter()
        .map(|(curve, rec)| {
            let (j, summary) = diagnose_recording(&format!("{name} curve {curve}"), &rec);
            (curve, j, summary)
        })
        .collect()
}

/// Writes `rec`, diagnoses it and checks the report's files: (report, summary).
fn diagnose_recording(what: &str, rec: &Recording) -> (Json, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("curve.csv");
    rec.write(&path).unwrap();
    let json = dir.path().join("curve.json");
    let d = diagnose(&path, &Options::new(&json)).unwrap_or_else(|e| panic!("{e}"));
    let j = report_support::validate_file("diagnose", &json);
    // Every figure listed was written.
    for f in j.get("figures").and_then(|v| v.as_array()).unwrap() {
        assert!(std::path::Path::new(f.as_str().unwrap()).is_file());
    }
    let summary = d.summary();
    println!("{what}: {summary}");
    (j, summary)
}

fn num(j: &Json, path: &str) -> f64 {
    at(j, path).and_then(|v| v.as_f64()).unwrap_or(f64::NAN)
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
    pin_quoted(name, 0, j);
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
    // Who relaxed: at constant height the force fell (by ~0.11 µN; a lagging scanner would
    // have kept pressing, the force rising).
    assert_eq!(
        at(&j, "hold.kind").and_then(|v| v.as_str()),
        Some("constant height")
    );
    let df = num(&j, "hold.force_change_n");
    assert!(df < -50e-9, "force change {df:e}: {summary}");
}

#[test]
fn creep_recording_relaxes_beyond_kelvin_voigt() {
    let (j, sr, summary) = relaxation_named(CC);
    // The hold at constant force: a Kelvin–Voigt bed creeps with one time constant, fixed by
    // the approach; the misfit left there is cut at least 2×.
    let (b, a) = phase_rms(&sr, "dwell");
    assert!(b / a >= 2.0, "the hold: {b} → {a}: {summary}");
    // Who crept: under the force loop the base sank 0.11 µm further into the gel (a lagging
    // scanner would have drawn the command back), far beyond the levels' noise (~nm).
    assert_eq!(
        at(&j, "hold.kind").and_then(|v| v.as_str()),
        Some("constant force")
    );
    let sank = num(&j, "hold.base_towards_sample_m");
    assert!(sank > 50e-9, "base travel {sank:e}: {summary}");
    // The retract's tether ruptures: adhesion that pulls once the contact unloads.
    let adhesion = finding(&j, "adhesion", &summary);
    assert_eq!(num(&adhesion, "parameters.on_unloading_only"), 1.0);
}

#[test]
fn force_distance_curves_report_what_they_find() {
    for name in [SPOT3, MAP, WORKSHOP, NTMDT] {
        for (curve, j, summary) in diagnose_file(name) {
            check_report(&format!("{name} curve {curve}"), &j);
            pin_quoted(name, curve, &j);
            if name == NTMDT {
                assert!(effects(&j).iter().any(|e| e == "adhesion"), "{summary}");
            }
        }
    }
}

/// AFM Workshop's free approach carries an optical-interference wave (the laser spilling onto
/// the sample): the nominal model takes it as part of its baseline, and a stronger one (twice
/// its own, 13× the noise left, at the same period: the same laser) changes neither what is
/// named nor the held-out RMS beyond its noise. (A wave of 36× the noise, 15 % of the
/// deflection range, is estimated on the free part to ~2.5 % of its amplitude, ~1σ, which
/// drops the marginal adhesion, z = 3.3, from the findings.)
#[test]
fn an_interference_wave_is_part_of_the_baseline() {
    let all = import_all(&real(WORKSHOP), &real_import_options(WORKSHOP)).unwrap();
    let rec = &all[0].1;
    let (j0, s0) = diagnose_recording("AFM Workshop", rec);
    // The file's own wave: amplitude and period resolved over the free approach's ~790 rows
    // at σ ≈ 1.3 pm to SE σ·√(2/n) ≈ 0.07 pm and ~0.1 %; pinned to ±0.3 pm and ±1 %.
    let (a, p) = (
        num(&j0, "nominal.baseline_wave.amplitude_m"),
        num(&j0, "nominal.baseline_wave.period_m"),
    );
    assert!((a - 8.6e-12).abs() < 0.3e-12, "amplitude {a:e}: {s0}");
    assert!((p / 0.319e-6 - 1.0).abs() < 0.01, "period {p:e}: {s0}");
    let mut wavy = rec.clone();
    let tau = std::f64::consts::TAU;
    // At the lever's height U − D (the deflection from the free level: ≤ 0.2 nm here).
    let free = rec.d_m[0];
    for (d, &u) in wavy.d_m.iter_mut().zip(&rec.u_m) {
        *d += 2.0 * a * (tau * (u - (*d - free)) / p + 1.0).sin();
    }
    let (j1, s1) = diagnose_recording("AFM Workshop with a stronger wave", &wavy);
    assert_eq!(effects(&j1), effects(&j0), "{s0}\n{s1}");
    for key in ["rms_before_m", "rms_after_m"] {
        let (b, w) = (num(&j0, key), num(&j1, key));
        // An RMS over ~1200 held-out samples moves by its SE, ~σ/√n_eff (pin_quoted's se_rms);
        // 10 % is several of those at these levels.
        assert!((w / b - 1.0).abs() < 0.1, "{key}: {b:e} → {w:e}");
    }
}
