//! Fault injection on the simulated instrument: what the loop does when the ADC glitches, the
//! tip loses the sample, the force runs away or the estimator is misled — and how long it takes
//! to recover.
//!
//! Each class runs the core in closed loop with the plant (DIVE: one tap on a flat cell-like
//! sample; SVE: a line across it), injects its fault while the estimator is running, and
//! measures:
//! * whether every output and estimate stayed finite and inside its bounds at every sample;
//! * the largest contact force on the tip against the configured limit;
//! * the recovery time: from the end of the fault until the estimates (ĉ, k̂) are back within
//!   5 % of their values just before the fault, and stay there for the rest of the window.
//!
//! The classes: ADC values non-finite (a burst of NaN), saturated (the full-scale code), spiking
//! (isolated single-sample excursions), missing (dropouts: the board reports no sample); loss of
//! contact during SVE (a pit deeper than the depth); a tip force above the limit (a stiff
//! inclusion rising under the scanning tip); and a misleading input for the estimator (a step of
//! the detector's offset, which no Kelvin–Voigt contact explains).

use super::Setup;
use crate::plant::Plant;
use crate::sample::Sample;
use serde::Serialize;
use visco_core::{status, Command, Controller, Mode, Phase};

/// A fault to inject.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultClass {
    /// 200 µs of NaN from the ADC.
    NonFinite,
    /// 200 µs of the ADC's full-scale code.
    Saturated,
    /// Single-sample excursions of 1.5 µm every 50 µs for 5 ms.
    Spikes,
    /// Missing samples: 30 % of the samples over 5 ms, in runs of 1–5.
    Dropouts,
    /// SVE over a 600 nm deep pit: the tip loses the sample.
    ContactLoss,
    /// SVE over a stiff inclusion rising 250 nm: the force would exceed the limit.
    ForceLimit,
    /// A 40 nm step of the detector's offset during a DIVE dwell, which misleads the estimator.
    OffsetStep,
}

impl FaultClass {
    /// Every class.
    pub const ALL: [FaultClass; 7] = [
        FaultClass::NonFinite,
        FaultClass::Saturated,
        FaultClass::Spikes,
        FaultClass::Dropouts,
        FaultClass::ContactLoss,
        FaultClass::ForceLimit,
        FaultClass::OffsetStep,
    ];

    /// The mode it is injected in.
    pub fn mode(self) -> Mode {
        match self {
            FaultClass::ContactLoss | FaultClass::ForceLimit => Mode::Sve,
            _ => Mode::Dive,
        }
    }
}

/// The outcome of one fault.
#[derive(Clone, Debug, Serialize)]
pub struct FaultOutcome {
    /// The class.
    pub class: FaultClass,
    /// Every output and estimate finite and inside its bounds at every sample.
    pub bounded: bool,
    /// Samples at which something was not.
    pub unbounded_samples: u64,
    /// Largest contact force on the tip (N).
    pub max_force_n: f64,
    /// The configured force limit (N).
    pub force_limit_n: f64,
    /// Status bits seen during and after the fault (or-ed).
    pub flags: u32,
    /// Time from the end of the fault until ĉ and k̂ are back within 5 % of their pre-fault
    /// values for good (s); `None` if they never are within the window.
    pub recovery_s: Option<f64>,
    /// The pre-fault ĉ, k̂ (aggregates, SI).
    pub before: [f64; 2],
    /// ĉ, k̂ at the end of the window.
    pub after: [f64; 2],
}

/// The sample faults run on: a flat bed of mid-range elements 100 nm high, with a pit 600 nm
/// deep or a stiff inclusion 250 nm high where the class needs one (x from 2.0 to 2.6 µm).
pub fn fault_sample(class: FaultClass) -> Sample {
    let inside = |x: f64| (2.0e-6..2.6e-6).contains(&x);
    Sample::from_fn(50, 50, 100e-9, [50e-9, 50e-9], |x, _| match class {
        FaultClass::ContactLoss if inside(x) => (-500e-9, 6e-7, 3.5e-3),
        FaultClass::ForceLimit if inside(x) => (350e-9, 6e-5, 0.35),
        _ => (100e-9, 6e-7, 3.5e-3),
    })
    .expect("fault sample")
}

/// What the fault does to the ADC reading at loop sample `n` (0 = the fault's start), or `None`
/// for no change; `Some(NaN)` is a missing or invalid sample.
fn corrupt(class: FaultClass, n: u64, d: f32, full_scale: f32, rng: &mut u64) -> Option<f32> {
    let mut next = || {
        *rng ^= *rng << 13;
        *rng ^= *rng >> 7;
        *rng ^= *rng << 17;
        *rng
    };
    match class {
        FaultClass::NonFinite if n < 100 => Some(f32::NAN),
        FaultClass::Saturated if n < 100 => Some(-full_scale),
        FaultClass::Spikes if n < 2500 && n % 25 == 0 => {
            Some(d + if next() % 2 == 0 { 1.5e-6 } else { -1.5e-6 })
        }
        FaultClass::Dropouts if n < 2500 && next() % 10 < 3 => Some(f32::NAN),
        FaultClass::OffsetStep if n < 2500 => Some(d + 40e-9),
        _ => None,
    }
}

