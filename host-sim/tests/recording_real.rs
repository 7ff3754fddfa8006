//! Every real vendor file in `shared/data/real/` imports into physically plausible
//! recordings that round-trip bit-exactly through the CSV contract.

mod recording_support;

use recording_support::*;
use visco::recording::import::{import_all, ImportOptions};
use visco::recording::{ErrorKind, Mode, Recording};

/// README's spring constants are rounded; the file's value must round to them.
fn assert_k_rounds_to(rec: &Recording, readme: f64, decimals: i32) {
    let k = rec.meta.cantilever_k_n_per_m;
    let scale = 10f64.powi(decimals);
    assert!(
        ((k * scale).round() / scale - readme).abs() < 1e-12,
        "k = {k} does not round to the README's {readme}"
    );
}

/// Time strictly increasing, and within each segment spaced by exactly 1/rate.
fn assert_time_grid(rec: &Recording, rates_hz: &[f64]) {
    assert!(
        rec.t_s.windows(2).all(|w| w[1] > w[0]),
        "time not increasing"
    );
    assert_eq!(rec.t_s[0], 0.0);
    for (s, &rate) in rates_hz.iter().enumerate() {
        let r = segment_range(rec, s as f64);
        for w in rec.t_s[r].windows(2) {
            let dt = w[1] - w[0];
            assert!(
                (dt * rate - 1.0).abs() < 1e-9,
                "segment {s}: dt = {dt} s, not 1/{rate} Hz"
            );
        }
    }
}

/// D·k against the vendor's own force channel: same numbers (the vendor computes force from
/// the same raw counts and calibration), opposite sign (vendor: repulsive positive).
fn assert_force_matches_vendor(rec: &Recording) {
    let f = rec.extra_column("force_vendor_n").expect("vendor force");
    let k = rec.meta.cantilever_k_n_per_m;
    let scale = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0);
    for (i, (&d, &fv)) in rec.d_m.iter().zip(f).enumerate() {
        assert!(
            (-d * k - fv).abs() <= 1e-12 * scale,
            "sample {i}: -D·k = {} N, vendor {fv} N",
            -d * k
        );
    }
}

/// Mean of a slice.
fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Approach of a force-triggered curve: U falls by the configured stroke (or less when the
/// setpoint stops it early), and the deflection at the turn, relative to the free baseline at
/// the start, is the configured setpoint force. D must go *negative* (contract sign).
fn assert_approach(rec: &Recording, extend: f64, setpoint_n: Option<f64>, min_stroke_m: f64) {
    let r = segment_range(rec, extend);
    let u = &rec.u_m[r.clone()];
    let d = &rec.d_m[r.clone()];
    let stroke = u[0] - u[u.len() - 1];
    assert!(
        stroke >= min_stroke_m,
        "approach stroke {stroke} m < {min_stroke_m} m"
    );
    let n0 = (d.len() / 20).max(5);
    let baseline = mean(&d[..n0]);
    let turn = d[d.len() - 1];
    assert!(
        turn < baseline,
        "D at the turn {turn} not below the free baseline {baseline}"
    );
    let k = rec.meta.cantilever_k_n_per_m;
    let force = (baseline - turn) * k;
    // Non-zero: far above the noise of the free baseline.
    let noise = (d[..n0].iter().map(|x| (x - baseline).powi(2)).sum::<f64>() / n0 as f64).sqrt();
    assert!(
        baseline - turn > 20.0 * noise.max(1e-12),
        "deflection {} m vs noise {noise} m",
        baseline - turn
    );
    if let Some(sp) = setpoint_n {
        assert!(
            (force - sp).abs() < 0.1 * sp,
            "force at the turn {force} N vs setpoint {sp} N"
        );
    }
}

fn assert_round_trip(rec: &Recording) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.csv");
    rec.write(&path).unwrap();
    let back = Recording::read(&path).unwrap();
    assert_bit_exact(rec, &back);
    assert_eq!(
        dir_listing(dir.path()),
        vec!["rec.csv"],
        "temporary files left"
    );
}

