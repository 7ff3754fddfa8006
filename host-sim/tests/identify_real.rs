//! Every real vendor file in `shared/data/real/` imports, round-trips through the CSV
//! contract, and identifies with physically plausible results.
//!
//! Values the files lack, supplied as a user would: the tip radius 5 µm for all (colloidal
//! probes for cells; no vendor stores it); AFM Workshop: spring constant 0.1 N/m, 1 kHz (its
//! Force(nN) columns need no sensitivity); NT-MDT: spring constant 0.1 N/m, sensitivity
//! 50 nm/nA, 1 kHz. JPK files carry their own spring constant, sensitivity and rates.

mod identify_support;
mod report_support;

use identify_support::pins::Pins;
use identify_support::{real, CC, MAP, NTMDT, SPOT3, SR, WORKSHOP};
use serde_json::Value as Json;
use visco::identify::force_curve::ForceCurveFit;
use visco::identify::{identify, Options, Outcome};
use visco::recording::import::{import_all, ImportOptions};
use visco::recording::Recording;
use visco::report::at;

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
            let j = report_support::validate_file("identify", &json);
            assert_eq!(
                j,
                serde_json::to_value(&report.json).unwrap(),
                "the file holds the report"
            );
            // The typed report reads the file back whole (null ↔ NaN, every f64 exact).
            let typed: visco::identify::IdentifyReport = serde_json::from_value(j.clone()).unwrap();
            assert_eq!(serde_json::to_value(&typed).unwrap(), j, "typed read-back");
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

/// The identify table of README.md ("Recordings and importers"), as quoted: per file, the
/// contact row, δ_max (figure, m per unit), k_a and c_a (figure, N/m³ or N·s/m³ per unit),
/// the misfit over all rows and over the approach (nm), and the report's
/// `cantilever_dynamics.to_noise` (the lever's dynamic force as a deflection over the noise,
/// for the worst-case lever the report assumes when the file gives none). The map row quotes the range over its
/// four curves: `Range(low, high)`. A re-measure changes these figures and README.md only.
#[rustfmt::skip]
const IDENTIFY_TABLE: &[(&str, Row)] = &[
    (SPOT3, Row { contact: Some("1909"), depth: ("148", 1e-9), k_a: ("1.20", 1e10), c_a: ("3.1", 1e7), misfit: ("1.8", "0.5"), dynamics: "2.5" }),
    (SR, Row { contact: Some("1202"), depth: ("10.9", 1e-6), k_a: ("1.27", 1e8), c_a: ("0", 1e6), misfit: ("142", "4.3"), dynamics: "0.47" }),
    (CC, Row { contact: Some("2770"), depth: ("2.40", 1e-6), k_a: ("1.20", 1e8), c_a: ("2.0", 1e6), misfit: ("32", "3.5"), dynamics: "43" }),
    (WORKSHOP, Row { contact: Some("821"), depth: ("396", 1e-9), k_a: ("9.0", 1e6), c_a: ("6.8", 1e3), misfit: ("0.03", "0.010"), dynamics: "2.8" }),
    (NTMDT, Row { contact: Some("601"), depth: ("1.63", 1e-6), k_a: ("3.5", 1e8), c_a: ("2.7", 1e6), misfit: ("8.4", "3.0"), dynamics: "0.34" }),
];

/// The map's row: (low, high) over its four curves.
const MAP_RANGES: MapRow = MapRow {
    depth: (("430", "658"), 1e-9),
    k_a: (("1.9", "4.8"), 1e8),
    c_a: (("0", "1.5"), 1e6),
    misfit: ("3.9", "8.5"),
    approach: ("1.5", "4.8"),
    dynamics: ("1.8", "2.3"),
};

