//! The core's configuration over the wire: which `visco_core::Config` fields the host can
//! set, their parameter ids, how staged values become a validated `Config`, and how the
//! core's records become telemetry frames.
//!
//! This file is self-contained (`visco_core` and `visco_protocol` only): the firmware uses
//! it as `visco_firmware::core_config`, and the host (`visco::replay`) includes the same
//! source file, so both ends build the identical `Config` from the same staged values and
//! the host reference of a replay is bit-identical by construction.
//!
//! ## The configuration
//! [`Config::paper`] at the staged `sample_rate_hz` (default [`DEFAULT_SAMPLE_RATE_HZ`]) is
//! the base; every staged field then replaces that field, and nothing else: values that
//! `paper` derives from a field (the excitation amplitudes from the cantilever, the
//! estimator constants from the sample rate, …) keep their `paper` value unless they are
//! staged too. The sample rate is the exception, as the base is built at it. Validation is
//! the core's own [`Config::validate`], whose errors name the field (`dive.estimator.alpha`);
//! a field that is not a number of the right kind here (an integer, an enum code) is refused
//! the same way, by name.
//!
//! The set is every scalar of `Config` that a user running the instrument may want to
//! change: sample rate, cantilever and tip, the nominal contacts, prefilter, contact
//! detector, approach, converter ranges, the DIVE grid and timing, the SVE raster and depth
//! control, both estimators (with their decimation) and both excitations, and the fault
//! handling (`faults.*`). Parameter `CORE_BASE + i` is
//! `PARAMS[i]`; enums are numeric (see [`PARAMS`]).

use visco_core::{
    Config, ConfigError, DiveRegressor, EstimatorKind, PixelRecord, Record, SveRegressor, TapRecord,
};
use visco_protocol::{param::CORE_BASE, RecordFrame};

/// The loop rate when none is staged (Hz): the rate the firmware's budget is set for.
pub const DEFAULT_SAMPLE_RATE_HZ: f64 = 1e6;

/// The settable fields, by dotted path (the names `ConfigError` uses). Id = `CORE_BASE` +
/// index. Enums: `dive.regressor` 0 = paper, 1 = offset; `sve.regressor` 0 = paper,
/// 1 = decoupled; `*.estimator.kind` 0 = least squares, 1 = gradient.
pub const PARAMS: [&str; 96] = [
    "sample_rate_hz",
    "cantilever.k_n_per_m",
    "cantilever.c_ns_per_m",
    "cantilever.m_kg",
    "tip_radius_m",
    "nominal_dive.k_n_per_m",
    "nominal_dive.c_ns_per_m",
    "nominal_sve.k_n_per_m",
    "nominal_sve.c_ns_per_m",
    "prefilter.lambda_s",
    // 10
    "contact.lowpass_hz",
    "contact.gamma_m",
    "contact.gamma_plus_m",
    "approach.u_start_m",
    "approach.speed_m_per_s",
    "approach.retract_speed_m_per_s",
    "approach.clearance_m",
    "approach.max_travel_m",
    "limits.u_min_m",
    "limits.u_max_m",
    // 20
    "limits.dac_bits",
    "limits.xy_min_m",
    "limits.xy_max_m",
    "limits.xy_dac_bits",
    "limits.d_full_scale_m",
    "dive.nx",
    "dive.ny",
    "dive.x0_m",
    "dive.y0_m",
    "dive.dx_m",
    // 30
    "dive.dy_m",
    "dive.tap_s",
    "dive.move_s",
    "dive.indent_depth_m",
    "dive.settle_s",
    "dive.readout_s",
    "dive.regressor",
    "dive.estimator.kind",
    "dive.estimator.alpha",
    "dive.estimator.beta_per_s",
    // 40
    "dive.estimator.r0",
    "dive.estimator.p0.0",
    "dive.estimator.p0.1",
    "dive.estimator.p0.2",
    "dive.estimator.gamma.0",
    "dive.estimator.gamma.1",
    "dive.estimator.gamma.2",
    "dive.estimator.k_min_n_per_m",
    "dive.estimator.k_max_n_per_m",
    "dive.estimator.c_max_ns_per_m",
    // 50
    "dive.excitation.f1_hz",
    "dive.excitation.f2_hz",
    "dive.excitation.a1_m",
    "dive.excitation.a2_m",
    "dive.excitation.ramp_s",
    "sve.regressor",
    "sve.lines",
    "sve.pixels",
    "sve.x0_m",
    "sve.x1_m",
    // 60
    "sve.y0_m",
    "sve.dy_m",
    "sve.line_period_s",
    "sve.turn_s",
    "sve.settle_s",
    "sve.depth_ref_m",
    "sve.ki_per_s",
    "sve.highpass_hz",
    "sve.estimator.kind",
    "sve.estimator.alpha",
    // 70
    "sve.estimator.beta_per_s",
    "sve.estimator.r0",
    "sve.estimator.p0.0",
    "sve.estimator.p0.1",
    "sve.estimator.p0.2",
    "sve.estimator.gamma.0",
    "sve.estimator.gamma.1",
    "sve.estimator.gamma.2",
    "sve.estimator.k_min_n_per_m",
    "sve.estimator.k_max_n_per_m",
    // 80
    "sve.estimator.c_max_ns_per_m",
    "sve.excitation.f1_hz",
    "sve.excitation.f2_hz",
    "sve.excitation.a1_m",
    "sve.excitation.a2_m",
    "sve.excitation.ramp_s",
    "dive.estimator.decimation",
    "sve.estimator.decimation",
    "faults.spike_dive_m",
    "faults.spike_sve_m",
    // 90
    "faults.hold_s",
    "faults.force_max_n",
    "faults.lost_s",
    "faults.lost_force_n",
    "faults.diverge_memories",
    "faults.residual_ratio",
];

