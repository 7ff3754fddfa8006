//! `visco identify` end to end: the command on real files, and malformed inputs refused with
//! one error line naming the file (and line), exit status 1 and nothing written.

mod identify_support;
mod report_support;

use std::path::Path;
use std::process::{Command, Output};

use identify_support::real;
use serde_json::Value as Json;
use visco::identify::{identify, Options};
use visco::recording::{Metadata, Mode, Recording};
use visco::report::at;

fn visco(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_visco"))
        .args(args)
        .output()
        .expect("run visco")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    v.sort();
    v
}

/// Runs identify on `rec` written to a fresh directory; asserts the one-line error and that
/// only the recording is left; returns the error line.
fn refused(rec_text: &str, name: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, rec_text).unwrap();
    let json = dir.path().join("r.json");
    let o = visco(&["identify", s(&path), "--json", s(&json)]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stdout));
    let err = text(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with(&format!("error: {}", path.display())),
        "the error names the file: {err}"
    );
    assert_eq!(
        listing(dir.path()),
        vec![name.to_string()],
        "nothing written"
    );
    err
}

/// A synthetic force curve: approach from 2 µm above a bed at 0 to 300 nm in, and back, on a
/// lever of 0.1 N/m; `force` gives the repulsive force at depth δ.
fn curve(segments: &str, force: impl Fn(f64) -> f64) -> Recording {
    let mut meta = Metadata::new(Mode::ForceCurve, 1000.0, 0.1, 5e-6);
    meta.set("segments", segments);
    let mut rec = Recording::new(meta);
    rec.extra.push(visco::recording::Column {
        name: "segment".into(),
        values: Vec::new(),
    });
    let n = 1000;
    for i in 0..2 * n {
        let (u, seg) = if i < n {
            (2e-6 - 2.3e-6 * i as f64 / (n - 1) as f64, 0.0)
        } else {
            (-0.3e-6 + 2.3e-6 * (i - n) as f64 / (n - 1) as f64, 1.0)
        };
        // Quasi-static: K·D = −F(δ), δ = −Z = −(U − D); solved by fixed point.
        let mut d = 0.0f64;
        for _ in 0..200 {
            d = -force((-(u - d)).max(0.0)) / 0.1;
        }
        let noise = 1e-11 * ((i * 7919 % 1000) as f64 / 1000.0 - 0.5);
        rec.t_s.push(i as f64 / 1000.0);
        rec.u_m.push(u);
        rec.d_m.push(d + noise);
        rec.extra[0].values.push(seg);
    }
    rec
}

fn recording_text(rec: &Recording) -> String {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.csv");
    rec.write(&p).unwrap();
    std::fs::read_to_string(p).unwrap()
}

