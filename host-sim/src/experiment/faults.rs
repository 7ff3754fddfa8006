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

use super::{plant_reading, Setup};
use crate::plant::Plant;
use crate::sample::Sample;
use schemars::JsonSchema;
use serde::Serialize;
use visco_core::{status, Command, Controller, Mode, Phase};

/// A fault to inject.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, JsonSchema)]
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
    /// A DIVE tap into a sample 100 times stiffer than the soft bed (the stiff inclusion's
    /// material under the whole tap): the force limit must retract the tip. Judged by the
    /// peak force and the time from the force crossing the limit to the retract
    /// ([`FaultOutcome::retract_s`]); no estimates to recover.
    DiveForceLimit,
}

impl FaultClass {
    /// Every class.
    pub const ALL: [FaultClass; 8] = [
        FaultClass::NonFinite,
        FaultClass::Saturated,
        FaultClass::Spikes,
        FaultClass::Dropouts,
        FaultClass::ContactLoss,
        FaultClass::ForceLimit,
        FaultClass::OffsetStep,
        FaultClass::DiveForceLimit,
    ];

    /// The mode it is injected in.
    pub fn mode(self) -> Mode {
        match self {
            FaultClass::ContactLoss | FaultClass::ForceLimit => Mode::Sve,
            // (DiveForceLimit, like the input classes and the offset step.)
            _ => Mode::Dive,
        }
    }
}

/// The outcome of one fault.
#[derive(Clone, Debug, Serialize, JsonSchema)]
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
    /// `dive-force-limit` only: the time from the contact (the indentation's start) to the
    /// loop's retract on the force limit (its `FORCE_LIMIT` status) (s); `None` for the
    /// other classes, or if either never happened.
    pub retract_s: Option<f64>,
    /// `dive-force-limit` only: the true static tip force when the loop retracted (N): the
    /// cantilever's K·(D_free − D) from the plant's true deflection, low-passed at the loop
    /// limit's corner (every sample, f64) — the force the limit is about, without the
    /// detector's noise; `None` for the other classes or without a retract.
    pub retract_force_n: Option<f64>,
    /// The fault-free run's ĉ, k̂ when the fault starts (aggregates, SI).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 2]")]
    pub before: [f64; 2],
    /// ĉ, k̂ at the end of the window.
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 2]")]
    pub after: [f64; 2],
}

