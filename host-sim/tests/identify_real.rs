//! Every real vendor file in `shared/data/real/` imports, round-trips through the CSV
//! contract, and identifies with physically plausible results.
//!
//! Values the files lack, supplied as a user would: the tip radius 5 µm for all (colloidal
//! probes for cells; no vendor stores it); AFM Workshop: spring constant 0.1 N/m, 1 kHz (its
//! Force(nN) columns need no sensitivity); NT-MDT: spring constant 0.1 N/m, sensitivity
//! 50 nm/nA, 1 kHz. JPK files carry their own spring constant, sensitivity and rates.

mod identify_support;

use identify_support::{real, CC, MAP, NTMDT, SPOT3, SR, WORKSHOP};
use visco::identify::force_curve::ForceCurveFit;
use visco::identify::{identify, Json, Options, Outcome};
use visco::recording::import::{import_all, ImportOptions};
use visco::recording::Recording;

fn options_for(name: &str) -> ImportOptions {
    identify_support::real_import_options(name)
}

/// Imports, writes, reads back and identifies every curve of a file.
fn identify_file(name: &str) -> Vec<(Recording, ForceCurveFit, Json)> {
    let all = import_all(&real(name), &options_for(name)).unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    all.into_iter()
        .map(|(curve, rec)| {
            let path = dir.path().join(format!("curve{curve}.csv"));
            rec.write(&path).unwrap();
            let back = Recording::read(&path).unwrap();
            assert_eq!(back, rec, "{name}: the CSV contract round-trips");
            let json = dir.path().join(format!("curve{curve}.json"));
            let report = identify(&path, &Options::new(&json)).unwrap_or_else(|e| panic!("{e}"));
            let Outcome::ForceCurve(fit) = report.outcome else {
                panic!("{name}: not a force curve")
            };
            let j = Json::parse(&std::fs::read_to_string(&json).unwrap()).unwrap();
            assert_eq!(j, report.json, "the file holds the report");
            (back, *fit, j)
        })
        .collect()
}

fn segment_rms(f: &ForceCurveFit, kind: &str) -> f64 {
    f.segments
        .iter()
        .find(|s| s.1 == kind)
        .map(|s| s.3)
        .unwrap_or_else(|| panic!("no {kind} segment"))
}

