//! The number type the firmware's core computes in, and the conversions at the loop's edge.
//!
//! The core is one generic code (`visco_core::Controller<T>`); the firmware runs it as
//! `Controller<f32>` on the Cortex-M7's FPU (default) or, with the cargo feature
//! `fixed-point`, as `Controller<Q32>` for cores without an FPU (Cortex-M3, issue 8). Only
//! the edge differs, and it is here: f32 steps in SI (`step`, D in metres); Q32 steps in the
//! core's internal units (`step_internal`, D in nm), because no Q format holds both the 10⁹
//! and the 10⁻⁹ of the SI conversion (see `visco_core::fixed`). Telemetry stays f32 SI for
//! both, so the host link and the host tools do not change.
//!
//! This file is self-contained (`visco_core` only): the firmware uses it as
//! `visco_firmware::core_number`, and the host (`visco::replay`) includes the same source
//! file, so a host reference of either build converts exactly as the firmware does and a
//! replay can be compared bit for bit.

use visco_core::excitation::SineTable;
use visco_core::fixed::Q32;
use visco_core::schedule::SampleSink;
use visco_core::{Controller, PixelRecord, Real, Record, StepOut, TapRecord};

/// A number type the firmware's core can run in, with its loop edge.
pub trait LoopReal: SineTable {
    /// The core identifier announced in the Hello frame (1: f32, 2: Q31.32).
    const CORE_ID: u8;
    /// Name in reports.
    const NAME: &'static str;
    /// ADC code → deflection factor besides the metres per code, computed once outside the
    /// loop (f32 needs none: `()`, which keeps the f32 loop state's layout, and with it the
    /// interrupt's code, as it was before the fixed-point build).
    type AdcScale: Copy + core::fmt::Debug + PartialEq;
    /// The factor for an ADC of `metres_per_code`; `None` if it is zero, not finite, or
    /// (fixed point) not representable for 18-bit codes.
    fn adc_scale(metres_per_code: f32) -> Option<Self::AdcScale>;
    /// The deflection `step` takes for an ADC code (`metres_per_code` as validated by
    /// [`Self::adc_scale`], `s` its result).
    fn from_code(s: &Self::AdcScale, metres_per_code: f32, code: i32) -> Self;
    /// The deflection `step` takes for a value in metres (replay of off-grid recordings).
    fn from_metres(d_m: f32) -> Self;
    /// A deflection back in metres (telemetry).
    fn to_metres(d: Self) -> f32;
    /// One loop sample (with the block estimator run in-line: the host's reference; not on
    /// the firmware, whose core has no in-line task).
    #[cfg(not(target_os = "none"))]
    fn step(c: &mut Controller<Self>, d: Self) -> StepOut<Self>;
    /// One loop sample without the block estimator (the firmware's loop interrupt, which
    /// hands the samples of a running mode to `sink` and the block headers to its estimator
    /// interrupt: `Controller::step_loop`).
    fn step_loop(
        c: &mut Controller<Self>,
        d: Self,
        sink: &mut impl SampleSink<Self>,
    ) -> StepOut<Self>;
    /// The U applied now, in metres.
    fn u_m(c: &Controller<Self>) -> f32;
    /// U, X, Y after [`Self::step`], in metres (telemetry; the DACs take the codes).
    fn outputs_m(c: &Controller<Self>, o: &StepOut<Self>) -> [f32; 3];
    /// ĉ (N·s/m), k̂ (N/m), ĥ (m) now.
    fn estimates_si(c: &Controller<Self>) -> [f32; 3];
    /// The waiting record in SI.
    fn take_record(c: &mut Controller<Self>) -> Option<Record<f32>>;
}

