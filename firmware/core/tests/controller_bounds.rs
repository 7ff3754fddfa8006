//! For arbitrary input sequences — finite or not, in range or absurd — `step` returns finite
//! outputs inside their ranges and the estimates stay finite and inside their bounds.

use proptest::prelude::*;
use visco_core::{Command, Config, Controller, DiveRegressor, Mode, SveRegressor};

fn arb_d() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -3e-6f32..3e-6,          // plausible deflections, including beyond full scale
        2 => -1e-9f32..1e-9,          // near zero
        1 => any::<f32>(),            // anything, NaN and ±∞ included
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(-f32::MAX),
    ]
}

fn short_config(fs: f64) -> Config {
    let mut c = Config::paper(fs);
    c.dive.nx = 2;
    c.dive.ny = 1;
    c.dive.tap_s = 0.03;
    c.dive.move_s = 1e-4;
    c.dive.settle_s = 1e-4;
    c.dive.readout_s = 1e-3;
    c.dive.excitation.ramp_s = 2e-4;
    c.sve.lines = 1;
    c.sve.pixels = 4;
    c.sve.line_period_s = 0.02;
    c.sve.turn_s = 1e-3;
    c.sve.settle_s = 1e-3;
    c.sve.excitation.ramp_s = 2e-4;
    c.approach.u_start_m = 20e-9;
    c
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn step_output_is_finite_and_in_range_for_any_input(
        data in proptest::collection::vec(arb_d(), 1..30_000),
        mode in prop_oneof![Just(Mode::Dive), Just(Mode::Sve)],
        paper in any::<bool>(),
    ) {
        let mut cfg = short_config(1e6);
        if paper {
            cfg.dive.regressor = DiveRegressor::Paper;
            cfg.sve.regressor = SveRegressor::Paper;
        }
        cfg.validate().unwrap();
        let mut ctrl = Controller::<f32>::new(&cfg).unwrap();
        ctrl.command(Command::Start(mode));
        let (umin, umax) = (cfg.limits.u_min_m as f32, cfg.limits.u_max_m as f32);
        let (xmin, xmax) = (cfg.limits.xy_min_m as f32, cfg.limits.xy_max_m as f32);
        for d in data {
            let out = ctrl.step(d);
            prop_assert!(out.u_m.is_finite() && out.u_m >= umin && out.u_m <= umax, "u = {}", out.u_m);
            prop_assert!(out.x_m.is_finite() && out.x_m >= xmin && out.x_m <= xmax);
            prop_assert!(out.y_m.is_finite() && out.y_m >= xmin && out.y_m <= xmax);
            prop_assert!(out.u_code >= -32768 && out.u_code <= 32767);
            let (c, k, h) = ctrl.estimates();
            prop_assert!(c.is_finite() && c >= 0.0 && c as f64 <= cfg.dive.estimator.c_max_ns_per_m.max(cfg.sve.estimator.c_max_ns_per_m) * 1.0001);
            prop_assert!(k.is_finite() && k > 0.0);
            prop_assert!(h.is_finite());
            if let Some(r) = ctrl.take_record() {
                match r {
                    visco_core::Record::Tap(t) => prop_assert!(t.c_ns_per_m.is_finite() && t.k_n_per_m.is_finite() && t.offset_n.is_finite() && t.depth_m.is_finite()),
                    visco_core::Record::Pixel(p) => prop_assert!(p.c_ns_per_m.is_finite() && p.k_n_per_m.is_finite() && p.bed_height_m.is_finite() && p.depth_m.is_finite()),
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// The fixed-point core (Q31.32) through its internal-unit entry point: no overflow panic
    /// (the tests run with overflow checks), U on the DAC grid, estimates in their boxes, for
    /// any input — including the extremes of the format.
    #[test]
    fn fixed_point_step_stays_in_range_for_any_input(
        data in proptest::collection::vec(prop_oneof![
            4 => (-3000i64..3000).prop_map(|v| visco_core::fixed::Q32(v << 32)),
            2 => any::<i64>().prop_map(visco_core::fixed::Q32),
            1 => Just(visco_core::fixed::Q32(i64::MAX)),
            1 => Just(visco_core::fixed::Q32(i64::MIN)),
        ], 1..20_000),
        mode in prop_oneof![Just(Mode::Dive), Just(Mode::Sve)],
    ) {
        use visco_core::fixed::Q32;
        use visco_core::Real;
        let cfg = short_config(1e6);
        let mut ctrl = Controller::<Q32>::new(&cfg).unwrap();
        ctrl.command(Command::Start(mode));
        let (umin, umax) = (cfg.limits.u_min_m * 1e9, cfg.limits.u_max_m * 1e9);
        let cmax = cfg.dive.estimator.c_max_ns_per_m.max(cfg.sve.estimator.c_max_ns_per_m)
            / visco_core::units::DAMPING;
        for d in data {
            let out = ctrl.step_internal(d);
            let u = ctrl.u_internal().to_f64();
            prop_assert!(u >= umin - 1.0 && u <= umax + 1.0, "u = {u} nm");
            prop_assert!(out.u_code >= -32768 && out.u_code <= 32767);
            let (c, k, _) = ctrl.estimates_internal();
            prop_assert!(c >= Q32::ZERO && c.to_f64() <= cmax * 1.0001, "c = {}", c.to_f64());
            prop_assert!(k > Q32::ZERO);
            ctrl.take_record();
        }
    }
}

/// The f32 core rounds onto a DAC's grid exactly up to 22 bits (`Real::CODE_BITS_MAX`): a
/// wider DAC is refused by name, not driven with codes off by one; the f64 reference and the
/// fixed-point build take the configuration's full 24.
#[test]
fn a_dac_wider_than_the_number_type_rounds_is_refused() {
    for (u_bits, xy_bits, field) in [(23, 16, "limits.dac_bits"), (16, 24, "limits.xy_dac_bits")] {
        let mut cfg = Config::paper(500e3);
        cfg.limits.dac_bits = u_bits;
        cfg.limits.xy_dac_bits = xy_bits;
        let e = Controller::<f32>::new(&cfg).err().expect("refused");
        assert_eq!(e.field, field);
        assert!(Controller::<f64>::new(&cfg).is_ok());
        assert!(Controller::<visco_core::fixed::Q32>::new(&cfg).is_ok());
    }
    let mut cfg = Config::paper(500e3);
    cfg.limits.dac_bits = 22;
    cfg.limits.xy_dac_bits = 22;
    assert!(Controller::<f32>::new(&cfg).is_ok());
}