#[test]
fn identifies_an_imported_jpk_curve_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("spot3.csv");
    let o = visco(&[
        "import",
        s(&real("fmt-jpk-fd_spot3-0192.jpk-force")),
        "--out",
        s(&rec),
        "--tip-radius",
        "5e-6",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let json = dir.path().join("spot3.json");
    let figs = dir.path().join("figs");
    let o = visco(&[
        "identify",
        s(&rec),
        "--json",
        s(&json),
        "--out",
        s(&figs),
        "--element-pitch",
        "50e-9",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let stdout = text(&o.stdout);
    assert!(
        stdout.contains("(force-curve)") && stdout.contains("k_a ="),
        "{stdout}"
    );
    let j = report_support::validate_file("identify", &json);
    assert_eq!(at(&j, "mode").and_then(Json::as_str), Some("force-curve"));
    assert_eq!(
        at(&j, "element_pitch_m").and_then(Json::as_f64),
        Some(50e-9)
    );
    let k_a = at(&j, "k_a_n_per_m3").and_then(Json::as_f64).unwrap();
    let k_el = at(&j, "taps.0.k_element_n_per_m")
        .and_then(Json::as_f64)
        .unwrap();
    assert!((k_el / (k_a * 50e-9 * 50e-9) - 1.0).abs() < 1e-12);
    assert_eq!(listing(&figs), vec!["spot3_fit.csv", "spot3_fit.png"]);
    assert_eq!(listing(dir.path()), vec!["figs", "spot3.csv", "spot3.json"]);
}

#[test]
fn a_synthetic_kelvin_voigt_free_curve_identifies_its_bed() {
    // F = k_a·V(δ) with k_a = 2e8 N/m³ under a 5 µm sphere: the fit recovers it.
    let k_a = 2e8;
    let v = |d: f64| std::f64::consts::PI * d * d * (5e-6 - d / 3.0);
    let rec = curve("0=extend,1=retract", |d| k_a * v(d));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("kv.csv");
    rec.write(&path).unwrap();
    let r = identify(&path, &Options::new(dir.path().join("kv.json"))).unwrap();
    let visco::identify::Outcome::ForceCurve(f) = r.outcome else {
        panic!()
    };
    println!(
        "k_a {:.5e}, c_a {:.4e}, contact {:.3e} m, misfit {:.3e} m",
        f.k_a_n_per_m3, f.c_a_ns_per_m3, f.contact_height_m, f.rms_misfit_m
    );
    assert!(
        (f.k_a_n_per_m3 / k_a - 1.0).abs() < 0.02,
        "{}",
        f.k_a_n_per_m3
    );
    assert!(f.c_a_ns_per_m3 < 0.01 * k_a, "no damping in the data");
    assert!(
        f.contact_height_m.abs() < 15e-9,
        "contact at {}",
        f.contact_height_m
    );
    assert!(f.rms_misfit_m < 1e-10);
}

#[test]
fn a_force_curve_without_an_approach() {
    let rec = curve("0=retract,1=retract", |d| 1e8 * d * d);
    let err = refused(&recording_text(&rec), "retract.csv");
    assert!(err.contains("without an approach"), "{err}");
    // Without segments, U must fall somewhere.
    let mut rec = curve("0=extend,1=retract", |d| 1e8 * d * d);
    rec.meta.extra.retain(|(k, _)| k != "segments");
    rec.extra.clear();
    let n = rec.len();
    rec.u_m = (0..n).map(|i| i as f64 * 1e-9).collect();
    let err = refused(&recording_text(&rec), "rising.csv");
    assert!(err.contains("without an approach"), "{err}");
}

#[test]
fn a_force_curve_that_never_touches() {
    let rec = curve("0=extend,1=retract", |_| 0.0);
    let err = refused(&recording_text(&rec), "air.csv");
    assert!(err.contains("no contact on the approach"), "{err}");
}

#[test]
fn contract_violations_name_the_line() {
    let rec = curve("0=extend,1=retract", |d| 1e8 * d * d);
    let good = recording_text(&rec);
    let lines: Vec<&str> = good.lines().collect();
    let header = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    // A non-numeric cell on the 5th data row.
    let mut bad: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    bad[header + 5] = bad[header + 5].replacen(',', ",x", 1);
    let err = refused(&(bad.join("\n") + "\n"), "cell.csv");
    assert!(err.contains(&format!("cell.csv:{}:", header + 6)), "{err}");
    // Time going backwards.
    let mut bad: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    bad.swap(header + 10, header + 11);
    let err = refused(&(bad.join("\n") + "\n"), "time.csv");
    assert!(err.contains(&format!("time.csv:{}:", header + 12)), "{err}");
    // Empty file.
    let err = refused("", "empty.csv");
    assert!(err.contains("empty file"), "{err}");
    // A missing required key.
    let err = refused(&good.replace("# tip_radius_m: 5e-6\n", ""), "key.csv");
    assert!(err.contains("tip_radius_m"), "{err}");
}

#[test]
fn an_sve_recording_without_scan_lines() {
    // A DIVE tap relabelled as SVE: contact, but x never moves.
    let mut meta = Metadata::new(Mode::Sve, 1e6, 0.18, 300e-9);
    meta.cantilever_c_ns_per_m = Some(1.48e-8);
    meta.cantilever_m_kg = Some(1.18e-11);
    let mut rec = Recording::new(meta);
    rec.x_m = Some(Vec::new());
    rec.y_m = Some(Vec::new());
    let n = 20_000;
    for i in 0..n {
        // The base comes down at 100 µm/s onto a 0.1 N/m contact at U = 0.
        let u = 0.5e-6 - 1e-4 * i as f64 * 1e-6;
        let d = if u < 0.0 { u * 0.1 / 0.28 } else { 0.0 };
        rec.t_s.push(i as f64 * 1e-6);
        rec.u_m.push(u);
        rec.d_m.push(d);
        rec.x_m.as_mut().unwrap().push(1e-6);
        rec.y_m.as_mut().unwrap().push(1e-6);
    }
    let err = refused(&recording_text(&rec), "still.csv");
    assert!(err.contains("no scan line"), "{err}");
}

#[test]
fn a_dive_recording_with_uneven_time_steps() {
    let mut meta = Metadata::new(Mode::Dive, 1e6, 0.18, 300e-9);
    meta.cantilever_c_ns_per_m = Some(1.48e-8);
    meta.cantilever_m_kg = Some(1.18e-11);
    let mut rec = Recording::new(meta);
    let mut t = 0.0;
    for i in 0..5000 {
        t += if i % 2 == 0 { 1e-6 } else { 2e-6 };
        rec.t_s.push(t);
        rec.u_m.push(0.0);
        rec.d_m.push(0.0);
    }
    let err = refused(&recording_text(&rec), "uneven.csv");
    assert!(err.contains("not uniform"), "{err}");
}

#[test]
fn bad_options_and_paths() {
    let rec = curve("0=extend,1=retract", |d| 1e8 * d * d);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.csv");
    rec.write(&path).unwrap();
    // The report's directory must exist.
    let o = visco(&[
        "identify",
        s(&path),
        "--json",
        s(&dir.path().join("no/r.json")),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        text(&o.stderr).contains("does not exist"),
        "{}",
        text(&o.stderr)
    );
    // Never over the recording.
    let o = visco(&["identify", s(&path), "--json", s(&path)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("overwrite the recording"));
    // Usage errors from the parser.
    let o = visco(&[
        "identify",
        s(&path),
        "--json",
        "r.json",
        "--element-pitch",
        "-1",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(listing(dir.path()), vec!["c.csv"]);
}

#[test]
fn a_synthetic_kelvin_voigt_curve_with_damping_identifies_both() {
    // F = k_a·V(δ) + c_a·A(δ)·δ̇, quasi-static on a 0.1 N/m lever, integrated implicitly; the
    // approach and the unloading while the bed still pushes give k_a and c_a.
    let (k_a, c_a, r, kc) = (2e8, 4e6, 5e-6, 0.1);
    let v = |d: f64| std::f64::consts::PI * d * d * (r - d / 3.0);
    let area = |d: f64| std::f64::consts::PI * (2.0 * r * d - d * d);
    let mut rec = curve("0=extend,1=retract", |_| 0.0);
    let dt = 1e-3;
    let mut delta = 0.0f64;
    for i in 0..rec.len() {
        let u = rec.u_m[i];
        let cd = c_a * area(delta) / dt;
        let g = |x: f64| kc * (x + u) + k_a * v(x) + cd * (x - delta);
        delta = if g(0.0) < 0.0 {
            let (mut lo, mut hi) = (0.0, 1e-5);
            for _ in 0..200 {
                let m = 0.5 * (lo + hi);
                if g(m) < 0.0 {
                    lo = m
                } else {
                    hi = m
                }
            }
            0.5 * (lo + hi)
        } else {
            0.0
        };
        rec.d_m[i] = if delta > 0.0 { delta + u } else { 0.0 };
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("kv.csv");
    rec.write(&path).unwrap();
    let r = identify(&path, &Options::new(dir.path().join("kv.json"))).unwrap();
    let visco::identify::Outcome::ForceCurve(f) = r.outcome else {
        panic!()
    };
    println!(
        "k_a {:.5e}, c_a {:.5e}, contact {:.3e} m, misfit {:.3e} m",
        f.k_a_n_per_m3, f.c_a_ns_per_m3, f.contact_height_m, f.rms_misfit_m
    );
    assert!(
        (f.k_a_n_per_m3 / k_a - 1.0).abs() < 0.03,
        "k_a {}",
        f.k_a_n_per_m3
    );
    assert!(
        (f.c_a_ns_per_m3 / c_a - 1.0).abs() < 0.1,
        "c_a {}",
        f.c_a_ns_per_m3
    );
    assert!(f.rms_misfit_m < 0.01 * f.deflection_range_m);
}