/// How many core parameter ids can be staged (ids `CORE_BASE .. CORE_BASE + MAX_PARAMS`).
pub const MAX_PARAMS: usize = PARAMS.len();

/// The parameter id of a field name.
pub fn param_id(name: &str) -> Option<u16> {
    PARAMS
        .iter()
        .position(|p| *p == name)
        .map(|i| CORE_BASE + i as u16)
}

/// The field name of a parameter id.
pub fn param_name(id: u16) -> Option<&'static str> {
    PARAMS.get(id.checked_sub(CORE_BASE)? as usize).copied()
}

/// Configuration values staged by `SetParam`, applied by `ApplyConfig`.
#[derive(Clone, Copy, Debug)]
pub struct StagedConfig {
    values: [f64; MAX_PARAMS],
    set: u128,
}

impl Default for StagedConfig {
    fn default() -> Self {
        Self::new()
    }
}

impl StagedConfig {
    /// Nothing staged.
    pub const fn new() -> Self {
        Self {
            values: [0.0; MAX_PARAMS],
            set: 0,
        }
    }
    /// Stages a core parameter; false for an id outside the core's range.
    pub fn stage(&mut self, id: u16, value: f64) -> bool {
        let Some(i) = id.checked_sub(CORE_BASE) else {
            return false;
        };
        match self.values.get_mut(i as usize) {
            Some(v) => {
                *v = value;
                self.set |= 1 << i;
                true
            }
            None => false,
        }
    }
    /// Stages a field by name; false for an unknown name.
    pub fn stage_name(&mut self, name: &str, value: f64) -> bool {
        match param_id(name) {
            Some(id) => self.stage(id, value),
            None => false,
        }
    }
    /// A staged value, if set.
    pub fn get(&self, id: u16) -> Option<f64> {
        let i = id.checked_sub(CORE_BASE)? as usize;
        if i >= MAX_PARAMS || self.set & (1u128 << i) == 0 {
            return None;
        }
        self.values.get(i).copied()
    }
    /// The staged (id, value) pairs in id order.
    pub fn iter(&self) -> impl Iterator<Item = (u16, f64)> + '_ {
        (0..MAX_PARAMS as u16)
            .filter_map(move |i| self.get(CORE_BASE + i).map(|v| (CORE_BASE + i, v)))
    }
}

fn reject(field: &'static str, value: f64, reason: &'static str) -> ConfigError {
    ConfigError {
        field,
        value,
        reason,
    }
}

fn integer(field: &'static str, v: f64, lo: u32, hi: u32) -> Result<u32, ConfigError> {
    if v.is_finite() && v == (v as u32) as f64 && v >= lo as f64 && v <= hi as f64 {
        Ok(v as u32)
    } else {
        Err(reject(field, v, "must be a whole number in range"))
    }
}

