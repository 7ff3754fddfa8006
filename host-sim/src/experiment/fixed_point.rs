//! The fixed-point core against the f64 reference (issue 8): the same closed loop in every
//! number type, the estimates compared at each record.
//!
//! `Controller<Q32>` is the same code as `Controller<f32>`, one type parameter apart, driven
//! through the internal-unit entry point (`step_internal`: no Q format holds the SI factors
//! 10⁹ and 10⁻⁹). The cases are the paper's DIVE and SVE on the cell phantom, reduced so that
//! they run in seconds: 3 × 3 DIVE taps, one SVE line of 25 pixels each way, at 500 kHz. At
//! every record (tap or pixel) the current estimates ĉ, k̂, ĥ in internal units are taken; the
//! error of a number type is the largest difference from the f64 run over the records, in %
//! of each property's largest value in the f64 run. Used by
//! `cargo test --release -p visco --test fixed_point` and `cargo xtask firmware-report`.

use crate::experiment::Setup;
use crate::plant::Plant;
use crate::sample::Sample;
use visco_core::excitation::SineTable;
use visco_core::{Command, Controller, EstimatorKind, Mode};

/// (ĉ, k̂, ĥ) in internal units at every record of the reduced paper case of `mode` with
/// the estimator `kind`, the core computing in `T`.
pub fn record_estimates<T: SineTable>(mode: Mode, kind: EstimatorKind) -> Vec<[f64; 3]> {
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
    let mut ctrl = Controller::<T>::new(&cfg).expect("the paper's configuration is valid");
    let mut plant: Plant = setup.build_plant().expect("the paper's plant is valid");
    ctrl.command(Command::Start(mode));
    let mut d_nm = plant.measured_deflection_m() * 1e9;
    let mut out = Vec::new();
    let steps = match mode {
        Mode::Dive => 9.5 * cfg.dive.tap_s,
        Mode::Sve => 1.2 * cfg.sve.line_period_s,
    } * cfg.sample_rate_hz;
    for _ in 0..steps as u64 {
        ctrl.step_internal(T::from_f64(d_nm));
        if ctrl.take_record_internal().is_some() {
            let (c, k, h) = ctrl.estimates_internal();
            out.push([c.to_f64(), k.to_f64(), h.to_f64()]);
        }
        let (x, y) = ctrl.xy_internal();
        d_nm = plant.step_nm(ctrl.u_internal().to_f64(), x.to_f64(), y.to_f64());
    }
    out
}

/// Largest difference against the reference, in % of each property's maximum over the
/// reference records, as [c, k, h]; ∞ when the record counts differ.
pub fn error_pct(a: &[[f64; 3]], reference: &[[f64; 3]]) -> [f64; 3] {
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

/// The error of the core in `T` against f64 on the case (`mode`, `kind`), [c, k, h] in % of
/// each maximum, and the number of records compared.
pub fn error_vs_f64<T: SineTable>(mode: Mode, kind: EstimatorKind) -> ([f64; 3], usize) {
    let reference = record_estimates::<f64>(mode, kind);
    (
        error_pct(&record_estimates::<T>(mode, kind), &reference),
        reference.len(),
    )
}