#[test]
fn jpk_force_distance_spot3() {
    let rec = import_one(SPOT3, &tip_only());
    assert_eq!(rec.meta.mode, Mode::ForceCurve);
    assert_eq!(rec.len(), 4000);
    assert_k_rounds_to(&rec, 0.043, 3);
    assert_eq!(rec.meta.cantilever_k_n_per_m, 0.043493666407368466);
    assert_eq!(rec.meta.tip_radius_m, 5e-6);
    assert_eq!(rec.meta.sample_rate_hz, 2000.0);
    assert_eq!(rec.meta.get("segments"), Some("0=extend,1=retract"));
    assert_eq!(
        rec.meta.get("sensitivity_m_per_v"),
        Some("7.000143623002982e-8")
    );
    assert_eq!(rec.meta.get("instrument"), Some("A0042-CellHesion"));
    assert_time_grid(&rec, &[2000.0, 2000.0]);
    assert_force_matches_vendor(&rec);
    // Setpoint 4 nN (README), 5 µm stroke (relative-z-start).
    let sp: f64 = rec.meta.get("setpoint_n").unwrap().parse().unwrap();
    assert!((sp - 4e-9).abs() < 0.05e-9, "setpoint {sp}");
    assert_approach(&rec, 0.0, Some(4e-9), 4.9e-6);
    let u = &rec.u_m[segment_range(&rec, 0.0)];
    assert!(
        (u[0] - u[u.len() - 1] - 5e-6).abs() < 0.05e-6,
        "stroke not the configured 5 µm"
    );
    // Retract: U climbs back.
    let r = segment_range(&rec, 1.0);
    assert!(rec.u_m[r.end - 1] - rec.u_m[r.start] > 4.9e-6);
    assert_round_trip(&rec);
}

#[test]
fn jpk_stress_relaxation_has_per_segment_rates() {
    let rec = import_one(SR, &tip_only());
    assert_k_rounds_to(&rec, 1.07, 2);
    assert_eq!(
        rec.meta.get("segments"),
        Some("0=pause,1=extend,2=pause,3=retract")
    );
    assert_eq!(rec.meta.get("segment_points"), Some("256,2048,7680,1951"));
    assert_eq!(rec.len(), 256 + 2048 + 7680 + 1951);
    assert_eq!(rec.meta.sample_rate_hz, 2048.0);
    assert_time_grid(&rec, &[256.0, 2048.0, 256.0, 2048.0]);
    // 33 s: 1 + 1 + 30 + 0.95 s (the retract was cut short by the instrument).
    let total = rec.t_s[rec.len() - 1];
    assert!(
        (total - (32.95263671875 - 1.0 / 2048.0)).abs() < 1e-9,
        "duration {total}"
    );
    assert_force_matches_vendor(&rec);
    // Height-controlled approach over 20 µm; the deflection at the turn is far from zero.
    assert_approach(&rec, 1.0, None, 19.8e-6);
    // Hold at constant height: the z sensor stays put, the force relaxes (D rises towards 0).
    let hold = segment_range(&rec, 2.0);
    let u = &rec.u_m[hold.clone()];
    let (umin, umax) = u
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    // The strain gauge resolves 3.1 nm (16-bit counts); 30 s of hold stay within ~8 counts,
    // while the piezo drive moved 0.6 µm to keep it there.
    assert!(
        umax - umin < 40e-9,
        "height moved {} m during a constant-height hold",
        umax - umin
    );
    let piezo = &rec.extra_column("height_piezo_m").unwrap()[segment_range(&rec, 2.0)];
    assert!((piezo[piezo.len() - 1] - piezo[0]).abs() > 10.0 * (umax - umin));
    let d = &rec.d_m[hold];
    assert!(
        d[d.len() - 1] - d[0] > 100e-9,
        "no relaxation: D {} -> {}",
        d[0],
        d[d.len() - 1]
    );
    assert_round_trip(&rec);
}