impl LoopReal for f32 {
    const CORE_ID: u8 = 1;
    const NAME: &'static str = "f32";
    type AdcScale = ();
    fn adc_scale(metres_per_code: f32) -> Option<()> {
        (metres_per_code.is_finite() && metres_per_code != 0.0).then_some(())
    }
    /// One correctly rounded multiplication of an exact integer: the host reproduces it.
    #[inline(always)]
    fn from_code(_: &(), metres_per_code: f32, code: i32) -> f32 {
        code as f32 * metres_per_code
    }
    #[inline(always)]
    fn from_metres(d_m: f32) -> f32 {
        d_m
    }
    #[inline(always)]
    fn to_metres(d: f32) -> f32 {
        d
    }
    #[cfg(not(target_os = "none"))]
    #[inline(always)]
    fn step(c: &mut Controller<f32>, d: f32) -> StepOut<f32> {
        c.step(d)
    }
    #[inline(always)]
    fn step_loop(c: &mut Controller<f32>, d: f32, sink: &mut impl SampleSink<f32>) -> StepOut<f32> {
        c.step_loop_m(d, sink)
    }
    fn u_m(c: &Controller<f32>) -> f32 {
        c.u_m()
    }
    #[inline(always)]
    fn outputs_m(c: &Controller<f32>, _: &StepOut<f32>) -> [f32; 3] {
        c.outputs_m()
    }
    #[inline(always)]
    fn estimates_si(c: &Controller<f32>) -> [f32; 3] {
        let (a, k, h) = c.estimates();
        [a, k, h]
    }
    #[inline(always)]
    fn take_record(c: &mut Controller<f32>) -> Option<Record<f32>> {
        c.take_record()
    }
}

/// nm → m for telemetry: f64 (soft float on an M3, outside the per-sample path except in
/// replay), rounded once to f32.
#[inline]
fn nm_to_m(v: Q32) -> f32 {
    (v.to_f64() * 1e-9) as f32
}

impl LoopReal for Q32 {
    const CORE_ID: u8 = 2;
    const NAME: &'static str = "Q31.32";
    /// Nanometres per code.
    type AdcScale = Q32;
    fn adc_scale(metres_per_code: f32) -> Option<Q32> {
        let nm = metres_per_code as f64 * 1e9;
        let s = Q32::from_f64(nm);
        // 18-bit codes times the factor stay below 2³⁰ nm (the format holds ±2³¹).
        (nm.is_finite() && s.0 != 0 && nm.abs() < (1u64 << 12) as f64).then_some(s)
    }
    /// Exact: an integer times the Q31.32 factor (the factor is the one rounding, once).
    #[inline(always)]
    fn from_code(s: &Q32, _: f32, code: i32) -> Q32 {
        Q32(s.0.saturating_mul(code as i64))
    }
    fn from_metres(d_m: f32) -> Q32 {
        Q32::from_f64(d_m as f64 * 1e9)
    }
    fn to_metres(d: Q32) -> f32 {
        nm_to_m(d)
    }
    #[cfg(not(target_os = "none"))]
    #[inline(always)]
    fn step(c: &mut Controller<Q32>, d: Q32) -> StepOut<Q32> {
        c.step_internal(d)
    }
    #[inline(always)]
    fn step_loop(c: &mut Controller<Q32>, d: Q32, sink: &mut impl SampleSink<Q32>) -> StepOut<Q32> {
        c.step_loop(d, sink)
    }
    fn u_m(c: &Controller<Q32>) -> f32 {
        nm_to_m(c.u_internal())
    }
    fn outputs_m(c: &Controller<Q32>, _: &StepOut<Q32>) -> [f32; 3] {
        let (x, y) = c.xy_internal();
        [Self::u_m(c), nm_to_m(x), nm_to_m(y)]
    }
    fn estimates_si(c: &Controller<Q32>) -> [f32; 3] {
        let (a, k, h) = c.estimates_internal();
        [
            (a.to_f64() * visco_core::units::DAMPING) as f32,
            k.to_f64() as f32,
            nm_to_m(h),
        ]
    }
    fn take_record(c: &mut Controller<Q32>) -> Option<Record<f32>> {
        c.take_record_internal().map(record_si)
    }
}