/// What every curve must satisfy.
fn check_plausible(name: &str, rec: &Recording, f: &ForceCurveFit, j: &Json) {
    let k = rec.meta.cantilever_k_n_per_m;
    println!(
        "{name}: contact Z = {:.4e} m (row {}, threshold row {}), δmax {:.1} nm, Fmax {:.3} nN, \
         k_a {:.4e} N/m³, c_a {:.4e} N·s/m³, k {:.4e} N/m, c {:.4e} N·s/m, p {:.2}, \
         misfit {:.3e} m (approach {:.3e}) of D range {:.3e} m",
        f.contact_height_m,
        f.contact_row + 1,
        f.threshold_row + 1,
        f.max_depth_m * 1e9,
        f.max_force_n * 1e9,
        f.k_a_n_per_m3,
        f.c_a_ns_per_m3,
        f.k_n_per_m,
        f.c_ns_per_m,
        f.onset_exponent,
        f.rms_misfit_m,
        segment_rms(f, "extend"),
        f.deflection_range_m
    );
    // The contact point lies inside the approach, after its free part.
    assert!(
        f.baseline.free_rows.end < f.contact_row,
        "{name}: contact in the free part"
    );
    assert!(
        f.contact_row < f.approach.end - 1,
        "{name}: contact at the approach's end"
    );
    assert!(
        f.contact_row <= f.threshold_row + 1,
        "{name}: contact after the threshold"
    );
    // Z at contact is between the tip positions of the approach.
    let z = |i: usize| rec.u_m[i] - (rec.d_m[i] - f.baseline.at(rec.u_m[i]));
    assert!(f.contact_height_m < z(f.approach.start) && f.contact_height_m > z(f.approach.end - 1));
    // The element bed pushes back and dissipates (or not).
    assert!(
        f.k_a_n_per_m3 > 0.0 && f.k_a_n_per_m3.is_finite(),
        "{name}: k_a"
    );
    assert!(
        f.c_a_ns_per_m3 >= 0.0 && f.c_a_ns_per_m3.is_finite(),
        "{name}: c_a"
    );
    assert!(f.k_n_per_m > 0.0 && f.c_ns_per_m >= 0.0 && f.max_depth_m > 0.0);
    // The deflection at the turn is the force the instrument was told to reach.
    if let Some(sp) = rec
        .meta
        .get("setpoint_n")
        .and_then(|v| v.parse::<f64>().ok())
    {
        assert!(
            (f.max_force_n - sp).abs() < 0.1 * sp,
            "{name}: largest force {} vs setpoint {sp}",
            f.max_force_n
        );
    }
    // The forces are the vendor's own force channel, to its precision.
    if let Some((diff, range)) = f.vendor_force {
        assert!(
            diff <= 1e-9 * range,
            "{name}: −K·D vs vendor force: {diff} of {range}"
        );
        assert_eq!(j.at("vendor_force.matches"), Some(&Json::Bool(true)));
    }
    // The fit: the approach (fitted) is reproduced to a few % of the deflection range.
    assert!(
        segment_rms(f, "extend") < 0.05 * f.deflection_range_m,
        "{name}: approach misfit"
    );
    // Quasi-static: the cantilever's inertia and damping are ≲ 2 % of the force range even
    // for the worst-case lever assumed (f0 1 kHz, Q 0.5).
    let dynamics = f.dynamics.inertial_n.max(f.dynamics.damping_n);
    assert!(
        dynamics < 0.02 * f.force_range_n,
        "{name}: dynamics {dynamics}"
    );
    assert_eq!(
        j.at("cantilever_dynamics.neglected"),
        Some(&Json::Bool(true))
    );
    assert!(j.at("taps.0.k_n_per_m").and_then(Json::as_f64).unwrap() > 0.0);
    assert!(j.at("rms_misfit_m").and_then(Json::as_f64).is_some());
    assert!(k > 0.0);
}

#[test]
fn jpk_force_distance_spot3() {
    for (rec, f, j) in identify_file(SPOT3) {
        check_plausible(SPOT3, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.05 * f.deflection_range_m);
    }
}

#[test]
fn jpk_force_map_all_four_curves() {
    let all = identify_file(MAP);
    assert_eq!(all.len(), 4);
    for (rec, f, j) in all {
        check_plausible(MAP, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.1 * f.deflection_range_m);
    }
}

#[test]
fn jpk_creep_compliance_on_a_gel() {
    for (rec, f, j) in identify_file(CC) {
        check_plausible(CC, &rec, &f, &j);
        // A Kelvin–Voigt bed creeps under constant force: the hold is within reach of the
        // model (fitted on the ramps only), the retract's pull-off is not.
        assert!(f.rms_misfit_m < 0.15 * f.deflection_range_m);
        assert!(segment_rms(&f, "pause") < 0.1 * f.deflection_range_m);
    }
}

#[test]
fn jpk_stress_relaxation_leaves_the_relaxation_to_the_misfit() {
    for (rec, f, j) in identify_file(SR) {
        check_plausible(SR, &rec, &f, &j);
        // The cell relaxes at constant height, which a Kelvin–Voigt element cannot: the
        // hold's misfit dwarfs the approach's. (diagnose names it: stress-relaxation.)
        let hold = f
            .segments
            .iter()
            .filter(|s| s.1 == "pause")
            .map(|s| s.3)
            .fold(0.0, f64::max);
        assert!(hold > 10.0 * segment_rms(&f, "extend"), "hold {hold}");
        // The baseline is strongly tilted over the 20 µm approach (~1 % of U).
        assert!(f.baseline.linear && f.baseline.tilt.abs() > 1e-3);
    }
}

#[test]
fn afm_workshop_with_the_missing_spring_constant_supplied() {
    for (rec, f, j) in identify_file(WORKSHOP) {
        check_plausible(WORKSHOP, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.15 * f.deflection_range_m);
    }
}

#[test]
fn ntmdt_with_the_missing_calibration_supplied() {
    for (rec, f, j) in identify_file(NTMDT) {
        check_plausible(NTMDT, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.1 * f.deflection_range_m);
    }
}