#[test]
fn jpk_creep_compliance_hold_at_constant_force() {
    let rec = import_one(CC, &tip_only());
    assert_k_rounds_to(&rec, 0.061, 3);
    assert_eq!(rec.meta.get("segments"), Some("0=extend,1=pause,2=retract"));
    assert_eq!(rec.len(), 9000);
    assert_eq!(rec.meta.sample_rate_hz, 1000.0);
    assert_time_grid(&rec, &[1000.0, 1000.0, 1000.0]);
    assert_force_matches_vendor(&rec);
    let sp: f64 = rec.meta.get("setpoint_n").unwrap().parse().unwrap();
    assert!((sp - 10e-9).abs() < 0.1e-9, "setpoint {sp}");
    assert_approach(&rec, 0.0, Some(sp), 29.5e-6);
    // Constant force: D stays within 10 % of the setpoint force; the base creeps into the gel
    // (U falls), which the z sensor shows and the piezo drive signal does not.
    let hold = segment_range(&rec, 1.0);
    let d = &rec.d_m[hold.clone()];
    let (dmin, dmax) = d
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    assert!((dmax - dmin) * rec.meta.cantilever_k_n_per_m < 0.1 * sp);
    let u = &rec.u_m[hold.clone()];
    assert!(u[u.len() - 1] < u[0] - 100e-9, "no creep into the gel");
    let piezo = &rec.extra_column("height_piezo_m").unwrap()[hold];
    assert!(
        piezo[piezo.len() - 1] > piezo[0],
        "the piezo drive compensates creep upwards"
    );
    assert_round_trip(&rec);
}

#[test]
fn jpk_force_map_gives_one_recording_per_curve() {
    let all = import_all(&real(MAP), &tip_only()).unwrap();
    assert_eq!(
        all.iter().map(|(c, _)| *c).collect::<Vec<_>>(),
        vec![0, 1, 2, 3]
    );
    let expect = [
        (24060, "3.1972656250000005e-5", "-7.535351562500001e-4", "0"),
        (24060, "5.718359375000001e-4", "-7.5390625e-4", "9"),
        (3226, "5.718359375000001e-4", "-2.1373046875000003e-4", "90"),
        (8210, "3.185546875e-5", "-2.1373046875000003e-4", "99"),
    ];
    for ((curve, rec), (n, x, y, pos)) in all.iter().zip(expect) {
        assert_eq!(rec.len(), n, "curve {curve}");
        assert_eq!(
            rec.meta.get("curve_index"),
            Some(curve.to_string().as_str())
        );
        assert_eq!(rec.meta.get("position_x_m"), Some(x));
        assert_eq!(rec.meta.get("position_y_m"), Some(y));
        assert_eq!(rec.meta.get("position_index"), Some(pos));
        assert_eq!(rec.meta.get("source_format"), Some("jpk-force-map"));
        assert_k_rounds_to(rec, 0.0155, 4);
        // 12030 points in 6 s: "2 kHz".
        assert_eq!(rec.meta.sample_rate_hz, 2005.0);
        assert_time_grid(rec, &[2005.0, 2005.0]);
        assert_force_matches_vendor(rec);
        let sp: f64 = rec.meta.get("setpoint_n").unwrap().parse().unwrap();
        assert!((sp - 2e-9).abs() < 0.05e-9, "setpoint {sp}");
        assert_approach(rec, 0.0, Some(sp), 1e-6);
        assert_round_trip(rec);
    }
}