/// A Q31.32 record in internal units (`Controller::take_record_internal`) in SI, each field
/// rounded once to f32.
fn record_si(r: Record<Q32>) -> Record<f32> {
    let m = nm_to_m;
    let k = |v: Q32| v.to_f64() as f32;
    let damping = |v: Q32| (v.to_f64() * visco_core::units::DAMPING) as f32;
    match r {
        Record::Tap(t) => Record::Tap(TapRecord {
            index: t.index,
            ix: t.ix,
            iy: t.iy,
            x_m: m(t.x_m),
            y_m: m(t.y_m),
            contact_height_m: m(t.contact_height_m),
            c_ns_per_m: damping(t.c_ns_per_m),
            k_n_per_m: k(t.k_n_per_m),
            // nN → N, the same factor as nm → m.
            offset_n: m(t.offset_n),
            centre_m: m(t.centre_m),
            depth_m: m(t.depth_m),
            regressor: t.regressor,
            flags: t.flags,
            samples: t.samples,
        }),
        Record::Pixel(p) => Record::Pixel(PixelRecord {
            line: p.line,
            pixel: p.pixel,
            forward: p.forward,
            x_m: m(p.x_m),
            y_m: m(p.y_m),
            c_ns_per_m: damping(p.c_ns_per_m),
            k_n_per_m: k(p.k_n_per_m),
            bed_height_m: m(p.bed_height_m),
            depth_m: m(p.depth_m),
            flags: p.flags,
            samples: p.samples,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use visco_core::DiveRegressor;

    #[test]
    fn fixed_point_adc_is_exact_and_bounded() {
        let s = Q32::adc_scale(30e-12).unwrap();
        // The factor is rounded once; a code is an exact multiple of it.
        assert_eq!(Q32::from_code(&s, 30e-12, -32768).0, -32768 * s.0);
        assert!((Q32::from_code(&s, 30e-12, 1000).to_f64() - 30.0).abs() < 1e-5);
        for bad in [0.0, f32::NAN, f32::INFINITY, 5e-6, 1e-25] {
            assert!(Q32::adc_scale(bad).is_none(), "{bad}");
        }
        let d = 123.456e-9f32;
        assert!((Q32::to_metres(Q32::from_metres(d)) - d).abs() <= d * 1e-6);
        assert_eq!(f32::from_code(&(), 3e-11, 7), 7.0 * 3e-11);
        assert!(f32::adc_scale(0.0).is_none() && f32::adc_scale(f32::NAN).is_none());
    }

    #[test]
    fn fixed_point_records_convert_to_si_without_the_q_factor_error() {
        // In Q31.32, 1e-9 is 4 LSB (7 % off): SI values must not be formed in the format.
        let q = Q32::from_f64;
        let r = record_si(Record::Tap(TapRecord {
            index: 3,
            ix: 1,
            iy: 2,
            x_m: q(2500.0),
            y_m: q(-1500.25),
            contact_height_m: q(283.34),
            c_ns_per_m: q(23.765),
            k_n_per_m: q(0.10782),
            offset_n: q(4.5),
            centre_m: q(183.0),
            depth_m: q(100.5),
            regressor: DiveRegressor::Offset,
            flags: 5,
            samples: 9,
        }));
        let Record::Tap(t) = r else {
            panic!("a tap stays a tap")
        };
        let close = |a: f32, b: f64| ((a as f64 - b) / b).abs() < 1e-6;
        assert!(close(t.x_m, 2.5e-6) && close(t.y_m, -1.50025e-6));
        assert!(close(t.contact_height_m, 2.8334e-7) && close(t.centre_m, 1.83e-7));
        assert!(close(t.c_ns_per_m, 2.3765e-5) && close(t.k_n_per_m, 0.10782));
        assert!(close(t.offset_n, 4.5e-9) && close(t.depth_m, 1.005e-7));
        assert_eq!((t.index, t.ix, t.iy, t.flags, t.samples), (3, 1, 2, 5, 9));
    }
}