/// The sample faults run on (`None`: the fault-free reference): a flat bed of mid-range elements 100 nm high, with a pit 600 nm
/// deep or a stiff inclusion 250 nm high where the class needs one (x from 2.0 to 2.6 µm).
pub fn fault_sample(class: Option<FaultClass>) -> Sample {
    let inside = |x: f64| (2.0e-6..2.6e-6).contains(&x);
    Sample::from_fn(50, 50, 100e-9, [50e-9, 50e-9], |x, _| match class {
        Some(FaultClass::ContactLoss) if inside(x) => (-500e-9, 6e-7, 3.5e-3),
        Some(FaultClass::ForceLimit) if inside(x) => (350e-9, 6e-5, 0.35),
        Some(FaultClass::DiveForceLimit) => (100e-9, 6e-5, 0.35),
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
        FaultClass::ContactLoss | FaultClass::ForceLimit | FaultClass::DiveForceLimit => 0,
    }
}

/// `dive-force-limit`'s force limit (N): above the soft bed's tap (~51 nN peak), below the
/// stiff sample's (~148 nN without the limit).
pub const DIVE_FORCE_MAX_N: f64 = 100e-9;

/// One closed-loop run of a fault class's experiment, with the fault (`inject`) or without.
struct Run {
    /// (sample, ĉ, k̂) from the fault's start to the end of the window.
    history: Vec<(u64, f64, f64)>,
    fault_end: Option<u64>,
    unbounded: u64,
    max_force_n: f64,
    flags: u32,
    force_limit_n: f64,
    /// `dive-force-limit`: the first sample of the indentation (the contact confirmed), the
    /// first with the loop's `FORCE_LIMIT`, and the true static force there.
    crossed: Option<u64>,
    retracted: Option<u64>,
    retract_force_n: f64,
}

fn simulate(class: FaultClass, inject: bool, sample_rate_hz: f64, seed: u64) -> Run {
    let sample = fault_sample(if inject { Some(class) } else { None });
    let mut setup = Setup::paper(sample, sample_rate_hz, seed);
    let c = &mut setup.config;
    c.dive.nx = 1;
    c.dive.ny = 1;
    c.dive.x0_m = 1.0e-6;
    c.dive.y0_m = 2.5e-6;
    c.dive.tap_s = 0.2;
    c.sve.lines = 1;
    c.sve.y0_m = 2.5e-6;
    c.sve.line_period_s = 2.0;
    if class == FaultClass::DiveForceLimit {
        // The limit between the soft bed's tap (~51 nN) and the stiff sample's (~148 nN).
        c.faults.force_max_n = DIVE_FORCE_MAX_N;
    }
    let cfg = setup.config;
    let mut ctrl = Controller::<f32>::new(&cfg).expect("config");
    let mut plant: Plant = setup.build_plant().expect("plant");
    let mode = class.mode();
    ctrl.command(Command::Start(mode));
    let fs = cfg.sample_rate_hz;
    let full_scale = cfg.limits.d_full_scale_m as f32;
    let mut run = Run {
        history: Vec::new(),
        fault_end: None,
        unbounded: 0,
        max_force_n: 0.0,
        flags: 0,
        force_limit_n: cfg.faults.force_max_n,
        crossed: None,
        retracted: None,
        retract_force_n: f64::NAN,
    };
    let dive_limit = class == FaultClass::DiveForceLimit;
    // `dive-force-limit`: the true static tip force, K·(D_free − D) from the plant's true
    // deflection low-passed as the loop's limit low-passes the measured one (the contact
    // low-pass's corner, here at every sample and in f64): the force the limit is about,
    // without the detector's noise and the tones.
    let k_cant = cfg.cantilever.k_n_per_m;
    let d_free = plant.true_deflection_m();
    let lp_w = visco_core::discretize::one_pole_weight(
        2.0 * std::f64::consts::PI * cfg.contact.lowpass_hz / fs,
    );
    let mut force_lp = 0.0f64;
    // When: DIVE 60 ms into the estimating part of the dwell; SVE where the tip (radius
    // 300 nm) reaches the feature (x = 1.7 µm) until it has left it (2.9 µm).
    let mut estimating_for = 0u64;
    let mut fault_start: Option<u64> = None;
    let mut d = plant.measured_deflection_m() as f32;
    let mut rng = 0x9e37_79b9_7f4a_7c15u64 ^ seed;
    let steps = (if mode == Mode::Dive { 0.25 } else { 1.5 } * fs) as u64;
    for n in 0..steps {
        let mut d_in = d;
        if let (Some(s), true) = (fault_start, inject) {
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
            run.unbounded += 1;
        }
        let force = plant.elastic_force_n();
        run.max_force_n = run.max_force_n.max(force);
        if dive_limit {
            // The fault starts where the static tip force first exceeds the limit; the run
            // ends 2 ms after the retract (the force's peak after it included).
            force_lp += lp_w * (k_cant * (d_free - plant.true_deflection_m()) - force_lp);
            if run.crossed.is_none() && ctrl.phase() == Phase::Indent {
                run.crossed = Some(n);
            }
            if run.retracted.is_none() && out.status & status::FORCE_LIMIT != 0 {
                run.retracted = Some(n);
                run.retract_force_n = force_lp;
            }
            if run.crossed.is_some() || run.retracted.is_some() {
                run.flags |= out.status & status::FAULTS;
            }
            if run.retracted.is_some_and(|r| n >= r + (2e-3 * fs) as u64) {
                break;
            }
            d = plant_reading(&mut plant, &out);
            continue;
        }
        if out.status & status::ESTIMATING != 0 {
            estimating_for += 1;
        }
        let x = out.x_m as f64;
        let phase = ctrl.phase();
        match (mode, fault_start) {
            (Mode::Dive, None) if estimating_for as f64 >= 0.06 * fs => {
                fault_start = Some(n);
                run.fault_end = Some(n + fault_samples(class));
            }
            (Mode::Sve, None) if phase == Phase::Forward && x >= 1.7e-6 => fault_start = Some(n),
            (Mode::Sve, Some(_)) if run.fault_end.is_none() && x >= 2.9e-6 => {
                run.fault_end = Some(n)
            }
            _ => {}
        }
        // The window ends with the tap's dwell or the forward line (the estimates are held,
        // then reset, after), SVE before the bed's edge at 5 µm where the contact thins out.
        let window = match mode {
            Mode::Dive => Phase::Dwell,
            Mode::Sve => Phase::Forward,
        };
        if fault_start.is_some() && (phase != window || x > 4.2e-6) {
            break;
        }
        if fault_start.is_some() {
            run.flags |= out.status & status::FAULTS;
            run.history.push((n, ce as f64, ke as f64));
        }
        d = plant_reading(&mut plant, &out);
    }
    run
}

/// Run one fault class at `sample_rate_hz` and measure it against the same experiment without
/// the fault (same seed, so the same noise until the fault): recovered when ĉ and k̂ are back
/// within 5 % of the fault-free run's at the same instant, for good.
pub fn run_fault(class: FaultClass, sample_rate_hz: f64, seed: u64) -> FaultOutcome {
    if class == FaultClass::DiveForceLimit {
        // No fault-free run to compare with: the tap is aborted, nothing to recover.
        let run = simulate(class, true, sample_rate_hz, seed);
        let retract_s = match (run.crossed, run.retracted) {
            (Some(c), Some(r)) if r >= c => Some((r - c) as f64 / sample_rate_hz),
            _ => None,
        };
        return FaultOutcome {
            class,
            bounded: run.unbounded == 0,
            unbounded_samples: run.unbounded,
            max_force_n: run.max_force_n,
            force_limit_n: run.force_limit_n,
            flags: run.flags,
            recovery_s: None,
            retract_s,
            retract_force_n: Some(run.retract_force_n).filter(|f| f.is_finite()),
            before: [f64::NAN; 2],
            after: [f64::NAN; 2],
        };
    }
    let clean = simulate(class, false, sample_rate_hz, seed);
    let run = simulate(class, true, sample_rate_hz, seed);
    let dt = 1.0 / sample_rate_hz;
    let reference: std::collections::HashMap<u64, (f64, f64)> =
        clean.history.iter().map(|v| (v.0, (v.1, v.2))).collect();
    let within = |v: &(u64, f64, f64)| match reference.get(&v.0) {
        Some(&(c, k)) => (v.1 / c - 1.0).abs() <= 0.05 && (v.2 / k - 1.0).abs() <= 0.05,
        None => false,
    };
    let compared: Vec<&(u64, f64, f64)> = run
        .history
        .iter()
        .filter(|v| reference.contains_key(&v.0))
        .collect();
    let end = run.fault_end.unwrap_or(u64::MAX);
    let last_out = compared
        .iter()
        .rev()
        .find(|v| v.0 >= end && !within(v))
        .map(|v| v.0);
    let recovery_s = match (run.fault_end, compared.last()) {
        (Some(e), Some(last)) if within(last) => {
            Some(last_out.map_or(0.0, |o| (o + 1).saturating_sub(e) as f64 * dt))
        }
        _ => None,
    };
    let first = compared.first().map(|v| v.0);
    let before = first
        .and_then(|n| reference.get(&n))
        .map_or([f64::NAN; 2], |&(c, k)| [c, k]);
    FaultOutcome {
        class,
        bounded: run.unbounded == 0,
        unbounded_samples: run.unbounded,
        max_force_n: run.max_force_n,
        force_limit_n: run.force_limit_n,
        flags: run.flags,
        recovery_s,
        retract_s: None,
        retract_force_n: None,
        before,
        after: compared.last().map_or([f64::NAN; 2], |v| [v.1, v.2]),
    }
}

/// The faults report's `schema_version`.
pub const SCHEMA_VERSION: u32 = 1;

/// The report of `visco faults --json FILE.json`: every run, class by class, seed by seed.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct FaultsReport {
    /// Version of this report's layout (1): raised when a field is removed or renamed or changes
    /// meaning or unit; adding a field keeps it.
    pub schema_version: u32,
    /// Each run's outcome.
    pub runs: Vec<FaultOutcome>,
}