#[test]
fn afm_workshop_needs_its_missing_values_and_then_imports() {
    let e = import_all(&real(WORKSHOP), &ImportOptions::default()).unwrap_err();
    assert_eq!(e.kind, ErrorKind::MissingValue);
    assert!(e.reason.contains("no spring constant"), "{e}");
    let fix = e.fix.clone().unwrap();
    for flag in ["--spring-constant", "--sample-rate", "--tip-radius"] {
        assert!(fix.contains(flag), "{e}");
    }
    // Force(nN) columns: the sensitivity is not needed.
    assert!(!fix.contains("--sensitivity"), "{e}");

    let opts = ImportOptions {
        sensitivity_m_per_unit: None,
        ..everything()
    };
    let rec = import_one(WORKSHOP, &opts);
    assert_eq!(rec.len(), 2 * 1217);
    assert_eq!(rec.meta.cantilever_k_n_per_m, 0.1);
    assert_eq!(rec.meta.get("position_x_m"), Some("5e-7"));
    assert_time_grid(&rec, &[1000.0, 1000.0]);
    assert_force_matches_vendor(&rec);
    // First row of the file: Z-Sense 4129.0327 nm, force 0.0531 nN.
    assert_eq!(rec.u_m[0], -4129.0327e-9);
    assert_eq!(
        rec.extra_column("force_vendor_n").unwrap()[0],
        0.0531 * 1e-9
    );
    // Extend: Z-Sense grows by 1216 nm, U falls; the force grows in contact.
    let r = segment_range(&rec, 0.0);
    assert!((rec.u_m[r.start] - rec.u_m[r.end - 1] - 1216e-9).abs() < 1e-12);
    assert_approach(&rec, 0.0, None, 1.2e-6);
    assert_round_trip(&rec);
}

#[test]
fn ntmdt_reads_decimal_commas_in_time_order() {
    let e = import_all(&real(NTMDT), &ImportOptions::default()).unwrap_err();
    let fix = e.fix.clone().unwrap();
    for flag in [
        "--spring-constant",
        "--sensitivity",
        "--sample-rate",
        "--tip-radius",
    ] {
        assert!(fix.contains(flag), "{e}");
    }
    let rec = import_one(NTMDT, &everything());
    assert_eq!(rec.meta.get("ntmdt_cropped_rows_approach"), Some("178"));
    assert_eq!(rec.len(), 2 * (1000 - 178));
    assert_time_grid(&rec, &[1000.0, 1000.0]);
    // Approach starts at the last row (height -0,0006 nm, DFL -1,1033 nA) and goes down.
    assert_eq!(rec.u_m[0], -0.0006e-9);
    assert_eq!(rec.d_m[0], 1.1033 * 5e-8);
    assert_approach(&rec, 0.0, None, 6e-6);
    let r = segment_range(&rec, 1.0);
    assert!(
        rec.u_m[r.end - 1] > rec.u_m[r.start] + 6e-6,
        "retract goes up"
    );
    assert_round_trip(&rec);
}

#[test]
fn flags_override_the_file_with_a_warning() {
    let opts = ImportOptions {
        spring_constant_n_per_m: Some(0.05),
        ..tip_only()
    };
    let mut imp = visco::recording::import::Import::open(&real(SPOT3), &opts).unwrap();
    let rec = imp.read_curve(0).unwrap();
    assert_eq!(rec.meta.cantilever_k_n_per_m, 0.05);
    assert_eq!(
        rec.meta.get("spring_constant_source"),
        Some("--spring-constant")
    );
    assert_eq!(
        rec.meta.get("spring_constant_file_n_per_m"),
        Some("0.043493666407368466")
    );
    assert!(
        imp.warnings()
            .iter()
            .any(|w| w.contains("--spring-constant") && w.contains("0.043493666407368466")),
        "{:?}",
        imp.warnings()
    );
    // D is unchanged (it comes from the sensitivity), so D·k no longer equals the vendor force.
    let base = import_one(SPOT3, &tip_only());
    assert_eq!(rec.d_m, base.d_m);

    // --sensitivity rescales D from the raw volts.
    let opts = ImportOptions {
        sensitivity_m_per_unit: Some(2.0 * 7.000143623002982e-8),
        ..tip_only()
    };
    let rec = import_one(SPOT3, &opts);
    for (a, b) in rec.d_m.iter().zip(&base.d_m) {
        assert!((a - 2.0 * b).abs() <= 1e-15 * b.abs().max(1e-9));
    }
}