/// How long the injected ADC fault lasts (samples at 500 kHz); plant faults last as long as the
/// tip takes to cross them.
fn fault_samples(class: FaultClass) -> u64 {
    match class {
        FaultClass::NonFinite | FaultClass::Saturated => 100,
        FaultClass::Spikes | FaultClass::Dropouts | FaultClass::OffsetStep => 2500,
        FaultClass::ContactLoss | FaultClass::ForceLimit => 0,
    }
}

/// Run one fault class at `sample_rate_hz` and measure it.
pub fn run_fault(class: FaultClass, sample_rate_hz: f64, seed: u64) -> FaultOutcome {
    let mut setup = Setup::paper(fault_sample(class), sample_rate_hz, seed);
    let c = &mut setup.config;
    c.dive.nx = 1;
    c.dive.ny = 1;
    c.dive.x0_m = 1.0e-6;
    c.dive.y0_m = 2.5e-6;
    c.dive.tap_s = 0.2;
    c.sve.lines = 1;
    c.sve.y0_m = 2.5e-6;
    c.sve.line_period_s = 2.0;
    let cfg = setup.config;
    let force_limit_n = cfg.faults.force_max_n;
    let mut ctrl = Controller::<f32>::new(&cfg).expect("config");
    let mut plant: Plant = setup.build_plant().expect("plant");
    let mode = class.mode();
    ctrl.command(Command::Start(mode));
    let fs = cfg.sample_rate_hz;
    let dt = 1.0 / fs;
    let full_scale = cfg.limits.d_full_scale_m as f32;
    // When to inject: DIVE 60 ms into the estimating part of the dwell; SVE plant faults are in
    // the sample (the forward line reaches x = 2 µm at 0.4 s); estimates compared over windows.
    let mut estimating_for = 0u64;
    let mut fault_start: Option<u64> = None;
    let mut fault_end: Option<u64> = None;
    let mut before = [f64::NAN; 2];
    let mut history: Vec<(u64, f64, f64)> = Vec::new();
    let (mut bounded, mut unbounded) = (true, 0u64);
    let (mut max_force, mut flags) = (0.0f64, 0u32);
    let mut d = plant.measured_deflection_m() as f32;
    let mut rng = 0x9e37_79b9_7f4a_7c15u64 ^ seed;
    let steps = (if mode == Mode::Dive { 0.21 } else { 1.2 } * fs) as u64;
    for n in 0..steps {
        // Inject.
        let mut d_in = d;
        if let Some(s) = fault_start {
            if let Some(v) = corrupt(class, n - s, d, full_scale, &mut rng) {
                d_in = v;
            }
        }
        let out = ctrl.step(d_in);
        if out.status & status::RECORD_READY != 0 {
            ctrl.take_record();
        }
        let (ce, ke, he) = ctrl.estimates();
        let ok = [out.u_m, out.x_m, out.y_m, ce, ke, he]
            .iter()
            .all(|v| v.is_finite())
            && out.u_m as f64 >= cfg.limits.u_min_m
            && out.u_m as f64 <= cfg.limits.u_max_m
            && ce >= 0.0
            && ke > 0.0;
        if !ok {
            bounded = false;
            unbounded += 1;
        }
        max_force = max_force.max(plant.contact_force_n());
        if out.status & status::ESTIMATING != 0 {
            estimating_for += 1;
        }
        let x = out.x_m as f64;
        match (mode, fault_start) {
            (Mode::Dive, None) if estimating_for as f64 >= 0.06 * fs => {
                fault_start = Some(n);
                fault_end = Some(n + fault_samples(class));
            }
            (Mode::Sve, None) if ctrl.phase() == Phase::Forward && x >= 1.95e-6 => {
                fault_start = Some(n);
            }
            (Mode::Sve, Some(_)) if fault_end.is_none() && x >= 2.65e-6 => fault_end = Some(n),
            _ => {}
        }
        if fault_start.is_none() {
            if out.status & status::ESTIMATING != 0 {
                before = [ce as f64, ke as f64];
            }
        } else {
            flags |= out.status & 0x00ff_ffff;
            history.push((n, ce as f64, ke as f64));
        }
        if ctrl.phase() == Phase::Done {
            break;
        }
        d = (plant.step_nm(
            out.u_m as f64 * 1e9,
            out.x_m as f64 * 1e9,
            out.y_m as f64 * 1e9,
        ) * 1e-9) as f32;
    }
    // SVE: the pre-fault estimates are those over the flat bed, which the line returns to.
    let within = |v: &(u64, f64, f64)| {
        (v.1 / before[0] - 1.0).abs() <= 0.05 && (v.2 / before[1] - 1.0).abs() <= 0.05
    };
    let end = fault_end.unwrap_or(u64::MAX);
    let last_out = history
        .iter()
        .rev()
        .find(|v| v.0 >= end && !within(v))
        .map(|v| v.0);
    let recovery_s = match (fault_end, history.last()) {
        (Some(e), Some(last)) if within(last) => {
            Some(last_out.map_or(0.0, |o| (o + 1 - e) as f64 * dt))
        }
        _ => None,
    };
    FaultOutcome {
        class,
        bounded,
        unbounded_samples: unbounded,
        max_force_n: max_force,
        force_limit_n,
        flags,
        recovery_s,
        before,
        after: history.last().map_or([f64::NAN; 2], |v| [v.1, v.2]),
    }
}
