//! `visco diagnose` end to end: the report of `recording.md` §2 with its figures and series
//! on a recording with a concealed effect and on a clean one; refusals with one error line
//! naming the file, exit status 1, nothing written.

mod identify_support;
mod report_support;

use std::path::Path;

use identify_support::{listing, s, text, visco};
use serde_json::Value as Json;
use visco::experiment::concealed::scenario;
use visco::plant::effects::EffectKind;
use visco::report::at;

fn num(j: &Json, path: &str) -> f64 {
    at(j, path)
        .and_then(|v| v.as_f64())
        .unwrap_or_else(|| panic!("{path} missing or not a number"))
}

/// A force curve with adhesion concealed at a few times the noise: the report names it first,
/// with every field of the contract, and the files it lists exist.
#[test]
fn names_a_concealed_adhesion_with_the_contract_report_and_figures() {
    let dir = tempfile::tempdir().unwrap();
    let sc = scenario(Some(EffectKind::Adhesion), 3);
    let rec = dir.path().join("curve.csv");
    sc.recording.write(&rec).unwrap();
    let out = dir.path().join("out");
    let json = dir.path().join("report.json");
    let o = visco(&[
        "diagnose",
        s(&rec),
        "--json",
        s(&json),
        "--out",
        s(&out),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));
    let stdout = text(&o.stdout);
    assert!(stdout.contains("1. adhesion"), "{stdout}");
    let j = report_support::validate_file("diagnose", &json);
    assert_eq!(j.get("recording").and_then(|v| v.as_str()), Some(s(&rec)));
    assert!(j.get("nominal_model").and_then(|v| v.as_str()).is_some());
    let before = num(&j, "rms_before_m");
    let after = num(&j, "rms_after_m");
    assert!(after < before, "{after} < {before}");
    let left = j.get("left_out").and_then(|v| v.as_array()).unwrap();
    assert!(!left.is_empty());
    let first = &left[0];
    assert_eq!(
        first.get("effect").and_then(|v| v.as_str()),
        Some("adhesion")
    );
    let explanation = first.get("explanation").and_then(|v| v.as_str()).unwrap();
    assert!(
        explanation.contains("attractive force of") && explanation.contains("pN"),
        "{explanation}"
    );
    let spans = first.get("where").and_then(|v| v.as_array()).unwrap();
    assert!(!spans.is_empty());
    let phases: Vec<&str> = spans
        .iter()
        .map(|w| w.get("phase").and_then(|v| v.as_str()).unwrap())
        .collect();
    assert!(
        phases
            .iter()
            .all(|p| ["approach", "contact", "dwell", "retract", "free"].contains(p)),
        "{phases:?}"
    );
    for w in spans {
        assert!(num(w, "t_end_s") >= num(w, "t_start_s"));
    }
    // The fitted pull-off force is the concealed one within 15 %.
    let truth = match sc.spec {
        Some(visco::plant::effects::EffectSpec::Adhesion { force_n, .. }) => force_n,
        _ => unreachable!(),
    };
    let fitted = num(first, "parameters.pull_off_force_n");
    assert!((fitted / truth - 1.0).abs() < 0.15, "{fitted} vs {truth}");
    assert!(num(first, "rms_after_m") < num(first, "rms_before_m"));
    assert_eq!(
        at(first, "evidence.statistic").and_then(|v| v.as_str()),
        Some("held-out likelihood ratio")
    );
    assert!(num(first, "evidence.value") > 0.0);
    assert!(num(first, "evidence.p_value") < num(first, "evidence.level"));
    // The locate step's tests are there, corrected.
    let tests = at(&j, "locate.tests").and_then(|v| v.as_array()).unwrap();
    assert!(tests.len() >= 10);
    for f in j.get("figures").and_then(|v| v.as_array()).unwrap() {
        let p = f.as_str().unwrap();
        let bytes = std::fs::read(p).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{p} is a PNG");
    }
    assert!(listing(&out)
        .iter()
        .any(|f| f == "report_effect1_adhesion.png"));
    let series = std::fs::read_to_string(out.join("report_series.csv")).unwrap();
    assert_eq!(series.lines().count(), sc.recording.len() + 2);
}