fn choice(field: &'static str, v: f64) -> Result<bool, ConfigError> {
    if v == 0.0 {
        Ok(false)
    } else if v == 1.0 {
        Ok(true)
    } else {
        Err(reject(field, v, "must be 0 or 1"))
    }
}

fn kind(field: &'static str, v: f64) -> Result<EstimatorKind, ConfigError> {
    Ok(if choice(field, v)? {
        EstimatorKind::Gradient
    } else {
        EstimatorKind::LeastSquares
    })
}

/// Sets field `i` of [`PARAMS`] (not the sample rate, which selects the base).
fn set_field(c: &mut Config, i: usize, v: f64) -> Result<(), ConfigError> {
    let name = PARAMS.get(i).copied().unwrap_or("?");
    let de = &mut c.dive.estimator;
    let dx = &mut c.dive.excitation;
    match i {
        0 => c.sample_rate_hz = v,
        1 => c.cantilever.k_n_per_m = v,
        2 => c.cantilever.c_ns_per_m = v,
        3 => c.cantilever.m_kg = v,
        4 => c.tip_radius_m = v,
        5 => c.nominal_dive.k_n_per_m = v,
        6 => c.nominal_dive.c_ns_per_m = v,
        7 => c.nominal_sve.k_n_per_m = v,
        8 => c.nominal_sve.c_ns_per_m = v,
        9 => c.prefilter.lambda_s = v,
        10 => c.contact.lowpass_hz = v,
        11 => c.contact.gamma_m = v,
        12 => c.contact.gamma_plus_m = v,
        13 => c.approach.u_start_m = v,
        14 => c.approach.speed_m_per_s = v,
        15 => c.approach.retract_speed_m_per_s = v,
        16 => c.approach.clearance_m = v,
        17 => c.approach.max_travel_m = v,
        18 => c.limits.u_min_m = v,
        19 => c.limits.u_max_m = v,
        20 => c.limits.dac_bits = integer(name, v, 2, 24)?,
        21 => c.limits.xy_min_m = v,
        22 => c.limits.xy_max_m = v,
        23 => c.limits.xy_dac_bits = integer(name, v, 2, 24)?,
        24 => c.limits.d_full_scale_m = v,
        25 => c.dive.nx = integer(name, v, 1, 4096)?,
        26 => c.dive.ny = integer(name, v, 1, 4096)?,
        27 => c.dive.x0_m = v,
        28 => c.dive.y0_m = v,
        29 => c.dive.dx_m = v,
        30 => c.dive.dy_m = v,
        31 => c.dive.tap_s = v,
        32 => c.dive.move_s = v,
        33 => c.dive.indent_depth_m = v,
        34 => c.dive.settle_s = v,
        35 => c.dive.readout_s = v,
        36 => {
            c.dive.regressor = if choice(name, v)? {
                DiveRegressor::Offset
            } else {
                DiveRegressor::Paper
            }
        }
        37 => de.kind = kind(name, v)?,
        38 => de.alpha = v,
        39 => de.beta_per_s = v,
        40 => de.r0 = v,
        41 => de.p0[0] = v,
        42 => de.p0[1] = v,
        43 => de.p0[2] = v,
        44 => de.gamma[0] = v,
        45 => de.gamma[1] = v,
        46 => de.gamma[2] = v,
        47 => de.k_min_n_per_m = v,
        48 => de.k_max_n_per_m = v,
        49 => de.c_max_ns_per_m = v,
        50 => dx.f1_hz = v,
        51 => dx.f2_hz = v,
        52 => dx.a1_m = v,
        53 => dx.a2_m = v,
        54 => dx.ramp_s = v,
        _ => return set_sve_field(c, i, name, v),
    }
    Ok(())
}

