//! The fixed-point core (issue 8): `Controller<Q32>` is the same code as `Controller<f32>`, one
//! type parameter apart, driven through the internal-unit entry point (`step_internal`). On the
//! paper's DIVE and SVE cases (reduced: 3 × 3 taps, one SVE line on the cell phantom) in closed
//! loop with the plant, the estimates at each record are compared with the f64 reference, in %
//! of each property's maximum; the error against word length is printed
//! (`cargo test --release -p visco --test fixed_point -- --nocapture`).

use visco::experiment::Setup;
use visco::plant::Plant;
use visco::sample::Sample;
use visco_core::excitation::SineTable;
use visco_core::fixed::{Q16, Q24, Q32};
use visco_core::{Command, Controller, EstimatorKind, Mode};

/// (c, k, h) in internal units at every record (tap or pixel).
fn run<T: SineTable>(mode: Mode, kind: EstimatorKind) -> Vec<[f64; 3]> {
    let mut setup = Setup::paper(Sample::cell_phantom(), 500e3, 1);
    let c = &mut setup.config;
    c.dive.nx = 3;
    c.dive.ny = 3;
    c.dive.x0_m = 1.5e-6;
    c.dive.y0_m = 1.5e-6;
    c.dive.dx_m = 1.0e-6;
    c.dive.dy_m = 1.0e-6;
    c.sve.lines = 1;
    c.sve.y0_m = 2.5e-6;
    c.sve.pixels = 25;
    c.dive.estimator.kind = kind;
    c.sve.estimator.kind = kind;
    let cfg = setup.config;
    let mut ctrl = Controller::<T>::new(&cfg).expect("config");
    let mut plant: Plant = setup.build_plant().expect("plant");
    ctrl.command(Command::Start(mode));
    let mut d_nm = plant.measured_deflection_m() * 1e9;
    let mut out = Vec::new();
    let steps = match mode {
        Mode::Dive => 9.5 * cfg.dive.tap_s,
        Mode::Sve => 1.2 * cfg.sve.line_period_s,
    } * cfg.sample_rate_hz;
    for _ in 0..steps as u64 {
        ctrl.step_internal(T::from_f64(d_nm));
        if ctrl.take_record().is_some() {
            let (c, k, h) = ctrl.estimates_internal();
            out.push([c.to_f64(), k.to_f64(), h.to_f64()]);
        }
        let (x, y) = ctrl.xy_internal();
        d_nm = plant.step_nm(ctrl.u_internal().to_f64(), x.to_f64(), y.to_f64());
    }
    out
}

/// Largest difference against the reference, in % of each property's maximum over the
/// reference records.
fn error_pct(a: &[[f64; 3]], reference: &[[f64; 3]]) -> [f64; 3] {
    if a.len() != reference.len() {
        return [f64::INFINITY; 3];
    }
    let mut e = [0.0f64; 3];
    for i in 0..3 {
        let max = reference.iter().map(|r| r[i].abs()).fold(0.0, f64::max);
        for (x, r) in a.iter().zip(reference) {
            e[i] = e[i].max((x[i] - r[i]).abs() / max * 100.0);
        }
    }
    e
}

#[test]
fn fixed_point_against_f64() {
    for (mode, kind) in [
        (Mode::Dive, EstimatorKind::Gradient),
        (Mode::Sve, EstimatorKind::Gradient),
        (Mode::Dive, EstimatorKind::LeastSquares),
        (Mode::Sve, EstimatorKind::LeastSquares),
    ] {
        let reference = run::<f64>(mode, kind);
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
            ("f32", error_pct(&run::<f32>(mode, kind), &reference)),
            ("Q32", error_pct(&run::<Q32>(mode, kind), &reference)),
            ("Q24", error_pct(&run::<Q24>(mode, kind), &reference)),
            ("Q16", error_pct(&run::<Q16>(mode, kind), &reference)),
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