/// A clean tap: nothing named, an empty `left_out`, the misfit at the noise.
#[test]
fn clean_tap_names_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let sc = scenario(None, 0);
    let rec = dir.path().join("tap.csv");
    sc.recording.write(&rec).unwrap();
    let json = dir.path().join("r.json");
    let o = visco(&[
        "diagnose",
        s(&rec),
        "--json",
        s(&json),
        "--quiet",
        "--no-figures",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let j = report_support::validate_file("diagnose", &json);
    assert_eq!(
        j.get("left_out")
            .and_then(|v| v.as_array())
            .map(|a| a.len()),
        Some(0)
    );
    let rms = num(&j, "rms_before_m");
    assert!(rms < 1.2 * sc.noise_m, "{rms} vs noise {}", sc.noise_m);
    assert_eq!(
        j.get("verdict").and_then(|v| v.as_str()),
        Some("the nominal model explains the recording to within its noise")
    );
    assert!(text(&o.stdout).contains("explains the recording to within its noise"));
    // The located tests may see misfits far below the noise on 10⁴ samples; none is material
    // (half the noise RMS) on a clean tap, and each says how large it is.
    let tests = j["locate"]["tests"].as_array().expect("locate.tests");
    assert!(tests.len() > 10, "{} tests", tests.len());
    for t in tests {
        let size = t["size_over_noise"].as_f64().expect("a finite size");
        assert!(size >= 0.0, "{t}");
        assert_eq!(t["material"], serde_json::Value::Bool(false), "{t}");
    }
}

/// One error line naming the file, exit status 1, nothing written.
fn refused(dir: &Path, args: &[&str], names: &str) -> String {
    let before = listing(dir);
    let o = visco(args);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stdout));
    let err = text(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with(&format!("error: {names}")), "{err}");
    assert_eq!(listing(dir), before, "nothing written");
    err
}

#[test]
fn refusals_name_the_file_and_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let json = d.join("r.json");
    // Missing recording.
    let missing = d.join("none.csv");
    refused(
        d,
        &["diagnose", s(&missing), "--json", s(&json)],
        s(&missing),
    );
    // Malformed: a non-numeric cell, with its line.
    let bad = d.join("bad.csv");
    std::fs::write(
        &bad,
        "# visco-recording: 1\n# mode: force-curve\n# sample_rate_hz: 1000\n\
         # cantilever_k_n_per_m: 0.1\n# tip_radius_m: 1e-6\nt_s,u_m,d_m\n0,0,0\n0.001,x,0\n",
    )
    .unwrap();
    let err = refused(d, &["diagnose", s(&bad), "--json", s(&json)], s(&bad));
    assert!(err.contains(":8:"), "{err}");
    // Too short to diagnose.
    let short = d.join("short.csv");
    let mut t = String::from(
        "# visco-recording: 1\n# mode: force-curve\n# sample_rate_hz: 1000\n\
         # cantilever_k_n_per_m: 0.1\n# tip_radius_m: 1e-6\nt_s,u_m,d_m\n",
    );
    for i in 0..20 {
        t.push_str(&format!("{},{},0\n", i as f64 * 1e-3, -(i as f64) * 1e-9));
    }
    std::fs::write(&short, t).unwrap();
    let err = refused(d, &["diagnose", s(&short), "--json", s(&json)], s(&short));
    assert!(err.contains("64 samples"), "{err}");
    // An SVE scan: refused with the reason.
    let sve = d.join("sve.csv");
    let mut t = String::from(
        "# visco-recording: 1\n# mode: sve\n# sample_rate_hz: 1000\n\
         # cantilever_k_n_per_m: 0.1\n# tip_radius_m: 1e-6\nt_s,u_m,d_m,x_m,y_m\n",
    );
    for i in 0..100 {
        t.push_str(&format!("{},0,0,{},0\n", i as f64 * 1e-3, i as f64 * 1e-9));
    }
    std::fs::write(&sve, t).unwrap();
    let err = refused(d, &["diagnose", s(&sve), "--json", s(&json)], s(&sve));
    assert!(err.contains("SVE"), "{err}");
    // The report's directory must exist.
    let sc = scenario(None, 3);
    let rec = d.join("ok.csv");
    sc.recording.write(&rec).unwrap();
    let nowhere = d.join("no/such/r.json");
    let err = refused(
        d,
        &["diagnose", s(&rec), "--json", s(&nowhere)],
        s(&nowhere),
    );
    assert!(err.contains("does not exist"), "{err}");
    // Bad options are usage errors (status 2).
    let o = visco(&["diagnose", s(&rec), "--json", s(&json), "--alpha", "2"]);
    assert_eq!(o.status.code(), Some(2));
    let o = visco(&[
        "diagnose",
        s(&rec),
        "--json",
        s(&json),
        "--effects",
        "gravity",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("not an effect"));
}