fn set_sve_field(c: &mut Config, i: usize, name: &'static str, v: f64) -> Result<(), ConfigError> {
    let s = &mut c.sve;
    let se = &mut s.estimator;
    match i {
        55 => {
            s.regressor = if choice(name, v)? {
                SveRegressor::Decoupled
            } else {
                SveRegressor::Paper
            }
        }
        56 => s.lines = integer(name, v, 1, 4096)?,
        57 => s.pixels = integer(name, v, 1, 4096)?,
        58 => s.x0_m = v,
        59 => s.x1_m = v,
        60 => s.y0_m = v,
        61 => s.dy_m = v,
        62 => s.line_period_s = v,
        63 => s.turn_s = v,
        64 => s.settle_s = v,
        65 => s.depth_ref_m = v,
        66 => s.ki_per_s = v,
        67 => s.highpass_hz = v,
        68 => se.kind = kind(name, v)?,
        69 => se.alpha = v,
        70 => se.beta_per_s = v,
        71 => se.r0 = v,
        72 => se.p0[0] = v,
        73 => se.p0[1] = v,
        74 => se.p0[2] = v,
        75 => se.gamma[0] = v,
        76 => se.gamma[1] = v,
        77 => se.gamma[2] = v,
        78 => se.k_min_n_per_m = v,
        79 => se.k_max_n_per_m = v,
        80 => se.c_max_ns_per_m = v,
        81 => s.excitation.f1_hz = v,
        82 => s.excitation.f2_hz = v,
        83 => s.excitation.a1_m = v,
        84 => s.excitation.a2_m = v,
        85 => s.excitation.ramp_s = v,
        86 => c.dive.estimator.decimation = integer(name, v, 1, 64)?,
        87 => se.decimation = integer(name, v, 1, 64)?,
        88 => c.faults.spike_dive_m = v,
        89 => c.faults.spike_sve_m = v,
        90 => c.faults.hold_s = v,
        91 => c.faults.force_max_n = v,
        92 => c.faults.lost_s = v,
        93 => c.faults.lost_force_n = v,
        94 => c.faults.diverge_memories = v,
        95 => c.faults.residual_ratio = v,
        _ => return Err(reject("?", v, "unknown parameter")),
    }
    Ok(())
}

/// `Config::paper` at the staged sample rate with every staged field replaced, validated.
pub fn build_config(staged: &StagedConfig) -> Result<Config, ConfigError> {
    let fs = staged.get(CORE_BASE).unwrap_or(DEFAULT_SAMPLE_RATE_HZ);
    // `Config::paper` needs a usable rate to derive from; `validate` names the field.
    if !(fs.is_finite() && fs > 0.0 && fs <= 1e8) {
        return Err(reject(
            "sample_rate_hz",
            fs,
            "must be a finite number > 0 and at most 100 MHz",
        ));
    }
    let mut c = Config::paper(fs);
    for (id, v) in staged.iter() {
        set_field(&mut c, (id - CORE_BASE) as usize, v)?;
    }
    c.validate()?;
    Ok(c)
}

/// The ADC's metres per code when the board parameter is not set: a 16-bit converter
/// spanning the core's full scale ±`limits.d_full_scale_m` (the simulator's ADC).
pub fn default_adc_metres_per_code(c: &Config) -> f64 {
    c.limits.d_full_scale_m / 32768.0
}

/// A finished tap or pixel as a telemetry frame, taken at loop sample `index`.
pub fn record_frame(index: u32, rec: &Record<f32>) -> RecordFrame {
    match rec {
        Record::Tap(t) => tap_frame(index, t),
        Record::Pixel(p) => pixel_frame(index, p),
    }
}

fn tap_frame(index: u32, t: &TapRecord<f32>) -> RecordFrame {
    RecordFrame {
        index,
        mode: 1,
        number: t.index,
        ix: t.ix,
        iy: t.iy,
        variant: match t.regressor {
            DiveRegressor::Paper => 0,
            DiveRegressor::Offset => 1,
        },
        x_m: t.x_m,
        y_m: t.y_m,
        c_ns_per_m: t.c_ns_per_m,
        k_n_per_m: t.k_n_per_m,
        height_m: t.contact_height_m,
        depth_m: t.depth_m,
        offset_n: t.offset_n,
        centre_m: t.centre_m,
        flags: t.flags,
        samples: t.samples,
    }
}

fn pixel_frame(index: u32, p: &PixelRecord<f32>) -> RecordFrame {
    RecordFrame {
        index,
        mode: 2,
        number: p.line as u32,
        ix: p.pixel,
        iy: p.line,
        variant: p.forward as u8,
        x_m: p.x_m,
        y_m: p.y_m,
        c_ns_per_m: p.c_ns_per_m,
        k_n_per_m: p.k_n_per_m,
        height_m: p.bed_height_m,
        depth_m: p.depth_m,
        offset_n: 0.0,
        centre_m: 0.0,
        flags: p.flags,
        samples: p.samples,
    }
}