struct Row {
    contact: Option<&'static str>,
    depth: (&'static str, f64),
    k_a: (&'static str, f64),
    c_a: (&'static str, f64),
    misfit: (&'static str, &'static str),
    dynamics: &'static str,
}

struct MapRow {
    depth: ((&'static str, &'static str), f64),
    k_a: ((&'static str, &'static str), f64),
    c_a: ((&'static str, &'static str), f64),
    misfit: (&'static str, &'static str),
    approach: (&'static str, &'static str),
    dynamics: (&'static str, &'static str),
}

/// One curve's identified figures and their standard errors from the deflection noise σ_D
/// (the free approach's), in SI units: (value, SE) for the contact row, δ_max, k_a, c_a, the
/// misfit over all rows and over the approach.
struct Measured {
    contact: (f64, f64),
    depth: (f64, f64),
    k_a: (f64, f64),
    c_a: (f64, f64),
    misfit: (f64, f64),
    approach: (f64, f64),
    dynamics: (f64, f64),
}

/// Standard errors from the noise: the contact point is resolved to the depth δ_σ at which
/// the bed's force bends the lever by σ_D (k_a·πRδ² = K·σ_D); it carries into δ_max (± δ_σ),
/// the row (δ_σ over the approach's step per row) and k_a (V ∝ δ²: 2δ_σ/δ_max, plus the force
/// noise K·σ_D/F_max/√n over the n rows in contact); c_a is resolved to the damping force
/// that equals the force noise over the contact rows, K·σ_D/(A(δ_max)·v·√n); an RMS over n
/// rows to σ_D/√n; the dynamics' ratio to its noise σ_D's own relative error, 1/√(2·n_free).
fn measured(rec: &Recording, f: &ForceCurveFit) -> Measured {
    let (k, r, sd) = (
        rec.meta.cantilever_k_n_per_m,
        rec.meta.tip_radius_m,
        f.baseline.noise_m,
    );
    let pi = std::f64::consts::PI;
    let d_sigma = (k * sd / (pi * r * f.k_a_n_per_m3)).sqrt();
    let rows = f.approach.len() as f64;
    let (u0, u1) = (rec.u_m[f.approach.start], rec.u_m[f.approach.end - 1]);
    let (t0, t1) = (rec.t_s[f.approach.start], rec.t_s[f.approach.end - 1]);
    let step = (u0 - u1).abs() / rows;
    let speed = (u0 - u1).abs() / (t1 - t0);
    let n_contact = (f.approach.end - f.contact_row).max(1) as f64;
    // The contact's area, πa² (πR² past the sphere's equator).
    let d = f.max_depth_m.min(r);
    let area = pi * (2.0 * r * d - d * d);
    let force_noise = k * sd / f.max_force_n / n_contact.sqrt();
    Measured {
        contact: (f.contact_row as f64 + 1.0, d_sigma / step),
        depth: (f.max_depth_m, d_sigma),
        k_a: (
            f.k_a_n_per_m3,
            f.k_a_n_per_m3 * (2.0 * d_sigma / f.max_depth_m + force_noise),
        ),
        c_a: (f.c_a_ns_per_m3, k * sd / (area * speed * n_contact.sqrt())),
        misfit: (f.rms_misfit_m, sd / (rec.len() as f64).sqrt()),
        approach: (segment_rms(f, "extend"), sd / rows.sqrt()),
        dynamics: (
            f.dynamics.to_noise,
            f.dynamics.to_noise / (2.0 * f.baseline.free_rows.len() as f64).sqrt(),
        ),
    }
}

/// Compares a file's curves with the README's identify table.
fn pin_table(name: &str, all: &[(Recording, ForceCurveFit, Json)]) {
    let m: Vec<Measured> = all.iter().map(|(r, f, _)| measured(r, f)).collect();
    let mut p = Pins::default();
    let fig = |p: &mut Pins, what: &str, quoted: &str, unit: f64, (v, se): (f64, f64)| {
        println!("{name} {what}: {v:.5e} ± {se:.2e} (SI)");
        p.check(what, quoted, v / unit, se / unit)
    };
    if name == MAP {
        let r = &MAP_RANGES;
        // The range's ends: the smallest and the largest over the curves.
        let ends = |get: &dyn Fn(&Measured) -> (f64, f64)| {
            let lo = m
                .iter()
                .map(get)
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap();
            let hi = m
                .iter()
                .map(get)
                .max_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap();
            (lo, hi)
        };
        for (what, (lo_q, hi_q), unit, get) in [
            (
                "δ_max",
                r.depth.0,
                r.depth.1,
                &(|x: &Measured| x.depth) as &dyn Fn(&Measured) -> (f64, f64),
            ),
            ("k_a", r.k_a.0, r.k_a.1, &|x: &Measured| x.k_a),
            ("c_a", r.c_a.0, r.c_a.1, &|x: &Measured| x.c_a),
            ("misfit all", r.misfit, 1e-9, &|x: &Measured| x.misfit),
            ("misfit approach", r.approach, 1e-9, &|x: &Measured| {
                x.approach
            }),
            (
                "lever dynamics over the noise",
                r.dynamics,
                1.0,
                &|x: &Measured| x.dynamics,
            ),
        ] {
            let (lo, hi) = ends(get);
            fig(
                &mut p,
                &format!("{what}, lowest of the curves"),
                lo_q,
                unit,
                lo,
            );
            fig(
                &mut p,
                &format!("{what}, highest of the curves"),
                hi_q,
                unit,
                hi,
            );
        }
    } else {
        let (_, row) = IDENTIFY_TABLE
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap_or_else(|| panic!("{name} is not in the README's identify table"));
        assert_eq!(m.len(), 1, "{name}: one curve");
        let m = &m[0];
        if let Some(c) = row.contact {
            fig(&mut p, "contact row", c, 1.0, m.contact);
        }
        fig(&mut p, "δ_max", row.depth.0, row.depth.1, m.depth);
        fig(&mut p, "k_a", row.k_a.0, row.k_a.1, m.k_a);
        fig(&mut p, "c_a", row.c_a.0, row.c_a.1, m.c_a);
        fig(&mut p, "misfit all (nm)", row.misfit.0, 1e-9, m.misfit);
        fig(
            &mut p,
            "misfit approach (nm)",
            row.misfit.1,
            1e-9,
            m.approach,
        );
        fig(
            &mut p,
            "lever dynamics over the noise",
            row.dynamics,
            1.0,
            m.dynamics,
        );
    }
    p.finish(name);
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
    let z = |i: usize| rec.u_m[i] - (rec.d_m[i] - f.baseline.under(rec.u_m[i], rec.d_m[i]));
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
        assert_eq!(at(j, "vendor_force.matches"), Some(&Json::Bool(true)));
    }
    // The fit: the approach (fitted) is reproduced to a few % of the deflection range.
    assert!(
        segment_rms(f, "extend") < 0.05 * f.deflection_range_m,
        "{name}: approach misfit"
    );
    check_dynamics(name, rec, f, j);
    assert!(at(j, "taps.0.k_n_per_m").and_then(Json::as_f64).unwrap() > 0.0);
    assert!(at(j, "rms_misfit_m").and_then(Json::as_f64).is_some());
    assert!(k > 0.0);
}

/// The report's `cantilever_dynamics`: the ratio of the lever's largest dynamic force, as a
/// deflection, to the deflection noise, recomputed here from the reported bounds, and
/// `neglected` exactly when it is below 1. Returns the ratio.
fn check_dynamics(name: &str, rec: &Recording, f: &ForceCurveFit, j: &Json) -> f64 {
    let k = rec.meta.cantilever_k_n_per_m;
    let worst = f.dynamics.inertial_n.max(f.dynamics.damping_n);
    let ratio = worst / k / f.baseline.noise_m;
    let reported = at(j, "cantilever_dynamics.to_noise")
        .and_then(Json::as_f64)
        .unwrap();
    println!(
        "{name}: lever dynamics {worst:.3e} N = {:.3e} m of deflection, {ratio:.3e} of the \
         noise {:.3e} m, {:.3e} of the force range (f0 {} Hz, Q {}, {})",
        worst / k,
        f.baseline.noise_m,
        worst / f.force_range_n,
        f.dynamics.f0_hz,
        f.dynamics.q,
        f.dynamics.source
    );
    assert!(
        (reported / ratio - 1.0).abs() < 1e-12,
        "{name}: {reported} vs {ratio}"
    );
    assert!(
        (at(j, "cantilever_dynamics.to_force_range")
            .and_then(Json::as_f64)
            .unwrap()
            / (worst / f.force_range_n)
            - 1.0)
            .abs()
            < 1e-12
    );
    assert_eq!(
        at(j, "cantilever_dynamics.neglected"),
        Some(&Json::Bool(ratio < 1.0)),
        "{name}: neglected iff the dynamics are below the noise"
    );
    ratio
}

/// A force curve simulated with the lever's dynamics (M·Z̈ = K·(U − Z) + C·(U̇ − Ż) + F,
/// F = k_a·πδ²(R − δ/3) below the bed at Z = 0, D = U − Z; f₀ 2 kHz, Q 1, K 0.1 N/m, given
/// in the recording), approach 2 µm down and back over `ramp_s` each, deflection noise
/// 0.1 nm RMS, 1000 rows per ramp. Also returns the true largest damping force C·|U̇ − Ż| (N)
/// over the rows.
fn dynamic_curve(ramp_s: f64) -> (Recording, f64) {
    use visco::recording::{Column, Metadata, Mode};
    let (k, r, k_a, f0, q) = (0.1, 5e-6, 2e10, 2e3, 1.0);
    let w0 = 2.0 * std::f64::consts::PI * f0;
    let m = k / (w0 * w0);
    let c = (k * m).sqrt() / q;
    let rows = 1000;
    let dt = ramp_s / rows as f64;
    let mut meta = Metadata::new(Mode::ForceCurve, 1.0 / dt, k, r);
    meta.cantilever_m_kg = Some(m);
    meta.cantilever_c_ns_per_m = Some(c);
    meta.set("segments", "0=extend,1=retract");
    let mut rec = Recording::new(meta);
    rec.extra.push(Column {
        name: "segment".into(),
        values: Vec::new(),
    });
    let u_at = |t: f64| {
        let s = (t / ramp_s).clamp(0.0, 2.0);
        1.7e-6 - 2e-6 * if s < 1.0 { s } else { 2.0 - s }
    };
    // Semi-implicit Euler at 1/200 of the period or finer.
    let sub = ((dt * f0 * 200.0).ceil() as usize).max(1);
    let h = dt / sub as f64;
    // In steady motion with the base from the start (no ring-up at the first row).
    let (mut z, mut v) = (u_at(0.0), -2e-6 / ramp_s);
    let mut seed = 12345u64;
    let mut damping = 0.0f64;
    for i in 0..2 * rows {
        for s in 0..sub {
            let t = (i * sub + s) as f64 * h;
            let (u, du) = (u_at(t), (u_at(t + h) - u_at(t)) / h);
            let delta = (-z).max(0.0);
            let f = k_a * std::f64::consts::PI * delta * delta * (r - delta / 3.0);
            v += h * (k * (u - z) + c * (du - v) + f) / m;
            z += h * v;
            if s == 0 {
                damping = damping.max((c * (du - v)).abs());
            }
        }
        let t = (i + 1) as f64 * dt;
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let noise = 0.1e-9 * 3f64.sqrt() * (2.0 * (seed >> 11) as f64 / (1u64 << 53) as f64 - 1.0);
        rec.t_s.push(t);
        rec.u_m.push(u_at(t));
        rec.d_m.push(u_at(t) - z + noise);
        rec.extra[0].values.push(if i < rows { 0.0 } else { 1.0 });
    }
    (rec, damping)
}

#[test]
fn lever_dynamics_neglected_only_when_the_noise_hides_them() {
    let dir = tempfile::tempdir().unwrap();
    let mut ratios = Vec::new();
    // 10 s ramps (0.2 µm/s): quasi-static; 0.1 s ramps (20 µm/s): the lever's damping
    // C·U̇ (C = K/ω₀Q) bends it by U̇/ω₀Q ≈ 1.6 nm, 16× the noise: not.
    for (ramp_s, quasi_static) in [(10.0, true), (0.1, false)] {
        let (rec, damping) = dynamic_curve(ramp_s);
        let path = dir.path().join(format!("dyn{ramp_s}.csv"));
        rec.write(&path).unwrap();
        let json = dir.path().join(format!("dyn{ramp_s}.json"));
        let report = identify(&path, &Options::new(&json)).unwrap_or_else(|e| panic!("{e}"));
        let Outcome::ForceCurve(fit) = report.outcome else {
            panic!("not a force curve")
        };
        let ratio = check_dynamics(
            &format!("{ramp_s} s ramps"),
            &rec,
            &fit,
            &serde_json::to_value(&report.json).unwrap(),
        );
        assert_eq!(
            fit.dynamics.neglected, quasi_static,
            "{ramp_s} s ramps: ratio {ratio}"
        );
        println!(
            "{ramp_s} s ramps: reported {ratio:.3}, the simulation's largest damping force over \
             the noise (turn-around transients included) {:.3}",
            damping / rec.meta.cantilever_k_n_per_m / 0.1e-9
        );
        ratios.push(ratio);
    }
    // The damping force scales with the speed (100×); the bound reads derivatives smoothed
    // over 5 ms, which shaves the fast curve's turn-arounds: within a factor of 3.
    let scale = ratios[1] / ratios[0];
    assert!(scale > 100.0 / 3.0 && scale < 300.0, "{ratios:?}");
}

#[test]
fn jpk_force_distance_spot3() {
    let all = identify_file(SPOT3);
    pin_table(SPOT3, &all);
    for (rec, f, j) in all {
        check_plausible(SPOT3, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.05 * f.deflection_range_m);
    }
}

#[test]
fn jpk_force_map_all_four_curves() {
    let all = identify_file(MAP);
    assert_eq!(all.len(), 4);
    pin_table(MAP, &all);
    for (rec, f, j) in all {
        check_plausible(MAP, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.1 * f.deflection_range_m);
    }
}

#[test]
fn jpk_creep_compliance_on_a_gel() {
    let all = identify_file(CC);
    pin_table(CC, &all);
    for (rec, f, j) in all {
        check_plausible(CC, &rec, &f, &j);
        // A Kelvin–Voigt bed creeps under constant force: the hold is within reach of the
        // model (fitted on the ramps only), the retract's pull-off is not.
        assert!(f.rms_misfit_m < 0.15 * f.deflection_range_m);
        assert!(segment_rms(&f, "pause") < 0.1 * f.deflection_range_m);
    }
}

#[test]
fn jpk_stress_relaxation_leaves_the_relaxation_to_the_misfit() {
    let all = identify_file(SR);
    pin_table(SR, &all);
    for (rec, f, j) in all {
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
    let all = identify_file(WORKSHOP);
    pin_table(WORKSHOP, &all);
    for (rec, f, j) in all {
        check_plausible(WORKSHOP, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.15 * f.deflection_range_m);
    }
}

#[test]
fn ntmdt_with_the_missing_calibration_supplied() {
    let all = identify_file(NTMDT);
    pin_table(NTMDT, &all);
    for (rec, f, j) in all {
        check_plausible(NTMDT, &rec, &f, &j);
        assert!(f.rms_misfit_m < 0.1 * f.deflection_range_m);
    }
}

/// Identifies `rec` with `wave(x)` added to its deflection at the lever's height
/// `x = U − (D − line(U))` (an optical interference of the laser that spills onto the sample;
/// `line`: the recording's own free deflection).
fn identify_with_wave(
    rec: &Recording,
    line: impl Fn(f64) -> f64,
    wave: impl Fn(f64) -> f64,
) -> ForceCurveFit {
    let mut rec = rec.clone();
    for (d, &u) in rec.d_m.iter_mut().zip(&rec.u_m) {
        *d += wave(u - (*d - line(u)));
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wavy.csv");
    rec.write(&path).unwrap();
    let report = identify(&path, &Options::new(dir.path().join("wavy.json")))
        .unwrap_or_else(|e| panic!("{e}"));
    let Outcome::ForceCurve(fit) = report.outcome else {
        panic!("not a force curve")
    };
    *fit
}

/// A wavy interference baseline (added at the lever's height, as the physics has it) is
/// modelled, not refused, and the contact's figures do not move: on AFM Workshop (whose free approach carries its own wave, 8.6 pm at 0.32 µm, which
/// the stronger one adds to at the same period: the same laser) and on JPK spot3 (no wave of
/// its own; 0.4 µm, an 830 nm laser's λ/2). The added wave is 15 % of the curve's deflection
/// range: with the line-only baseline this moved AFM Workshop's contact by 124 rows and its
/// k_a by 25 % at a fifth of that, and refused the curve at half of it.
#[test]
fn an_interference_wave_is_modelled_and_moves_nothing() {
    for (name, own_period) in [(WORKSHOP, true), (SPOT3, false)] {
        let (rec, f0, _) = identify_file(name).into_iter().next().unwrap();
        let m0 = measured(&rec, &f0);
        let period = if own_period {
            f0.baseline
                .wave
                .as_ref()
                .expect("AFM Workshop's own wave")
                .period_m
        } else {
            assert!(f0.baseline.wave.is_none(), "{name}: {:?}", f0.baseline.wave);
            400e-9
        };
        let a = 0.15 * f0.deflection_range_m;
        let tau = std::f64::consts::TAU;
        let line = |u: f64| f0.baseline.line_at(u);
        let f = identify_with_wave(&rec, line, |x| a * (tau * x / period + 1.0).sin());
        let w = f
            .baseline
            .wave
            .as_ref()
            .unwrap_or_else(|| panic!("{name}: no wave found"));
        println!(
            "{name}: added {a:.3e} m at {period:.4e} m; found {:.3e} m at {:.4e} m; contact row \
             {} → {}, k_a {:.4e} → {:.4e}, c_a {:.4e} → {:.4e}, δmax {:.4e} → {:.4e}",
            w.amplitude_m,
            w.period_m,
            f0.contact_row + 1,
            f.contact_row + 1,
            f0.k_a_n_per_m3,
            f.k_a_n_per_m3,
            f0.c_a_ns_per_m3,
            f.c_a_ns_per_m3,
            f0.max_depth_m,
            f.max_depth_m
        );
        // The period to 1 % (it is resolved to ~0.1 % over the free part's periods).
        assert!(
            (w.period_m / period - 1.0).abs() < 0.01,
            "{name}: period {}",
            w.period_m
        );
        if !own_period {
            assert!(
                (w.amplitude_m / a - 1.0).abs() < 0.05,
                "{name}: amplitude {}",
                w.amplitude_m
            );
        }
        // The contact's figures within 3 standard errors from the noise (identify_real's own
        // tolerances: `measured`), the noise being the wave-free curve's.
        let m = measured(&rec, &f);
        for (what, (v0, se), v) in [
            ("contact row", m0.contact, m.contact.0),
            ("δ_max", m0.depth, m.depth.0),
            ("k_a", m0.k_a, m.k_a.0),
            ("c_a", m0.c_a, m.c_a.0),
        ] {
            assert!(
                (v - v0).abs() <= 3.0 * se,
                "{name}: {what} {v0:.4e} → {v:.4e} (±3·{se:.2e})"
            );
        }
    }
}

/// A spring constant far too small for a Force(nN) file (here 10⁻⁶ N/m: the file's forces are
/// pN) makes the lever bend further than its base travels, which no sample allows: the refusal
/// says so and names the value and its source (AFM Workshop's 2020 test curve, given 0.1 N/m,
/// spanned 8× its travel).
#[test]
fn a_deflection_wider_than_the_travel_names_the_spring_constant() {
    let mut opts = options_for(WORKSHOP);
    opts.spring_constant_n_per_m = Some(1e-6);
    let (_, rec) = import_all(&real(WORKSHOP), &opts).unwrap().remove(0);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("soft-k.csv");
    rec.write(&path).unwrap();
    let e = match identify(&path, &Options::new(dir.path().join("soft-k.json"))) {
        Ok(_) => panic!("identified with k = 1e-6 N/m"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains("bends at most as far as its base moves")
            && e.contains("k = 0.000001 N/m, from --spring-constant"),
        "{e}"
    );
    // diagnose refuses it for the same reason.
    let e = visco::diagnose::problem::Problem::new(&rec).expect_err("diagnose refuses it");
    assert!(
        e.to_string()
            .contains("bends at most as far as its base moves"),
        "{e}"
    );
    // The file's own scale (k = 0.1 N/m as the table's row) passes the check.
    assert!(identify_file(WORKSHOP).len() == 1);
}
