//! The per-sample entry point: [`Controller::step`], called by the firmware's interrupt and by
//! the host simulation alike, with the DIVE and SVE sequencers behind it.
//!
//! ## One sample
//! ```text
//! D_k ─▶ clamp/hold ─▶ Z_k = U_k − D_k ─▶ prefilters (Z: first-order hold, U: zero-order hold)
//!     ─▶ w = (Ms² + Cs + K)Z/Λ − (Cs + K)U/Λ,  φ = [−sZ/Λ, z₀ − Z/Λ, 1]
//!     ─▶ mode: contact detector / estimator / depth controller / excitation / sequencer
//!     ─▶ U_{k+1} on the DAC grid, X, Y ─▶ the board's DACs (held until the next sample)
//! ```
//! `U_k` is the value the previous step returned: the DAC held it over the period that ends at
//! the sample, so the pair (U_k, D_k) describes the same instant. The w of (13) and (16) is the
//! same signal, `M·Z̈ − K·D − C·Ḋ` filtered, written in Z and U because Z is smooth and U is a
//! known staircase (see [`crate::prefilter`]).
//!
//! ## Regressors
//! * SVE (16): `φ = [−sZ/Λ, z₀ − Z/Λ, 1]`, `θ = [c, k, k·(h − z₀)]`. The reference height z₀
//!   (the contact height found when the scan started) only centres the position regressor so
//!   that f32 keeps precision; `ĥ = z₀ + θ̂₃/θ̂₂`.
//! * DIVE, paper (13): `φ = [s·δ/Λ, δ/Λ] = [−sZ/Λ, h − Z/Λ]` with `h` from the contact detector
//!   (for constant h, `h/Λ = h` once the filter has settled).
//! * DIVE, offset: the SVE regressor with z₀ = h. For a fully submerged sphere the element bed
//!   pushes with `Σkᵢ(hᵢ − sᵢ − Z)`, an offset the paper's form cannot represent (it is what
//!   correction (32) undoes afterwards); identifying it gives k without correction and the
//!   footprint's mean height from the dynamics instead of from the threshold crossing.
//!
//! Everything below is straight-line arithmetic over fixed-size arrays: no allocation, no
//! blocking, no panics (indices are loop counters over const-generic arrays).

use crate::config::{Config, ConfigError, DiveRegressor, SveRegressor};
use crate::contact::{ContactDetector, ContactParams, ContactState};
use crate::depth::{DepthController, DepthParams};
use crate::discretize::one_pole_weight;
use crate::estimator::Estimator;
use crate::excitation::{Excitation, ExcitationParams, SineTable, Tone};
use crate::geometry::mean_sag;
use crate::guard::{FaultBits, Guard, GuardParams};
use crate::prefilter::HighPass;
use crate::regressor::{GroupParams, RegressorParams};
#[cfg(not(target_os = "none"))]
use crate::schedule::Staged;
use crate::schedule::{
    Block, BlockResult, EstimatorTask, Sample, SampleSink, Target, TaskParams, ToneAhead,
    SAMPLE_EST, SAMPLE_HP, SAMPLE_HP_REST, TONES_DIVE, TONES_SVE,
};
use crate::units;
use core::num::{NonZeroU32, NonZeroU64};

/// Bits of the status word returned with every step.
pub mod status {
    /// The contact of the current tap or scan is confirmed.
    pub const CONTACT: u32 = 1 << 0;
    /// The excitation envelope is above zero.
    pub const EXCITING: u32 = 1 << 1;
    /// The estimator took this sample (a per-sample update, or into the block).
    pub const ESTIMATING: u32 = 1 << 2;
    /// A record (tap or pixel) is waiting in [`super::Controller::take_record`].
    pub const RECORD_READY: u32 = 1 << 3;
    /// The sequence has finished.
    pub const DONE: u32 = 1 << 4;
    /// D was not finite: the last valid D was used and the estimator skipped.
    pub const INPUT_INVALID: u32 = 1 << 5;
    /// D was at or beyond the ADC's full scale (clamped); the estimator skipped.
    pub const INPUT_SATURATED: u32 = 1 << 6;
    /// U was clamped to the DAC's range.
    pub const U_SATURATED: u32 = 1 << 7;
    /// The depth controller is at an output limit.
    pub const DEPTH_SATURATED: u32 = 1 << 8;
    /// tr P is at R₀ (forgetting paused).
    pub const COV_AT_BOUND: u32 = 1 << 9;
    /// A parameter was projected onto its bound.
    pub const PROJECTED: u32 = 1 << 10;
    /// The estimator rejected an update and reset P.
    pub const EST_RESET: u32 = 1 << 11;
    /// A tap found no contact within its travel.
    pub const NO_CONTACT: u32 = 1 << 12;
    /// The dwell was too short for settle + read-out (slow approach).
    pub const SHORT_DWELL: u32 = 1 << 13;
    /// This sample went into the average of a tap's read-out or of a pixel.
    pub const READOUT: u32 = 1 << 14;
    /// D implied a jump of the tip (a spike): the last good tip position was used.
    pub const INPUT_SPIKE: u32 = 1 << 15;
    /// The static tip force exceeded the limit: the tip was retracted at once.
    pub const FORCE_LIMIT: u32 = 1 << 16;
    /// SVE: the surface was lost (no contact force); the tip is re-approaching.
    pub const CONTACT_LOST: u32 = 1 << 17;
    /// The estimator showed a sustained sign of divergence; P was reset to P₀.
    pub const EST_DIVERGED: u32 = 1 << 18;
    /// Any fault bit.
    pub const FAULTS: u32 = INPUT_INVALID
        | INPUT_SATURATED
        | INPUT_SPIKE
        | FORCE_LIMIT
        | CONTACT_LOST
        | EST_DIVERGED
        | NO_CONTACT;
    /// Shift of the phase code (see [`super::Phase`]) in the status word.
    pub const PHASE_SHIFT: u32 = 24;
}

/// Which experiment runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Dynamic indentation viscoelastic mode.
    Dive,
    /// Scanning viscoelastic mode.
    Sve,
}

/// Commands from the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Start a mode from its beginning.
    Start(Mode),
    /// Stop: excitation off, U held, idle.
    Stop,
}

/// Where the sequencer is (also bits 24.. of the status word).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Phase {
    /// Holding U, nothing running.
    Idle = 0,
    /// Lateral move to the next tap or to the scan start, tip clear of the sample.
    Move = 1,
    /// Lowering U until the contact detector confirms contact.
    Approach = 2,
    /// DIVE: lowering further to the indentation depth.
    Indent = 3,
    /// DIVE: holding the depth with the excitation on; the estimator runs.
    Dwell = 4,
    /// Raising U clear of the sample.
    Retract = 5,
    /// DIVE: waiting for the tap's time slot to end.
    Wait = 6,
    /// SVE: at the first line's start, depth and estimates settling.
    Settle = 7,
    /// SVE: forward line.
    Forward = 8,
    /// SVE: backward line.
    Backward = 9,
    /// SVE: moving to the next line at the line start.
    Turn = 10,
    /// The sequence finished.
    Done = 11,
}

/// The outputs of one sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOut<T> {
    /// U for the next period (m), on the DAC grid.
    pub u_m: T,
    /// Signed DAC code of U relative to mid-scale.
    pub u_code: i32,
    /// Lateral setpoint x (m), on the lateral DAC grid.
    pub x_m: T,
    /// Lateral setpoint y (m).
    pub y_m: T,
    /// Signed DAC code of x relative to mid-scale.
    pub x_code: i32,
    /// Signed DAC code of y relative to mid-scale.
    pub y_code: i32,
    /// Status bits ([`status`]) and the phase code.
    pub status: u32,
}

/// The estimates of one DIVE tap: aggregates over the tip, averaged over the read-out window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TapRecord<T> {
    /// Tap number in the sequence.
    pub index: u32,
    /// Grid column.
    pub ix: u16,
    /// Grid row.
    pub iy: u16,
    /// Lateral position (m).
    pub x_m: T,
    /// Lateral position (m).
    pub y_m: T,
    /// Height at first contact, Z(t₁) (m).
    pub contact_height_m: T,
    /// Aggregate damping ĉ (N·s/m).
    pub c_ns_per_m: T,
    /// Aggregate spring constant k̂ (N/m).
    pub k_n_per_m: T,
    /// θ̂₃ = k̂·(h_bed − z₀) of the offset regressor (N); 0 for the paper's.
    pub offset_n: T,
    /// z₀ = h − indent depth, the centre of the offset regressor (m).
    pub centre_m: T,
    /// Mean depth δ = h − Z over the read-out (m).
    pub depth_m: T,
    /// Regressor the tap used.
    pub regressor: DiveRegressor,
    /// Status bits gathered over the tap (NO_CONTACT, SHORT_DWELL, faults).
    pub flags: u32,
    /// Samples averaged.
    pub samples: u32,
}

impl<T: crate::Real> TapRecord<T> {
    /// The identified height of the element bed under the tip: z₀ + θ̂₃/k̂ for the offset form
    /// (the k-weighted mean of hᵢ − sᵢ, before adding the tip's mean sag), h for the paper's.
    pub fn bed_height_m(&self) -> f64 {
        match self.regressor {
            DiveRegressor::Paper => self.contact_height_m.to_f64(),
            DiveRegressor::Offset => {
                self.centre_m.to_f64() + self.offset_n.to_f64() / self.k_n_per_m.to_f64()
            }
        }
    }
}

/// The estimates of one SVE pixel (one direction of one line), averaged over the pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelRecord<T> {
    /// Line number.
    pub line: u16,
    /// Pixel along the line, 0 at x0.
    pub pixel: u16,
    /// Forward (x0 → x1) or backward.
    pub forward: bool,
    /// Mean lateral position (m).
    pub x_m: T,
    /// Lateral position (m).
    pub y_m: T,
    /// Aggregate damping ĉ (N·s/m).
    pub c_ns_per_m: T,
    /// Aggregate spring constant k̂ (N/m).
    pub k_n_per_m: T,
    /// ĥ (m), the k-weighted mean of hᵢ − sᵢ under the tip: z₀ + θ̂₃/θ̂₂ for the paper's
    /// regressor, Z + F/k̂ for the decoupled one.
    pub bed_height_m: T,
    /// Mean of ĥ − Z, the depth the controller holds (m).
    pub depth_m: T,
    /// Status bits gathered over the pixel.
    pub flags: u32,
    /// Samples averaged.
    pub samples: u32,
}

/// A finished tap or pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Record<T> {
    /// DIVE.
    Tap(TapRecord<T>),
    /// SVE.
    Pixel(PixelRecord<T>),
}

impl<T: crate::Real> Record<T> {
    /// Internal units → SI: lengths and forces × `length` (1e-9), damping × `damping`
    /// (1e-6). The same products, in the same order, that the sequencers computed before
    /// records were kept in internal units, so f32 records are unchanged bit for bit.
    #[inline]
    fn scaled(self, length: T, damping: T) -> Self {
        match self {
            Record::Tap(t) => Record::Tap(TapRecord {
                x_m: t.x_m * length,
                y_m: t.y_m * length,
                contact_height_m: t.contact_height_m * length,
                c_ns_per_m: t.c_ns_per_m * damping,
                offset_n: t.offset_n * length,
                centre_m: t.centre_m * length,
                depth_m: t.depth_m * length,
                ..t
            }),
            Record::Pixel(p) => Record::Pixel(PixelRecord {
                x_m: p.x_m * length,
                y_m: p.y_m * length,
                c_ns_per_m: p.c_ns_per_m * damping,
                bed_height_m: p.bed_height_m * length,
                depth_m: p.depth_m * length,
                ..p
            }),
        }
    }
}

/// A DAC's grid: codes relative to mid-scale.
#[derive(Clone, Copy, Debug)]
struct Dac<T> {
    mid: T,
    lsb: T,
    inv_lsb: T,
    code_min: i32,
    code_max: i32,
    /// `code_max − code_min`: a code is in range when `code − code_min`, as unsigned, is at
    /// most this (one comparison).
    code_span: u32,
}

impl<T: crate::Real> Dac<T> {
    fn new(min_nm: f64, max_nm: f64, bits: u32) -> Self {
        let half = 1i64 << (bits - 1);
        let lsb = (max_nm - min_nm) / (2 * half) as f64;
        Self {
            mid: T::from_f64(0.5 * (min_nm + max_nm)),
            lsb: T::from_f64(lsb),
            inv_lsb: T::from_f64(1.0 / lsb),
            code_min: -half as i32,
            code_max: (half - 1) as i32,
            code_span: (2 * half - 1) as u32,
        }
    }

    /// The nearest code (clamped) and its value; `true` when clamped.
    #[inline(always)]
    fn quantize(&self, v: T) -> (i32, T, bool) {
        // Exact: the DAC's bits are at most `T::CODE_BITS_MAX` (`Controller::new`).
        self.at_code(((v - self.mid) * self.inv_lsb).round_code())
    }

    /// A code (clamped) and its value; `true` when clamped.
    #[inline(always)]
    fn at_code(&self, raw: i32) -> (i32, T, bool) {
        // In range, the usual case: one unsigned comparison instead of the clamp's two and
        // the clamped test (the same code and flag).
        if (raw.wrapping_sub(self.code_min) as u32) <= self.code_span {
            return (raw, self.mid + T::from_i32(raw) * self.lsb, false);
        }
        let code = if raw > self.code_max {
            self.code_max
        } else if raw < self.code_min {
            self.code_min
        } else {
            raw
        };
        (code, self.mid + T::from_i32(code) * self.lsb, code != raw)
    }

    /// A ramp from `from` over `span` in `samples` steps as a line of DAC codes in fixed
    /// point with [`RAMP_FRAC`] fractional bits and ½ added: (at step 0, per step), so that step
    /// t's nearest code (ties up) is `(q0 + dq·t) >> RAMP_FRAC`, in integers (issue 14, round
    /// 16: the SVE pass's x formed this way takes an integer multiply-add where the value, its
    /// offset, its scale and its rounding took ten FPU operations). Formed in f64 once per
    /// pass. A DAC has at most 24 bits (the configuration), so its codes and the line's ends
    /// (a pass may end at the top of the range, one code above the highest) are within
    /// 2²³ + 1: q0 < 2⁶¹·¹, |dq·t| ≤ 2²⁴·2³⁸ = 2⁶² for t ≤ `samples`, and the sum < 2⁶³. dq is
    /// rounded, so step t is within t·2⁻³⁹ of a code of the line.
    fn ramp(&self, from: T, span: T, samples: u32) -> (i64, i64) {
        const Q: f64 = (1u64 << RAMP_FRAC) as f64;
        let lsb = self.lsb.to_f64();
        let c0 = (from.to_f64() - self.mid.to_f64()) / lsb;
        let dq = span.to_f64() / lsb / samples.max(1) as f64 * Q;
        // `as` saturates: a NaN or an absurd line is clamped by `at_code` like any code.
        let dq = if dq < 0.0 { dq - 0.5 } else { dq + 0.5 };
        (((c0 + 0.5) * Q) as i64, dq as i64)
    }
}

/// Fractional bits of [`Dac::ramp`]'s fixed-point codes: 38 keeps a 24-bit DAC's line inside
/// i64 (40 overflowed at the top of its range: the review's catch).
const RAMP_FRAC: u32 = 38;

#[derive(Clone, Copy, Debug)]
struct DiveParams<T> {
    /// Validated ≥ 1: the divisions by it need no zero test (and have no panic path).
    nx: NonZeroU32,
    taps: u32,
    x0: T,
    y0: T,
    dx: T,
    dy: T,
    tap_samples: u32,
    move_samples: u32,
    inv_move: T,
    indent: T,
    settle_samples: u32,
    readout_samples: u32,
    ramp_samples: u32,
    regressor: DiveRegressor,
    exc: ExcitationParams<T>,
    theta0: [T; 3],
    retract_speed: f64,
}

#[derive(Clone, Copy, Debug)]
struct SveParams<T> {
    regressor: SveRegressor,
    lines: u32,
    /// Validated ≥ 1 (see `DiveParams::nx`).
    pixels: NonZeroU32,
    x0: T,
    x1: T,
    y0: T,
    dy: T,
    half_samples: u32,
    turn_samples: u32,
    inv_turn: T,
    settle_samples: u32,
    depth_eff: T,
    depth: DepthParams<T>,
    highpass: T,
    exc: ExcitationParams<T>,
    theta0: [T; 3],
}

/// Everything the loop reads, in internal units, computed once from a validated [`Config`].
#[derive(Clone, Copy, Debug)]
struct Params<T> {
    to_internal: T,
    to_m: T,
    damping_to_si: T,
    reg: RegressorParams<T>,
    contact: ContactParams<T>,
    d_max: T,
    u_dac: Dac<T>,
    xy_dac: Dac<T>,
    u_min: T,
    approach_step: T,
    retract_step: T,
    clearance: T,
    max_travel: T,
    u_start: T,
    dive: DiveParams<T>,
    sve: SveParams<T>,
    guard_dive: GuardParams<T>,
    guard_sve: GuardParams<T>,
    /// The DIVE force limit's low-pass of the deflection per check (the contact detector's
    /// corner at the rate of the checks: one sample in `force_check`).
    force_lowpass: T,
    /// Samples per check of the DIVE force limit (`FaultConfig::force_check_stride` with
    /// blocks, 1 without: the checks' clock is the block clock's tick).
    force_check: u32,
    /// Weight per sample of the slow force low-pass (corner f₂/20, so the tones' swing of the
    /// deflection does not reach the surface check).
    force_slow_weight: T,
    /// SVE: a static force below this is no contact (nN).
    lost_force: T,
    /// Samples per estimator block, per mode (1: the update runs in the loop, per sample).
    dec_dive: u32,
    dec_sve: u32,
}

/// The running mode's per-sample constants (see [`Controller::set_mode`]). `repr(C)` with
/// `last` first: it follows [`Controller::tick`], and the block clock loads both with one
/// `ldrd`.
#[derive(Clone, Copy, Debug)]
#[repr(C)]
struct ModeNow<T> {
    /// Samples per estimator block minus one (saturated): the block clock's last tick, so
    /// that `tick + 1 ≥ dec` is one comparison, and `dec > 1` a test for zero.
    last: u32,
    /// The input check's `spike` and `hold` ([`GuardParams`]).
    spike: T,
    hold: u32,
    /// SVE with blocks and the decoupled regressor.
    sve_blocks: bool,
    /// `sve_blocks`, the surface held, the pixel's sums begun (their base set) and y settled
    /// (`Controller::y_settled`): a pass takes the path whose tests of the regressor, the
    /// block length, the surface, the sums' start and y's cache are known
    /// (`Controller::sve_contact`). Set by a pass's sample that adds to the sums on the
    /// general path; cleared where the sums are (a pixel's end, a pass's start: before any
    /// `set_xy`, which only the move and the turn call), where the surface is lost, and with
    /// the mode.
    sve_fast: bool,
}

const BITS: FaultBits = FaultBits {
    invalid: status::INPUT_INVALID,
    saturated: status::INPUT_SATURATED,
    spike: status::INPUT_SPIKE,
};

/// Sums for a read-out average of [c, k, h, depth]. Values are accumulated as deviations from
/// the first sample so that f32 keeps its precision over tens of thousands of samples.
///
/// With the block estimator θ̂ changes only when a block's result is adopted, so its entries
/// (the first `L` of a sample, [`Self::add_held`]) need no per-sample sums: the loop counts
/// the samples that saw the same θ̂ (`pending`) and [`Self::settle`] adds them as
/// `count·(θ̂ − base)` once per block, before θ̂ changes, with θ̂ as it stood for them (the
/// loop's own θ̂ then, so the loop neither selects nor stores θ̂ per sample). [`Self::add`] is
/// the per-sample form, for the per-sample law (blocks of one), where θ̂ changes every sample.
#[derive(Clone, Copy, Debug, Default)]
struct Accumulator<T> {
    base: [T; 4],
    sum: [T; 4],
    /// Samples added, less the `pending` ones ([`Self::count`]).
    n: u32,
    /// Samples since the θ̂ entries were last added to `sum`, all with the θ̂ that
    /// [`Self::settle`] is given (counted into `n` then: one counter per sample, not two).
    pending: u32,
    flags: u32,
}

impl<T: crate::Real> Accumulator<T> {
    #[inline(always)]
    fn add(&mut self, v: [T; 4], flags: u32) {
        if self.n == 0 {
            self.base = v;
        }
        for i in 0..4 {
            self.sum[i] += v[i] - self.base[i];
        }
        self.n += 1;
        self.flags |= flags;
    }

    /// One sample whose first `L` entries are θ̂ as it stands until the next [`Self::settle`]:
    /// only `v[L..]` is read (the θ̂ entries come with the settle).
    #[inline(always)]
    // Index loops, not `copy_from_slice` or iterators: with those the M7 code of the whole
    // step came out laid out differently (`cargo xtask bench`: SVE scan +5).
    #[allow(clippy::manual_memcpy)]
    fn add_held<const L: usize>(&mut self, v: [T; 4], flags: u32) {
        if self.pending == 0 && self.n == 0 {
            for i in L.min(4)..4 {
                self.base[i] = v[i];
            }
        }
        for i in L.min(4)..4 {
            self.sum[i] += v[i] - self.base[i];
        }
        self.pending += 1;
        self.flags |= flags;
    }

    /// [`Self::add_held`] once samples have been added (the base set) and `flags` are in
    /// the sums' flags already, without counting the sample: the fast paths' caller counts
    /// them by its clock into `pending` (`DiveState::fast_mark`, `SveState::fast_mark`).
    #[inline(always)]
    fn add_uncounted<const L: usize>(&mut self, v: [T; 4]) {
        for i in L.min(4)..4 {
            self.sum[i] += v[i] - self.base[i];
        }
    }

    /// Samples added.
    #[inline(always)]
    fn count(&self) -> u32 {
        self.n + self.pending
    }

    /// The pending samples' θ̂ entries into the sums, `th` the θ̂ they saw (the first `L`
    /// entries used): before θ̂ changes. The first samples' θ̂ is the base, as in [`Self::add`].
    #[inline(always)]
    // Index loops: see `add_held`.
    #[allow(clippy::manual_memcpy)]
    fn settle<const L: usize>(&mut self, th: [T; 3]) {
        if self.pending > 0 {
            if self.n == 0 {
                for i in 0..L.min(3) {
                    self.base[i] = th[i];
                }
            }
            let count = T::from_i32(self.pending as i32);
            for i in 0..L.min(3) {
                self.sum[i] += (th[i] - self.base[i]) * count;
            }
            self.n += self.pending;
            self.pending = 0;
        }
    }

    /// The means, `th` the θ̂ of the samples not settled yet ([`Self::settle`]).
    fn mean<const L: usize>(&self, th: [T; 3]) -> [T; 4] {
        let mut acc = *self;
        acc.settle::<L>(th);
        let mut m = acc.base;
        if acc.n > 0 {
            let inv = T::ONE / T::from_i32(acc.n as i32);
            for i in 0..4 {
                m[i] += acc.sum[i] * inv;
            }
        }
        m
    }

    fn clear(&mut self) {
        *self = Self::default();
    }
}

#[derive(Clone, Copy, Debug)]
struct DiveState<T> {
    tap: u32,
    t: u32,
    dwell_end: u32,
    /// `dwell_end − ramp_samples` (saturated): where the excitation ramps out, one comparison
    /// per sample instead of a sum and two.
    ramp_from: u32,
    estimate_from: u32,
    readout_from: u32,
    /// The read-out's steady stretch with blocks, `fast_from ≤ t < fast_from + fast_len`:
    /// from the sample after the read-out's first (its sums started, their base set and
    /// `ESTIMATING` in their flags) to `ramp_from`, where a good sample estimates, is read out
    /// and does not ramp. Tested as one unsigned comparison (`t − fast_from < fast_len`)
    /// instead of three (the estimating sample, the read-out, the ramp-out) and the sums'
    /// start; empty (`fast_len` 0) until the read-out's first sample and with blocks of one.
    fast_from: u32,
    fast_len: u32,
    /// The stretch's samples taken by the fast path are not counted there (issue 14, round
    /// 15: one load, add and store per sample less): they are the clocks after this one up
    /// to the next sample that is not (which counts them, [`Controller::dive_fold_in`]) or
    /// up to the clock when the sums are read between two samples
    /// ([`Controller::dive_fold_between`]). Read only while `fast_len` > 0.
    fast_mark: u32,
    /// `readout_from − estimate_from` with blocks, 0 with blocks of one: the estimating
    /// stretch before the read-out, `estimate_from ≤ t < readout_from` (≤ `ramp_from`), where
    /// a good sample estimates only, tested as one comparison.
    estimate_len: u32,
    u_cmd: T,
    u_safe: T,
    approach_from: T,
    x_from: T,
    y_from: T,
    x_to: T,
    y_to: T,
    h: T,
    z0: T,
    /// The regressor's reference for the tap, set with the dwell: h (the paper's φ), or the
    /// target tip position z₀ = h − indent (the offset regressor).
    r: T,
    d_free: T,
    /// The highest low-passed deflection at which the force limit fires, for `d_free`
    /// ([`crate::guard::force_limit_lp`]).
    force_lp_max: T,
    theta_warm: [T; 3],
    acc: Accumulator<T>,
    flags: u32,
}

#[derive(Clone, Copy, Debug)]
struct SveState<T> {
    line: u32,
    t: u32,
    z0: T,
    d_free: T,
    u_cmd: T,
    approach_from: T,
    pixel: u32,
    next_boundary: u32,
    acc: Accumulator<T>,
    /// As `DiveState::fast_mark` (issue 14, round 15): the samples of the pass's fast path
    /// (`ModeNow::sve_fast`, `Hot::SvePass`) are not counted there; they are the clocks after
    /// this one, counted by [`Controller::sve_fold`] where the fast path ends or the sums are
    /// read. Read only while `ModeNow::sve_fast`.
    fast_mark: u32,
    x_acc: T,
    /// The pass's ramp in the lateral DAC's codes ([`Dac::ramp`]), set when it begins: from x0
    /// to x1 forward, back backward; sample t of the pass is at code
    /// `(x_q0 + x_dq·t) >> RAMP_FRAC`.
    x_q0: i64,
    x_dq: i64,
    /// The surface was lost (or the force limit hit): re-approaching while the scan goes on.
    lost: bool,
    reapproach_from: T,
    /// The static force low-passed again below the tones (nN): the surface check's input.
    force_slow: T,
    /// While re-approaching: the slow force has been below the contact threshold (the tip
    /// really is off the surface; a contact found before that is the old one, still decaying).
    left: bool,
}

/// The usual paths of a sample ([`Controller::update_hot`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
enum Hot {
    /// Through the mode's and the phase's dispatch.
    None,
    /// No mode: U held.
    Stopped,
    /// DIVE, dwelling.
    DiveDwell,
    /// SVE, a pass on its fast path (`ModeNow::sve_fast`).
    SvePass,
}

/// The identification core's per-sample state machine.
///
/// `repr(C)` keeps the fields in this order: the per-sample state first, then the constants,
/// then what the loop touches rarely (the configuration, the estimator task's copy, the
/// block hand-over), so that the hot fields sit within the reach of the M7's immediate-offset
/// loads (`vldr`: ±1 020 bytes) from the structure's base instead of each needing an address
/// computed first.
#[derive(Clone, Debug)]
#[repr(C)]
pub struct Controller<T> {
    mode: Option<Mode>,
    phase: Phase,
    /// The sample's usual path, kept with the mode, the phase and `ModeNow::sve_fast`
    /// ([`Self::update_hot`]): one byte dispatches it where the mode and the phase took two.
    hot: Hot,
    /// `set_x_code_same_y` would leave y as it is: y and its code are `y_quantized`'s value and
    /// code, and quantising that value gives it back. Cleared where y is set (`set_xy`).
    y_settled: bool,
    u: T,
    u_code: i32,
    x: T,
    y: T,
    x_code: i32,
    y_code: i32,
    /// The running mode's DIVE force limit stride minus one (0 or 1; 0 in SVE): a sample
    /// whose block clock tick has these bits set is between two of its checks. Set with
    /// [`Self::now`] by [`Self::set_mode`]; kept here, just before `tick`, so that the DIVE
    /// paths' test loads both with one `ldrd` (issue 14, round 18), as the block clock loads
    /// `tick` and `now.last`.
    check_mask: u32,
    /// The block clock: counts loop samples, 0 at the first sample of a block.
    tick: u32,
    /// What the running mode (DIVE when stopped) sets per sample: its block length and its
    /// input check's constants, kept here by [`Self::set_mode`] so that `step` does not pick
    /// them by mode every sample.
    now: ModeNow<T>,
    /// Status bits of the result adopted this sample.
    adopted: u32,
    guard: Guard<T>,
    /// Z = U − D of the last sample (the tip position, not prefiltered: the prefilters run in
    /// the estimator task).
    z: T,
    contact: ContactDetector<T>,
    exc: Excitation<T>,
    /// θ̂ of the two- and three-parameter estimators as the loop uses them.
    theta2: [T; 2],
    theta3: [T; 3],
    /// The block clock's value at which the block's own samples begin: 0, or the step of the
    /// last restart in it (1 in the first block, whose clock starts at 1). While a mode runs
    /// every step hands one sample to the sink, so the block's samples are the steps since
    /// then less the stopped ones (`unfed`): no count per sample (it duplicated the sink's).
    block_from: u32,
    /// Steps since `block_from` that handed no sample (the core stopped, with blocks).
    unfed: u32,
    /// Samples handed over before `block_from` and not in a header yet: those of a block left
    /// open when the blocks stopped (a mode with blocks of one, whose clock stands still),
    /// carried until the blocks run again (`Self::handed`).
    carry: u32,
    /// The steps of the block just closed ([`Self::block_due`]).
    closed_steps: u32,
    /// Samples handed over before a restart and not yet accounted for by a block header: the
    /// next header tells the task to discard them.
    skip_n: u32,
    depth: DepthController<T>,
    dive: DiveState<T>,
    sve: SveState<T>,
    p: Params<T>,
    /// The last y quantised by `set_x_code_same_y`: (input, code, value).
    y_quantized: (T, i32, T),
    record: Option<Record<T>>,
    target: Target,
    /// A restart (θ̂₀) and a watch restart to send with the next block.
    pending_restart: Option<[T; 3]>,
    pending_watch: bool,
    /// Bumped by every restart: results of older blocks are dropped.
    epoch: u32,
    /// The host's in-line result, adopted at the next block close. Not on the firmware
    /// (bare metal: its estimator interrupt returns the results), nor `host_stage`.
    #[cfg(not(target_os = "none"))]
    inflight: Option<BlockResult<T>>,
    /// The estimators (per sample with blocks of 1; else the host's in-line estimator task,
    /// and on the firmware only a copy that gives the restarts' projected θ̂₀).
    task: EstimatorTask<T>,
    /// The host's in-line task's samples of the block being accumulated
    /// ([`Self::step_internal`]; on the firmware they go to the estimator task's buffers, and
    /// its 1 KiB would sit unused in the loop's RAM).
    #[cfg(not(target_os = "none"))]
    host_stage: Staged<T>,
    cfg: Config,
}

fn samples(seconds: f64, fs: f64) -> u32 {
    let n = seconds * fs + 0.5;
    if n < 1.0 {
        1
    } else {
        n as u32
    }
}

impl<T: SineTable> Controller<T> {
    /// Validate `cfg` and build a controller, idle, with U at the approach start.
    pub fn new(cfg: &Config) -> Result<Self, ConfigError> {
        cfg.validate()?;
        // The number type rounds onto a DAC's grid exactly up to its `CODE_BITS_MAX` (f32: 22
        // bits, beyond which its own spacing reaches the code's).
        for (field, bits) in [
            ("limits.dac_bits", cfg.limits.dac_bits),
            ("limits.xy_dac_bits", cfg.limits.xy_dac_bits),
        ] {
            if bits > T::CODE_BITS_MAX {
                return Err(ConfigError {
                    field,
                    value: bits as f64,
                    reason: "too many bits for this build's number type (f32: at most 22)",
                });
            }
        }
        let fs = cfg.sample_rate_hz;
        let t = |v: f64| T::from_f64(v);
        let nm = 1.0 / units::LENGTH;
        let period_us = 1e6 / fs;
        let r_nm = cfg.tip_radius_m * nm;

        let u_span = cfg.limits.u_max_m - cfg.limits.u_min_m;
        let f = &cfg.faults;
        // The DIVE force limit's stride: its clock is the block clock's tick, which stands
        // still with blocks of one.
        let force_check = if cfg.dive.estimator.decimation > 1 {
            f.force_check_stride.max(1)
        } else {
            1
        };
        let guard = |spike_m: f64, e: &crate::config::EstimatorConfig| {
            let dec = e.decimation.max(1) as f64;
            let updates_per_memory = fs / (e.beta_per_s * dec);
            GuardParams {
                spike: t(spike_m * nm),
                hold: samples(f.hold_s, fs),
                force_max: t(f.force_max_n / units::FORCE),
                // `samples` is ≥ 1.
                lost: NonZeroU32::new(samples(f.lost_s, fs)).unwrap_or(NonZeroU32::MIN),
                diverge: (f.diverge_memories * updates_per_memory).max(1.0) as u32,
                residual_ratio: t(f.residual_ratio),
                // The running means of |e| and |w| remember one estimator memory.
                mean_weight: t((1.0 / updates_per_memory).min(1.0)),
            }
        };
        let exc = |e: &crate::config::ExcitationConfig| ExcitationParams {
            tone1: Tone::new(e.f1_hz, fs, t(e.a1_m * nm)),
            tone2: Tone::new(e.f2_hz, fs, t(e.a2_m * nm)),
            ramp_step: t(1.0 / (e.ramp_s * fs)),
        };

        let d = &cfg.dive;
        let n_d = cfg.nominal_dive;
        let k_d = n_d.k_n_per_m / units::STIFFNESS;
        let c_d = n_d.c_ns_per_m / units::DAMPING;
        let theta0_dive = match d.regressor {
            // The paper's form identifies k·(δ − R/3)/δ (Appendix A).
            DiveRegressor::Paper => {
                let delta = d.indent_depth_m * nm;
                [
                    t(c_d),
                    t(k_d * (delta - mean_sag(r_nm, delta)) / delta),
                    T::ZERO,
                ]
            }
            // Centred at z₀ = h − indent: θ₃ = k·(h_bed − z₀) ≈ k·(indent − R/3).
            DiveRegressor::Offset => [
                t(c_d),
                t(k_d),
                t(k_d * (d.indent_depth_m * nm - r_nm / 3.0)),
            ],
        };
        let s = &cfg.sve;
        let n_s = cfg.nominal_sve;
        let k_s = n_s.k_n_per_m / units::STIFFNESS;
        let sag_ref = mean_sag(r_nm, s.depth_ref_m * nm);
        let half = (s.line_period_s - s.turn_s) / 2.0;
        let exc_margin_sve = (s.excitation.a1_m + s.excitation.a2_m) * nm;

        let p = Params {
            to_internal: t(nm),
            to_m: t(units::LENGTH),
            damping_to_si: t(units::DAMPING),
            reg: RegressorParams::new(
                cfg.cantilever.m_kg / units::MASS,
                cfg.cantilever.c_ns_per_m / units::DAMPING,
                cfg.cantilever.k_n_per_m / units::STIFFNESS,
                cfg.prefilter.lambda_s / units::TIME,
                period_us,
            ),
            contact: ContactParams {
                lowpass: t(one_pole_weight(
                    2.0 * core::f64::consts::PI * cfg.contact.lowpass_hz / fs,
                )),
                gamma: t(cfg.contact.gamma_m * nm),
                gamma_plus: t(cfg.contact.gamma_plus_m * nm),
            },
            d_max: t(cfg.limits.d_full_scale_m * nm),
            u_dac: Dac::new(
                cfg.limits.u_min_m * nm,
                cfg.limits.u_max_m * nm,
                cfg.limits.dac_bits,
            ),
            xy_dac: Dac::new(
                cfg.limits.xy_min_m * nm,
                cfg.limits.xy_max_m * nm,
                cfg.limits.xy_dac_bits,
            ),
            u_min: t(cfg.limits.u_min_m * nm),
            approach_step: t(cfg.approach.speed_m_per_s / fs * nm),
            retract_step: t(cfg.approach.retract_speed_m_per_s / fs * nm),
            clearance: t(cfg.approach.clearance_m * nm),
            max_travel: t(cfg.approach.max_travel_m * nm),
            u_start: t(cfg.approach.u_start_m * nm),
            dive: DiveParams {
                nx: NonZeroU32::new(d.nx).unwrap_or(NonZeroU32::MIN),
                taps: d.nx * d.ny,
                x0: t(d.x0_m * nm),
                y0: t(d.y0_m * nm),
                dx: t(d.dx_m * nm),
                dy: t(d.dy_m * nm),
                tap_samples: samples(d.tap_s, fs),
                move_samples: samples(d.move_s, fs),
                inv_move: t(1.0 / samples(d.move_s, fs) as f64),
                indent: t(d.indent_depth_m * nm),
                settle_samples: samples(d.settle_s, fs),
                readout_samples: samples(d.readout_s, fs),
                ramp_samples: samples(d.excitation.ramp_s, fs),
                regressor: d.regressor,
                exc: exc(&d.excitation),
                theta0: theta0_dive,
                retract_speed: cfg.approach.retract_speed_m_per_s / fs * nm,
            },
            sve: SveParams {
                regressor: s.regressor,
                lines: s.lines,
                pixels: NonZeroU32::new(s.pixels).unwrap_or(NonZeroU32::MIN),
                x0: t(s.x0_m * nm),
                x1: t(s.x1_m * nm),
                y0: t(s.y0_m * nm),
                dy: t(s.dy_m * nm),
                half_samples: samples(half, fs),
                turn_samples: samples(s.turn_s, fs),
                inv_turn: t(1.0 / samples(s.turn_s, fs) as f64),
                settle_samples: samples(s.settle_s, fs),
                depth_eff: t((s.depth_ref_m * nm) - sag_ref),
                depth: DepthParams {
                    ki_period: t(s.ki_per_s / fs),
                    u_min: t(cfg.limits.u_min_m * nm + exc_margin_sve),
                    u_max: t(cfg.limits.u_max_m * nm - exc_margin_sve),
                },
                // The high-passes run at the loop rate (they feed every sample of a block).
                highpass: HighPass::coefficient(s.highpass_hz, fs),
                exc: exc(&s.excitation),
                // Centred at the slow tip position: θ₃ = k·(h_bed − Z_s), zero at first contact;
                // the depth controller then takes it to k·(δ_ref − s̄).
                theta0: [t(n_s.c_ns_per_m / units::DAMPING), t(k_s), T::ZERO],
            },
            guard_dive: guard(cfg.faults.spike_dive_m, &d.estimator),
            guard_sve: guard(cfg.faults.spike_sve_m, &s.estimator),
            force_lowpass: t(one_pole_weight(
                2.0 * core::f64::consts::PI * cfg.contact.lowpass_hz * f64::from(force_check) / fs,
            )),
            force_check,
            force_slow_weight: t(one_pole_weight(
                2.0 * core::f64::consts::PI * s.excitation.f2_hz / 20.0 / fs,
            )),
            lost_force: t(cfg.faults.lost_force_n / units::FORCE),
            dec_dive: d.estimator.decimation.max(1),
            dec_sve: s.estimator.decimation.max(1),
        };
        let u0 = p.u_start;
        let (u_code, u, _) = p.u_dac.quantize(u0);
        let (x_code, x, _) = p.xy_dac.quantize(p.dive.x0);
        let (y_code, y, _) = p.xy_dac.quantize(p.dive.y0);
        let dive = DiveState {
            tap: 0,
            t: 0,
            dwell_end: 0,
            ramp_from: 0,
            estimate_from: 0,
            readout_from: 0,
            fast_from: 0,
            fast_len: 0,
            fast_mark: 0,
            estimate_len: 0,
            u_cmd: u,
            u_safe: u,
            approach_from: u,
            x_from: x,
            y_from: y,
            x_to: x,
            y_to: y,
            h: T::ZERO,
            z0: T::ZERO,
            r: T::ZERO,
            d_free: T::ZERO,
            force_lp_max: crate::guard::force_limit_lp(
                p.reg.stiffness,
                T::ZERO,
                p.guard_dive.force_max,
            ),
            theta_warm: p.dive.theta0,
            acc: Accumulator::default(),
            flags: 0,
        };
        let sve = SveState {
            line: 0,
            t: 0,
            z0: T::ZERO,
            d_free: T::ZERO,
            u_cmd: u,
            approach_from: u,
            pixel: 0,
            next_boundary: 0,
            acc: Accumulator::default(),
            fast_mark: 0,
            x_acc: T::ZERO,
            x_q0: 0,
            x_dq: 0,
            lost: false,
            force_slow: T::ZERO,
            left: false,
            reapproach_from: u,
        };
        // Stopped: DIVE's constants, as `set_mode(None)` gives.
        let now = ModeNow {
            last: p.dec_dive.saturating_sub(1),
            spike: p.guard_dive.spike,
            hold: p.guard_dive.hold,
            sve_blocks: false,
            sve_fast: false,
        };
        // The sums' strides (1 without blocks: every sample is the block).
        let (sdi, ssi) = (
            d.estimator.stride_in_blocks(),
            s.estimator.stride_in_blocks(),
        );
        let (sd, ss) = (f64::from(sdi), f64::from(ssi));
        let task = EstimatorTask::new(
            TaskParams {
                dive2: d.estimator.params(fs, u_span),
                dive3: d.estimator.params(fs, u_span),
                sve2: s.estimator.params(fs, u_span),
                sve3: s.estimator.params(fs, u_span),
                guard_dive: p.guard_dive,
                guard_sve: p.guard_sve,
                // 1/T and α/T of the loop period: a block sample's weight T/m²; with a
                // stride of the sums, of `stride` loop periods (one sample in the sums for
                // `stride` of the block's: the same information per unit time).
                acc_dive: (
                    t(1.0 / (period_us * sd)),
                    t(d.estimator.alpha / (period_us * sd)),
                ),
                acc_sve: (
                    t(1.0 / (period_us * ss)),
                    t(s.estimator.alpha / (period_us * ss)),
                ),
                stride_mask_dive: sdi - 1,
                stride_mask_sve: ssi - 1,
                reg: p.reg,
                highpass: p.sve.highpass,
                exc_dive: p.dive.exc,
                exc_sve: p.sve.exc,
            },
            GroupParams::new(cfg.prefilter.lambda_s / units::TIME, period_us),
            p.dive.theta0,
            u,
        );
        let th2 = task.estimator2().theta();
        Ok(Self {
            task,
            theta2: th2,
            theta3: task.estimator3().theta(),
            // The clock's first step is 1 (`block_due` from 0).
            block_from: 1,
            unfed: 0,
            carry: 0,
            closed_steps: 0,
            skip_n: 0,
            #[cfg(not(target_os = "none"))]
            host_stage: Staged::default(),
            target: Target::Dive3,
            pending_restart: None,
            pending_watch: false,
            epoch: 0,
            #[cfg(not(target_os = "none"))]
            inflight: None,
            adopted: 0,
            depth: DepthController::new(u),
            p,
            cfg: *cfg,
            mode: None,
            now,
            phase: Phase::Idle,
            hot: Hot::Stopped,
            y_settled: false,
            u,
            u_code,
            x,
            y,
            x_code,
            y_code,
            y_quantized: (y, p.xy_dac.quantize(y).0, p.xy_dac.quantize(y).1),
            guard: Guard::default(),
            // Stopped: DIVE's, as `now`.
            check_mask: p.force_check - 1,
            tick: 0,
            z: u,
            contact: ContactDetector::new(T::ZERO),
            // Its held status bits (`Excitation::held_mut`): the phase bits of `Phase::Idle`
            // (0), no record, not sounding. They are set where the phase or the record changes
            // ([`Self::set_phase`], [`Self::set_record`]): one load per sample instead of
            // testing the record and shifting the phase.
            exc: Excitation::default(),
            dive,
            sve,
            record: None,
        })
    }

    /// The validated configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// The running mode, if any.
    pub fn mode(&self) -> Option<Mode> {
        self.mode
    }

    /// Where the sequencer is.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The U currently applied (m).
    pub fn u_m(&self) -> T {
        self.u * self.p.to_m
    }

    /// U, X and Y of the last step in metres: [`StepOut`]'s `u_m`, `x_m`, `y_m`, the same
    /// products. (The firmware's telemetry takes them here, only when it sends them: read from
    /// the step's output, their loads were hoisted into every sample.)
    #[inline(always)]
    pub fn outputs_m(&self) -> [T; 3] {
        [
            self.u * self.p.to_m,
            self.x * self.p.to_m,
            self.y * self.p.to_m,
        ]
    }

    /// Carry out a command from the host.
    pub fn command(&mut self, cmd: Command) {
        match cmd {
            Command::Stop => {
                self.set_mode(None, true);
                self.set_phase(Phase::Idle);
                self.exc.silence();
            }
            Command::Start(Mode::Dive) => {
                self.set_mode(Some(Mode::Dive), true);
                let p = &self.p.dive;
                self.dive.tap = 0;
                self.dive.t = 0;
                self.dive.u_safe = self.p.u_start;
                self.dive.u_cmd = self.p.u_start;
                self.dive.x_from = self.x;
                self.dive.y_from = self.y;
                self.dive.x_to = p.x0;
                self.dive.y_to = p.y0;
                self.dive.theta_warm = p.theta0;
                self.dive.flags = 0;
                self.exc.silence();
                self.set_phase(Phase::Move);
            }
            Command::Start(Mode::Sve) => {
                self.set_mode(Some(Mode::Sve), true);
                self.sve.line = 0;
                self.sve.t = 0;
                self.sve.u_cmd = self.p.u_start;
                self.dive.x_from = self.x;
                self.dive.y_from = self.y;
                self.exc.silence();
                self.set_phase(Phase::Move);
            }
        }
    }

    /// U for the next period in internal units (nm).
    pub fn u_internal(&self) -> T {
        self.u
    }

    /// The lateral setpoints in internal units (nm).
    pub fn xy_internal(&self) -> (T, T) {
        (self.x, self.y)
    }

    /// The finished tap or pixel, if one is waiting (status bit RECORD_READY), in SI.
    #[inline]
    pub fn take_record(&mut self) -> Option<Record<T>> {
        let (to_m, to_si) = (self.p.to_m, self.p.damping_to_si);
        *self.exc.held_mut() &= !status::RECORD_READY;
        self.record.take().map(|r| r.scaled(to_m, to_si))
    }

    /// [`Self::take_record`] in the core's internal units (nm, nN, nN·µs/nm, N/m: the fields
    /// named `_m` hold nm, `offset_n` nN, `c_ns_per_m` nN·µs/nm): what a fixed-point caller
    /// reads, as no Q format holds the SI factors (see [`crate::fixed`]).
    pub fn take_record_internal(&mut self) -> Option<Record<T>> {
        *self.exc.held_mut() &= !status::RECORD_READY;
        self.record.take()
    }

    /// The current estimate in SI: aggregate ĉ (N·s/m), k̂ (N/m), and the bed height ĥ (m)
    /// where the mode identifies it (SVE and DIVE offset), else the contact height.
    #[inline(always)]
    pub fn estimates(&self) -> (T, T, T) {
        let (c, k, h) = self.estimates_internal();
        (c * self.p.damping_to_si, k, h * self.p.to_m)
    }

    /// [`Self::estimates`] in the core's internal units ([`crate::units`]: ĉ in nN·µs/nm, k̂ in
    /// nN/nm = N/m, ĥ in nm): what a fixed-point caller reads, as no Q format holds the SI
    /// factors.
    pub fn estimates_internal(&self) -> (T, T, T) {
        let p = &self.p;
        match self.mode {
            Some(Mode::Dive) if p.dive.regressor == DiveRegressor::Paper => {
                let th = self.theta2;
                (th[0], th[1], self.dive.h)
            }
            Some(Mode::Dive) => {
                let th = self.theta3;
                (th[0], th[1], (self.dive.z0 + th[2] / th[1]))
            }
            Some(Mode::Sve) | None if p.sve.regressor == SveRegressor::Decoupled => {
                let th = self.theta2;
                let force = p.reg.stiffness * (self.sve.d_free - self.contact.lowpassed());
                (th[0], th[1], (self.z + force / th[1]))
            }
            _ => {
                let th = self.theta3;
                (th[0], th[1], (self.sve.z0 + th[2] / th[1]))
            }
        }
    }

    /// Read access to the three-parameter estimator (tests, telemetry).
    pub fn estimator3(&self) -> &Estimator<T, 3> {
        self.task.estimator3()
    }

    /// Read access to the two-parameter estimator (tests, telemetry).
    pub fn estimator2(&self) -> &Estimator<T, 2> {
        self.task.estimator2()
    }

    /// A copy of the estimator task as built (the firmware's lower-priority task runs it).
    pub fn estimator_task(&self) -> EstimatorTask<T> {
        self.task
    }

    /// The block clock, one tick per loop sample: call exactly once before each
    /// [`Self::step_loop`] (as [`Self::step_internal`] does). True when that step closes a
    /// block: adopt the result of the block before ([`Self::deliver`]) and take the block
    /// ([`Self::close_block`]) first. Always false with blocks of one sample. (The step
    /// advanced the clock itself until round 5; the caller's test of it read the same two
    /// words again.)
    #[inline(always)]
    pub fn block_due(&mut self) -> bool {
        let last = self.now.last;
        let tick = self.tick;
        // A block closes at the first sample of the next.
        if tick >= last {
            self.tick = 0;
            self.closed_steps = tick.wrapping_add(1);
            last > 0
        } else {
            self.tick = tick + 1;
            false
        }
    }

    /// [`Self::block_due`]'s usual case alone: the block clock advanced and true, where the
    /// next step does not close a block; false (the clock as it was) where it may, for the
    /// caller to call [`Self::block_due`] then (issue 14, round 19: the firmware's block close
    /// goes out of line whole, the usual sample falls through).
    #[inline(always)]
    pub fn block_continues(&mut self) -> bool {
        let tick = self.tick;
        if tick >= self.now.last {
            return false;
        }
        self.tick = tick + 1;
        true
    }

    /// [`Self::block_due`] where [`Self::block_continues`] returned false (the clock at the
    /// block's last tick, or blocks of one): its close branch without its test again.
    #[inline(always)]
    pub fn block_closes(&mut self) -> bool {
        let last = self.now.last;
        self.closed_steps = self.tick.wrapping_add(1);
        self.tick = 0;
        last > 0
    }

    /// The sequencer's phase, and the status word's phase bits with it.
    #[inline(always)]
    fn set_phase(&mut self, p: Phase) {
        self.phase = p;
        let held = self.exc.held_mut();
        *held = (*held & !(0xFF << status::PHASE_SHIFT)) | ((p as u32) << status::PHASE_SHIFT);
        self.update_hot();
    }

    /// `ModeNow::sve_fast`, and the usual path with it.
    #[inline(always)]
    fn set_sve_fast(&mut self, fast: bool) {
        if fast {
            // This sample is counted (`add_held`); the fast path's from the next
            // (`SveState::fast_mark`). Where it is cleared, the callers have counted them.
            self.sve.fast_mark = self.sve.t;
        }
        self.now.sve_fast = fast;
        self.update_hot();
    }

    /// The SVE pass's fast-path samples through clock `upto` into the sums' count
    /// (`SveState::fast_mark`), while the fast path is on.
    #[inline(always)]
    fn sve_fold(&mut self, upto: u32) {
        if self.now.sve_fast {
            let s = &mut self.sve;
            s.acc.pending = s.acc.pending.wrapping_add(upto.wrapping_sub(s.fast_mark));
            s.fast_mark = upto;
        }
    }

    /// The usual path from the mode, the phase and `ModeNow::sve_fast`: where any of them
    /// changes, and where a result's status bits are adopted and taken (`adopted`).
    #[inline(always)]
    fn update_hot(&mut self) {
        self.hot = match (self.mode, self.phase) {
            // A sample with adopted bits takes the general path, which reports them (issue
            // 14, round 15): the usual paths neither read nor clear `adopted`.
            _ if self.adopted != 0 => Hot::None,
            // The dwell's path adds to t without saturating (`step_loop`): from below u32::MAX.
            (Some(Mode::Dive), Phase::Dwell) if self.dive.t != u32::MAX => Hot::DiveDwell,
            (Some(Mode::Sve), Phase::Forward | Phase::Backward) if self.now.sve_fast => {
                Hot::SvePass
            }
            (None, _) => Hot::Stopped,
            _ => Hot::None,
        };
    }

    /// A finished tap or pixel to take, and `RECORD_READY` with it.
    #[inline(always)]
    fn set_record(&mut self, r: Record<T>) {
        self.record = Some(r);
        *self.exc.held_mut() |= status::RECORD_READY;
    }

    /// Samples handed over since the block's start or its last restart, up to the step whose
    /// clock is `upto` (not counting it), while the blocks run: every step of a running mode
    /// hands one sample over, the stopped ones (`unfed`) none. (With blocks of one none does,
    /// the clock stands at 0 and the count is `carry`.)
    #[inline(always)]
    fn handed(&self, upto: u32) -> u32 {
        self.carry
            .wrapping_add(upto)
            .wrapping_sub(self.block_from)
            .wrapping_sub(self.unfed)
    }

    /// The running mode, and its per-sample constants with it. `between`: called between
    /// two steps (a command), not inside one (before that step hands its sample over).
    fn set_mode(&mut self, mode: Option<Mode>, between: bool) {
        // `now` is set anew below (`sve_fast` cleared): the pass's fast-path samples so far
        // counted first (between two samples, or within one off the fast path, which
        // counted them already).
        self.sve_fold(self.sve.t);
        let was_blocks = self.now.last > 0;
        self.mode = mode;
        let (gp, dec, check) = match mode {
            Some(Mode::Sve) => (&self.p.guard_sve, self.p.dec_sve, 1),
            _ => (&self.p.guard_dive, self.p.dec_dive, self.p.force_check),
        };
        self.now = ModeNow {
            last: dec.saturating_sub(1),
            spike: gp.spike,
            hold: gp.hold,
            sve_blocks: mode == Some(Mode::Sve)
                && dec > 1
                && matches!(self.p.sve.regressor, SveRegressor::Decoupled),
            sve_fast: false,
        };
        self.check_mask = check - 1;
        // The block count across a change between blocks and blocks of one (`handed`): the
        // blocks stop with the samples handed so far carried (up to this step, or through the
        // last one when between steps); they start again from the clock's next step when
        // between steps (`block_due` before it advances the clock, which blocks of one keep
        // at 0), or from this step's.
        let blocks = self.now.last > 0;
        let here = self.tick.wrapping_add(u32::from(between));
        if was_blocks && !blocks {
            self.carry = self.handed(here);
            self.block_from = 0;
            self.unfed = 0;
        } else if !was_blocks && blocks {
            self.block_from = here;
            self.unfed = 0;
        }
        // The input check's steady path keeps the last `spike` (`Guard::leave_steady`); the
        // general path computes the same.
        self.guard.leave_steady();
        self.update_hot();
    }

    /// Closes the block handed over so far and gives its header to `send` (the firmware: a
    /// queue's `enqueue`; the block's samples went to the sink of [`Self::step_loop`] already);
    /// `None` when the block holds no sample. Call when [`Self::block_due`], after
    /// [`Self::deliver`] and before the step, as [`Self::step_internal`] does.
    #[inline(always)]
    pub fn close_block<R>(&mut self, send: impl FnOnce(Block<T>) -> R) -> Option<R> {
        let b = self.closing_block()?;
        Some(send(b))
    }

    /// Adopt an estimator task's result (call when [`Self::block_due`], before the step); a
    /// result from before the last restart is dropped.
    #[inline(always)]
    pub fn deliver(&mut self, r: &BlockResult<T>) {
        if r.epoch != self.epoch || !r.updated {
            return;
        }
        // The read-out sums take the samples of the θ̂ about to be replaced.
        self.settle_readouts();
        if r.target.two() {
            self.theta2 = [r.theta[0], r.theta[1]];
        } else {
            self.theta3 = r.theta;
        }
        self.adopted = r.flags;
        if r.flags != 0 {
            // This step reports them: the general path (`update_hot`).
            self.update_hot();
        }
        if r.flags & status::EST_DIVERGED != 0 && self.mode == Some(Mode::Dive) {
            self.dive.flags |= status::EST_DIVERGED;
        }
    }

    /// The DIVE read-out's fast-path samples up to sample `t − 1` into the sums' count, from
    /// within sample `t`, which is not one of them (`DiveState::fast_mark`); again within
    /// the same sample, nothing.
    #[inline(always)]
    fn dive_fold_in(&mut self, t: u32) {
        let s = &mut self.dive;
        if s.fast_len != 0 && s.fast_mark != t {
            s.acc.pending = s
                .acc
                .pending
                .wrapping_add(t.wrapping_sub(1).wrapping_sub(s.fast_mark));
            s.fast_mark = t;
        }
    }

    /// [`Self::dive_fold_in`] between two samples: those up to the last one (`dive.t`).
    #[inline(always)]
    fn dive_fold_between(&mut self) {
        let s = &mut self.dive;
        if s.fast_len != 0 {
            s.acc.pending = s.acc.pending.wrapping_add(s.t.wrapping_sub(s.fast_mark));
            s.fast_mark = s.t;
        }
    }

    /// θ̂ as the DIVE read-out averages it: [c, k, 0] (the paper's regressor) or [c, k, k·(h − z₀)].
    #[inline(always)]
    fn dive_theta(&self) -> [T; 3] {
        match self.p.dive.regressor {
            DiveRegressor::Paper => [self.theta2[0], self.theta2[1], T::ZERO],
            DiveRegressor::Offset => self.theta3,
        }
    }

    /// θ̂ as the SVE pixels average it (c and k: the first two entries).
    #[inline(always)]
    fn sve_theta(&self) -> [T; 3] {
        match self.p.sve.regressor {
            SveRegressor::Decoupled => [self.theta2[0], self.theta2[1], T::ZERO],
            SveRegressor::Paper => self.theta3,
        }
    }

    /// The read-out sums take their pending samples' θ̂ (before θ̂ changes).
    #[inline(always)]
    fn settle_readouts(&mut self) {
        self.dive_fold_between();
        self.sve_fold(self.sve.t);
        let (d, v) = (self.dive_theta(), self.sve_theta());
        self.dive.acc.settle::<3>(d);
        self.sve.acc.settle::<2>(v);
    }

    /// SVE: the static tip force low-passed below the tones, as the surface check sees it (N).
    pub fn sve_static_force_n(&self) -> T {
        self.sve.force_slow * T::from_f64(units::FORCE)
    }

    /// One loop sample: the measured deflection `d_m` (m) in, the next outputs out. (The
    /// host's; the firmware runs [`Self::step_loop`] and its estimator interrupt.)
    #[cfg(not(target_os = "none"))]
    #[inline(always)]
    pub fn step(&mut self, d_m: T) -> StepOut<T> {
        self.step_internal(d_m * self.p.to_internal)
    }

    /// [`Self::step_loop`] with the deflection in metres (the firmware's f32 loop).
    #[inline(always)]
    pub fn step_loop_m(&mut self, d_m: T, sink: &mut impl SampleSink<T>) -> StepOut<T> {
        self.step_loop(d_m * self.p.to_internal, sink)
    }

    /// [`Self::step`] with the deflection in the core's internal length unit (nm): the entry
    /// point of the fixed-point path (see [`crate::fixed`]), which cannot hold the SI factor
    /// 10⁹. U, X and Y in internal units are [`Self::u_internal`] and [`Self::xy_internal`]
    /// (or the DAC codes of [`StepOut`]).
    ///
    /// With blocks of N > 1 samples this runs the estimator task in-line on every block the
    /// step closes, on the schedule of [`crate::schedule`]: the same results as the
    /// firmware's two interrupts. (The host's, as [`Self::step`].)
    #[cfg(not(target_os = "none"))]
    #[inline(always)]
    pub fn step_internal(&mut self, d_nm: T) -> StepOut<T> {
        if self.block_due() {
            if let Some(r) = self.inflight.take() {
                self.deliver(&r);
            }
            if let Some(b) = self.closing_block() {
                // The block's staged samples through the firmware's pass.
                self.inflight = Some(self.host_stage.run(&mut self.task, b));
            }
        }
        let mut handed: Option<Sample<T>> = None;
        let out = self.step_loop(d_nm, &mut |x| handed = Some(x));
        if let Some(x) = handed {
            self.host_stage.push(x);
        }
        out
    }

    /// The loop's part of [`Self::step_internal`]: everything but the estimator task (the
    /// prefilters, the regressor, the SVE high-passes and the block estimator). With blocks
    /// (N > 1) every sample of a running mode goes to `sink` ([`Sample`]: Z, U, the
    /// regressor's reference, whether it estimates), in order; the
    /// caller takes the block headers with [`Self::close_block`] (when [`Self::block_due`],
    /// before this step) and gives the estimator task the samples they count; the results
    /// come back by [`Self::deliver`]. With blocks of one the sink is not used.
    #[inline(always)]
    pub fn step_loop(&mut self, d_nm: T, sink: &mut impl SampleSink<T>) -> StepOut<T> {
        let mut st = 0u32;
        // Input: out-of-range, non-finite and spiking readings are replaced by the last good
        // tip position, and the estimator waits (see `crate::guard`).
        let now = &self.now;
        let input =
            self.guard
                .input_by(|| (now.spike, now.hold), d_nm, self.u, self.p.d_max, &BITS);
        st |= input.flags;
        let d = input.d;
        let input_ok = input.ok;
        // The block clock has ticked for this step (`block_due`, the caller's).
        let z = self.u - d;
        self.z = z;

        // While a mode runs, every sample goes to the estimator task (its prefilters need an
        // unbroken signal): from the mode's step with what to do with it, else here.
        let mut fed = false;
        // A sample the estimator may not use takes the general path, which makes the usual
        // paths' tests itself: on those, the input is known good (issue 14, round 19: the
        // input check's steady path, which sets it, then reaches them without a test of it).
        let hot = if input_ok { self.hot } else { Hot::None };
        let u_next = match hot {
            // The usual paths, dispatched by one byte (the same steps as through the mode's
            // and the phase's below).
            Hot::DiveDwell => {
                // The general path's saturating add, as a wrapping one: here t < u32::MAX
                // (`update_hot` takes this path only from t < u32::MAX, and a dwell ends once
                // t ≥ dwell_end, so every later sample of it starts below dwell_end).
                self.dive.t = self.dive.t.wrapping_add(1);
                let t = self.dive.t;
                let u = self.dive_dwell::<true>(
                    t,
                    d,
                    z,
                    true,
                    self.force_check(),
                    &mut st,
                    sink,
                    &mut fed,
                );
                if !fed {
                    self.feed(sink, z, T::ZERO, 0);
                }
                u
            }
            Hot::SvePass => {
                // As the dwell's: a pass's sample on this path starts at t < next_boundary
                // (`sve_fast` is kept only by a sample before the pixel's boundary, and cleared
                // at it, with `next_boundary` and t set anew only where `sve_fast` is cleared).
                self.sve.t = self.sve.t.wrapping_add(1);
                let t = self.sve.t;
                let u = self.sve_contact::<true>(t, d, z, true, &mut st, sink, &mut fed);
                if !fed {
                    self.feed(sink, z, T::ZERO, 0);
                }
                u
            }
            Hot::Stopped => {
                // No sample handed over (see `block_from`; with blocks of one the count is
                // not read, and is cleared where the blocks start again, `set_mode`).
                self.unfed = self.unfed.wrapping_add(1);
                self.u
            }
            Hot::None => {
                let u = match self.mode {
                    Some(Mode::Dive) => {
                        let check = self.force_check();
                        let u = self.dive_step(d, z, input_ok, check, &mut st, sink, &mut fed);
                        if !fed {
                            self.feed(sink, z, T::ZERO, 0);
                        }
                        u
                    }
                    Some(Mode::Sve) => {
                        let u = self.sve_step(d, z, input_ok, &mut st, sink, &mut fed);
                        if !fed {
                            self.feed(sink, z, T::ZERO, 0);
                        }
                        u
                    }
                    // Stopped with a result's bits to report (`update_hot`).
                    None => {
                        self.unfed = self.unfed.wrapping_add(1);
                        self.u
                    }
                };
                // The status bits of the result adopted at this sample, reported once: only
                // this path sees them (`update_hot`), so the usual ones need no load, OR and
                // store of `adopted` per sample.
                if self.adopted != 0 {
                    st |= self.adopted;
                    self.adopted = 0;
                    self.update_hot();
                }
                u
            }
        };
        let (u_code, u, clamped) = self.p.u_dac.quantize(u_next);
        if clamped {
            st |= status::U_SATURATED;
        }
        self.u = u;
        self.u_code = u_code;
        // The phase and RECORD_READY, kept as they change (`set_phase`, `set_record`), and
        // EXCITING, kept by the excitation with its envelope.
        st |= self.exc.held();
        StepOut {
            u_m: u * self.p.to_m,
            u_code,
            x_m: self.x * self.p.to_m,
            y_m: self.y * self.p.to_m,
            x_code: self.x_code,
            y_code: self.y_code,
            status: st,
        }
    }

    #[inline(always)]
    fn set_xy(&mut self, x: T, y: T) {
        let (xc, xv, _) = self.p.xy_dac.quantize(x);
        let (yc, yv, _) = self.p.xy_dac.quantize(y);
        self.x = xv;
        self.x_code = xc;
        self.y = yv;
        self.y_code = yc;
        self.y_settled = false;
    }

    /// `set_xy` with x given as its DAC code (the pass's ramp), the scan's case, with the y
    /// quantisation remembered: it is a pure function of its input, and along a line y is the
    /// same sample after sample.
    #[inline(always)]
    fn set_x_code_same_y(&mut self, x_code: i32) {
        let (xc, xv, _) = self.p.xy_dac.at_code(x_code);
        self.x = xv;
        self.x_code = xc;
        if self.y_settled {
            // The lines below would store the y and code there are: skipped (one byte
            // tested instead of two loads, a comparison and four copies per sample).
            return;
        }
        let y = self.y;
        if y != self.y_quantized.0 {
            let (yc, yv, _) = self.p.xy_dac.quantize(y);
            self.y_quantized = (y, yc, yv);
        }
        self.y_code = self.y_quantized.1;
        self.y = self.y_quantized.2;
        // A fixed point when the value quantises to itself (always, but for grids finer
        // than the number type; never for NaN): until y is set again, the next call's test
        // is true and it stores these same two.
        self.y_settled = self.y == self.y_quantized.0;
    }

    /// The header of the block handed over so far, with a pending restart and the samples
    /// to discard before it, for the estimator task; `None` when it holds no sample (a
    /// restart and samples to discard then wait for the next block that does). One estimator
    /// takes samples between restarts: the target's.
    #[inline(always)]
    fn closing_block(&mut self) -> Option<Block<T>> {
        let n = self.block_samples();
        if n == 0 {
            return None;
        }
        Some(self.header(n))
    }

    /// The samples of the block just closed (when [`Self::block_due`]): handed over since its
    /// start or its last restart; the counts start again. With none, no header is taken: its
    /// restart and the samples to discard wait for the next block that has samples.
    #[inline(always)]
    pub fn block_samples(&mut self) -> u32 {
        let n = self.handed(self.closed_steps);
        self.block_from = 0;
        self.unfed = 0;
        self.carry = 0;
        n
    }

    /// The header of the block just closed, of its `n` samples ([`Self::block_samples`], not
    /// 0), with a pending restart and the samples to discard before it: taken (the firmware
    /// writes it straight into the buffer it hands over, issue 14, round 19: built first, it
    /// was spilled to the stack while a free buffer was taken, and copied).
    #[inline(always)]
    pub fn header(&mut self, n: u32) -> Block<T> {
        let b = Block {
            restart: self.pending_restart.take(),
            restart_watch: core::mem::take(&mut self.pending_watch),
            epoch: self.epoch,
            target: self.target,
            skip: self.skip_n,
            samples: n,
            tones: ToneAhead {
                at: self.exc.ahead(),
                n: self.now.last + 1,
                which: match self.mode {
                    Some(Mode::Dive) => TONES_DIVE,
                    Some(Mode::Sve) => TONES_SVE,
                    None => 0,
                },
            },
        };
        self.skip_n = 0;
        b
    }

    /// A new tap or scan: the estimator at θ̂₀ with P₀, the divergence watch restarted.
    fn restart_estimator(&mut self, target: Target, theta0: [T; 3]) {
        self.settle_readouts();
        self.task.restart(target, theta0);
        self.task.restart_watch();
        self.theta2 = self.task.estimator2().theta();
        self.theta3 = self.task.estimator3().theta();
        self.target = target;
        // The block's samples so far are discarded: the task skips them (the host's staged
        // ones too, by the header).
        // This step's sample, handed over after the restart, is the block's own (`tick`:
        // this step's clock, set by `block_due`).
        // With blocks of one nothing is handed over: only the carried samples.
        let handed = if self.now.last > 0 {
            self.handed(self.tick)
        } else {
            self.carry
        };
        self.skip_n = self.skip_n.wrapping_add(handed);
        self.block_from = self.tick;
        self.unfed = 0;
        self.carry = 0;
        self.pending_restart = Some(theta0);
        self.pending_watch = true;
        self.epoch = self.epoch.wrapping_add(1);
    }

    /// The divergence watch restarted (the surface found again).
    fn restart_watch(&mut self) {
        self.task.restart_watch();
        self.pending_watch = true;
    }

    /// One loop sample for the estimator task, `flags` as [`Sample::flags`]: to the sink with
    /// blocks (the block's samples), else through the controller's own task at once (the
    /// prefilters, and the per-sample update when estimating). Returns the status bits of an
    /// estimating sample (meaningless for the others).
    #[inline(always)]
    fn feed(&mut self, sink: &mut impl SampleSink<T>, z: T, r: T, flags: u32) -> u32 {
        if self.now.last > 0 {
            self.feed_block(sink, z, r, flags)
        } else {
            let x = Sample {
                z,
                u: self.u,
                r,
                flags,
            };
            let Some((w, phi)) = self.task.feed(&x) else {
                return 0;
            };
            let target = self.target;
            let f = if target.two() {
                let f = self.task.sample2(target, w, &[phi[0], phi[1]]);
                self.theta2 = self.task.estimator2().theta();
                f
            } else {
                let f = self.task.sample3(target, w, &phi);
                self.theta3 = self.task.estimator3().theta();
                f
            };
            status::ESTIMATING | f
        }
    }

    /// [`Self::feed`] with blocks (`now.last` > 0): the sample to the sink.
    #[inline(always)]
    fn feed_block(&mut self, sink: &mut impl SampleSink<T>, z: T, r: T, flags: u32) -> u32 {
        self.feed_block_as::<false>(sink, z, r, flags)
    }

    /// [`Self::feed_block`]; `HOT`: from a usual path, where no result's bits are waiting
    /// (`update_hot`), so `adopted` is 0 and not read.
    #[inline(always)]
    fn feed_block_as<const HOT: bool>(
        &mut self,
        sink: &mut impl SampleSink<T>,
        z: T,
        r: T,
        flags: u32,
    ) -> u32 {
        sink.push(Sample {
            z,
            u: self.u,
            r,
            flags,
        });
        if HOT {
            status::ESTIMATING
        } else {
            status::ESTIMATING | self.adopted
        }
    }

    /// The lowered base during an approach; `None` when the travel limit is reached.
    #[inline(always)]
    fn approach_u(&self, u_cmd: T, from: T) -> Option<T> {
        let u = u_cmd - self.p.approach_step;
        if from - u > self.p.max_travel || u < self.p.u_min {
            None
        } else {
            Some(u)
        }
    }

    // Inlined into `step_loop` (its only caller), as `sve_step`: out of line, the call saved
    // and restored 9 core and 8 double FPU registers and passed the state through memory
    // (~23 instructions per sample, `cargo xtask bench`).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn dive_step(
        &mut self,
        d: T,
        z: T,
        input_ok: bool,
        check: bool,
        st: &mut u32,
        sink: &mut impl SampleSink<T>,
        fed: &mut bool,
    ) -> T {
        self.dive.t = self.dive.t.saturating_add(1);
        let t = self.dive.t;
        let mut u = self.dive.u_cmd;
        match self.phase {
            Phase::Move => {
                let f = T::from_i32(t.min(self.p.dive.move_samples) as i32) * self.p.dive.inv_move;
                let s = &self.dive;
                let (x, y) = (
                    s.x_from + (s.x_to - s.x_from) * f,
                    s.y_from + (s.y_to - s.y_from) * f,
                );
                self.set_xy(x, y);
                if t >= self.p.dive.move_samples {
                    self.contact = ContactDetector::new(d);
                    self.dive.d_free = d;
                    self.dive.force_lp_max = crate::guard::force_limit_lp(
                        self.p.reg.stiffness,
                        d,
                        self.p.guard_dive.force_max,
                    );
                    self.dive.approach_from = u;
                    self.set_phase(Phase::Approach);
                }
            }
            Phase::Approach => {
                let state = self.contact.update(&self.p.contact, d, z);
                match self.approach_u(u, self.dive.approach_from) {
                    _ if matches!(state, ContactState::Confirmed { .. }) => {
                        if let ContactState::Confirmed { h } = state {
                            self.dive.h = h;
                        }
                        self.set_phase(Phase::Indent);
                    }
                    Some(next) => u = next,
                    None => {
                        self.dive.flags |= status::NO_CONTACT;
                        self.finish_tap(false);
                    }
                }
            }
            Phase::Indent => {
                *st |= status::CONTACT;
                // The tip's depth from Z itself (the prefiltered Z/Λ is the task's).
                let depth = self.dive.h - z;
                if self.dive_force_limit(check, d, &mut u, st) {
                    // Retracted.
                } else if depth >= self.p.dive.indent {
                    self.start_dwell(t, u);
                } else {
                    match self.approach_u(u, self.dive.approach_from) {
                        Some(next) => u = next,
                        None => {
                            self.dive.flags |= status::NO_CONTACT;
                            self.finish_tap(false);
                        }
                    }
                }
            }
            Phase::Dwell => {
                return self.dive_dwell::<false>(t, d, z, input_ok, check, st, sink, fed)
            }
            Phase::Retract => {
                u += self.p.retract_step;
                if u >= self.dive.u_safe {
                    u = self.dive.u_safe;
                    self.set_phase(Phase::Wait);
                }
            }
            Phase::Wait if t >= self.p.dive.tap_samples => self.next_tap(),
            _ => {}
        }
        self.dive.u_cmd = u;
        u + self.exc.next(&self.p.dive.exc, sink)
    }

    /// One DIVE dwell sample (`dive_step`'s phase, and the usual path `Hot::DiveDwell`).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn dive_dwell<const HOT: bool>(
        &mut self,
        t: u32,
        d: T,
        z: T,
        input_ok: bool,
        check: bool,
        st: &mut u32,
        sink: &mut impl SampleSink<T>,
        fed: &mut bool,
    ) -> T {
        let mut u = self.dive.u_cmd;
        *st |= status::CONTACT;
        if self.dive_force_limit(check, d, &mut u, st) {
            self.dive.u_cmd = u;
            return u + self.exc.next(&self.p.dive.exc, sink);
        }
        if input_ok && t.wrapping_sub(self.dive.fast_from) < self.dive.fast_len {
            // The read-out's steady stretch with blocks (see `DiveState::fast_from`):
            // the path below for a good sample with estimate_from ≤ readout_from < t
            // < ramp_from and `now.last` > 0, its tests known. U is `u_cmd` as it was.
            let f = self.feed_block_as::<HOT>(sink, z, self.dive.r, SAMPLE_EST);
            *fed = true;
            *st |= f | status::READOUT;
            let v = [T::ZERO, T::ZERO, T::ZERO, self.dive.h - z];
            // Counted by the clock (`DiveState::fast_mark`).
            self.dive.acc.add_uncounted::<3>(v);
            // f is ESTIMATING (in the sums' flags already) and the adopted bits (none on the
            // usual path, `update_hot`).
            if !HOT && self.adopted != 0 {
                self.dive.acc.flags |= self.adopted;
            }
            return u + self.exc.next(&self.p.dive.exc, sink);
        }
        if input_ok && t.wrapping_sub(self.dive.estimate_from) < self.dive.estimate_len {
            // The estimating stretch before the read-out, with blocks (see
            // `DiveState::estimate_len`): the path below with its tests known.
            *st |= self.feed_block_as::<HOT>(sink, z, self.dive.r, SAMPLE_EST);
            *fed = true;
            return u + self.exc.next(&self.p.dive.exc, sink);
        }
        // Not a fast-path sample: those before it counted.
        self.dive_fold_in(t);
        let estimating = input_ok && t >= self.dive.estimate_from;
        let h = self.dive.h;
        // The regressor's reference (`DiveState::r`, fixed for the tap).
        let f = self.feed(
            sink,
            z,
            self.dive.r,
            if estimating { SAMPLE_EST } else { 0 },
        );
        *fed = true;
        if estimating {
            *st |= f;
            // z₀ is constant over the dwell: its mean is z₀ itself (finish_tap).
            // The depth from Z itself: its mean over the read-out is that of Z/Λ
            // (unit DC gain) but for the filter's edges and the tones' residue.
            if self.now.last > 0 {
                // Blocks: f is ESTIMATING and the flags of a result adopted at this
                // sample, whose divergence `deliver` put into the tap's flags
                // already; the read-out's θ̂ entries come with `settle` per block.
                if t >= self.dive.readout_from {
                    let v = [T::ZERO, T::ZERO, T::ZERO, h - z];
                    self.dive.acc.add_held::<3>(v, f);
                    *st |= status::READOUT;
                    // The sums have begun: the steady stretch from the next sample
                    // (empty from the ramp-out on).
                    self.dive.fast_from = t.wrapping_add(1);
                    self.dive.fast_len = self.dive.ramp_from.saturating_sub(t).saturating_sub(1);
                    // This sample is counted (`add_held`); the fast path's from the next.
                    self.dive.fast_mark = t;
                }
            } else {
                if f & status::EST_DIVERGED != 0 {
                    self.dive.flags |= status::EST_DIVERGED;
                }
                if t >= self.dive.readout_from {
                    let v = self.dive_theta();
                    self.dive.acc.add([v[0], v[1], v[2], h - z], f);
                    *st |= status::READOUT;
                }
            }
        }
        // t + ramp ≥ dwell_end; dwell_end ≥ ramp_from, so the end is inside.
        if t >= self.dive.ramp_from {
            self.exc.set_on(false);
            if t >= self.dive.dwell_end {
                self.finish_tap(true);
            }
        }
        self.dive.u_cmd = u;
        u + self.exc.next(&self.p.dive.exc, sink)
    }

    /// The DIVE force limit's clock (issue 14, round 10): true when this step is one of its
    /// checks, by the block clock's tick, which `block_due` advanced for this step (read in
    /// the DIVE paths only: the SVE ones do not need it).
    #[inline(always)]
    fn force_check(&self) -> bool {
        self.tick & self.check_mask == 0
    }

    /// The DIVE force check (Indent and Dwell): the static force from the low-passed
    /// deflection against the free one; above the limit the tip jumps clear of the sample in
    /// this very sample and the tap ends. True when it did. Only at a check (`check`: one
    /// sample in `FaultConfig::force_check_stride`, issue 14, round 10), its low-pass at the
    /// checks' rate; between two checks false.
    #[inline(always)]
    fn dive_force_limit(&mut self, check: bool, d: T, u: &mut T, st: &mut u32) -> bool {
        if !check {
            return false;
        }
        self.contact.lowpass_with(self.p.force_lowpass, d);
        // `K·(d_free − lp) > force_max` decided on lp alone, exactly (the threshold set with
        // d_free per tap): one comparison where the force took a subtraction, a product and
        // two more loads per sample.
        if self.contact.lowpassed() > self.dive.force_lp_max {
            return false;
        }
        *st |= status::FORCE_LIMIT;
        self.dive.flags |= status::FORCE_LIMIT;
        self.exc.silence();
        // Clear of the surface: the contact height plus the clearance, at once.
        let up = self.dive.h + self.p.clearance;
        if up > *u {
            *u = up;
        }
        self.dive.u_cmd = *u;
        // The tip is about to move fast on purpose: no spike check against the old position.
        self.guard.reprime();
        self.finish_tap(true);
        true
    }

    fn start_dwell(&mut self, t: u32, u_hold: T) {
        let p = self.p.dive;
        // The retract from here to clearance above the contact must fit in the tap's slot.
        let dist = (self.dive.h + self.p.clearance - u_hold).to_f64();
        let retract = if dist > 0.0 {
            (dist / p.retract_speed) as u32 + 2
        } else {
            2
        };
        let end = p.tap_samples.saturating_sub(retract);
        let estimate_from = t + p.ramp_samples + p.settle_samples;
        let readout_from = end.saturating_sub(p.ramp_samples + p.readout_samples);
        if readout_from <= estimate_from {
            self.dive.flags |= status::SHORT_DWELL;
        }
        self.dive.dwell_end = end.max(estimate_from + p.ramp_samples + p.readout_samples);
        self.dive.ramp_from = self.dive.dwell_end.saturating_sub(p.ramp_samples);
        self.dive.estimate_from = estimate_from;
        self.dive.readout_from = readout_from.max(estimate_from);
        // The steady stretch opens with the read-out's first sample.
        self.dive.fast_len = 0;
        // readout_from ≤ ramp_from: end − ramp − readout ≤ dwell_end − ramp, and
        // estimate_from ≤ dwell_end − ramp − readout. The mode (and with it `now.last`)
        // cannot change within a dwell: a command leaves the phase.
        self.dive.estimate_len = if self.now.last > 0 {
            self.dive.readout_from - estimate_from
        } else {
            0
        };
        self.dive.acc.clear();
        self.dive.z0 = self.dive.h - p.indent;
        self.dive.r = match p.regressor {
            DiveRegressor::Paper => self.dive.h,
            DiveRegressor::Offset => self.dive.z0,
        };
        let target = match p.regressor {
            DiveRegressor::Paper => Target::Dive2,
            DiveRegressor::Offset => Target::Dive3,
        };
        self.restart_estimator(target, self.dive.theta_warm);
        self.exc.set_on(true);
        self.set_phase(Phase::Dwell);
    }

    fn finish_tap(&mut self, contact: bool) {
        // Within a sample that is not the fast path's (every caller): the fast path's
        // samples before it counted, and none after it (the stretch closed).
        let t = self.dive.t;
        self.dive_fold_in(t);
        self.dive.fast_len = 0;
        let p = self.p.dive;
        let th = self.dive_theta();
        let s = &mut self.dive;
        let m = s.acc.mean::<3>(th);
        let tap = s.tap;
        // In internal units: `take_record` converts to SI.
        let rec = TapRecord {
            index: tap,
            ix: (tap % p.nx) as u16,
            iy: (tap / p.nx) as u16,
            x_m: self.x,
            y_m: self.y,
            contact_height_m: if contact { s.h } else { T::ZERO },
            c_ns_per_m: m[0],
            k_n_per_m: m[1],
            offset_n: m[2],
            // The mean of the constant z₀ over the read-out (0 without samples).
            centre_m: if s.acc.count() > 0 { s.z0 } else { T::ZERO },
            depth_m: m[3],
            regressor: p.regressor,
            flags: s.flags | s.acc.flags,
            samples: s.acc.count(),
        };
        if contact && s.acc.count() > 0 {
            // Warm start of the next tap: neighbours are alike.
            s.theta_warm = [m[0], m[1], m[2]];
            s.u_safe = s.h + self.p.clearance;
        } else {
            let up = s.u_cmd + self.p.clearance;
            if up > s.u_safe {
                s.u_safe = up;
            }
        }
        self.set_record(Record::Tap(rec));
        self.exc.set_on(false);
        self.set_phase(Phase::Retract);
    }

    fn next_tap(&mut self) {
        let p = self.p.dive;
        let s = &mut self.dive;
        s.tap += 1;
        s.t = 0;
        s.flags = 0;
        s.acc.clear();
        if s.tap >= p.taps {
            self.set_phase(Phase::Done);
            self.set_mode(None, false);
            return;
        }
        let ix = s.tap % p.nx;
        let iy = s.tap / p.nx;
        s.x_from = self.x;
        s.y_from = self.y;
        s.x_to = p.x0 + p.dx * T::from_i32(ix as i32);
        s.y_to = p.y0 + p.dy * T::from_i32(iy as i32);
        self.set_phase(Phase::Move);
    }

    /// One SVE sample (inlined into `step_loop`, see `dive_step`).
    #[inline(always)]
    fn sve_step(
        &mut self,
        d: T,
        z: T,
        input_ok: bool,
        st: &mut u32,
        sink: &mut impl SampleSink<T>,
        fed: &mut bool,
    ) -> T {
        // Off the fast path: its samples before this one counted, this one not theirs.
        self.sve_fold(self.sve.t);
        self.sve.t = self.sve.t.saturating_add(1);
        self.sve.fast_mark = self.sve.t;
        let t = self.sve.t;
        match self.phase {
            Phase::Move => {
                let f = T::from_i32(t.min(self.p.dive.move_samples) as i32) * self.p.dive.inv_move;
                let s = &self.dive;
                let (x, y) = (
                    s.x_from + (self.p.sve.x0 - s.x_from) * f,
                    s.y_from + (self.p.sve.y0 - s.y_from) * f,
                );
                self.set_xy(x, y);
                if t >= self.p.dive.move_samples {
                    self.contact = ContactDetector::new(d);
                    self.sve.d_free = d;
                    self.sve.approach_from = self.sve.u_cmd;
                    self.set_phase(Phase::Approach);
                }
                self.sve.u_cmd
            }
            Phase::Approach => {
                let state = self.contact.update(&self.p.contact, d, z);
                if let ContactState::Confirmed { h } = state {
                    self.sve.z0 = h;
                    self.sve.lost = false;
                    self.sve.force_slow = T::ZERO;
                    let target = match self.p.sve.regressor {
                        SveRegressor::Decoupled => Target::Sve2,
                        SveRegressor::Paper => Target::Sve3,
                    };
                    self.restart_estimator(target, self.p.sve.theta0);
                    // The task's high-passes at rest at this sample's w and φ.
                    self.feed(sink, z, h, SAMPLE_HP_REST);
                    *fed = true;
                    self.depth = DepthController::new(self.sve.u_cmd);
                    self.exc.set_on(true);
                    self.sve.t = 0;
                    self.set_phase(Phase::Settle);
                } else {
                    match self.approach_u(self.sve.u_cmd, self.sve.approach_from) {
                        Some(u) => self.sve.u_cmd = u,
                        None => {
                            *st |= status::NO_CONTACT;
                            self.set_phase(Phase::Retract);
                        }
                    }
                }
                self.sve.u_cmd
            }
            Phase::Settle | Phase::Forward | Phase::Backward | Phase::Turn => {
                self.sve_contact::<false>(t, d, z, input_ok, st, sink, fed)
            }
            Phase::Retract => {
                let u = self.sve.u_cmd + self.p.retract_step;
                self.sve.u_cmd = u;
                if u >= self.sve.z0 + self.p.clearance || u >= self.p.u_start {
                    self.set_phase(Phase::Done);
                    self.set_mode(None, false);
                }
                // Let the excitation ramp out while retracting.
                u + self.exc.next(&self.p.sve.exc, sink)
            }
            _ => self.sve.u_cmd,
        }
    }

    /// One SVE sample in contact (settle, the passes, the turn). `FAST`: a pass (forward or
    /// backward) with blocks and the decoupled regressor, the surface held and the pixel's
    /// sums begun ([`ModeNow::sve_fast`]), whose tests of the phase, the regressor, the block
    /// length, the surface and the sums' start are known; the same operations on the same
    /// values as the general path.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn sve_contact<const FAST: bool>(
        &mut self,
        t: u32,
        d: T,
        z: T,
        input_ok: bool,
        st: &mut u32,
        sink: &mut impl SampleSink<T>,
        fed: &mut bool,
    ) -> T {
        // The contact detector's low-pass keeps running: it gives the slow force. (Its
        // state is the contact confirmed at the approach, latched until the next move.)
        self.contact.lowpass(&self.p.contact, d);
        let force = self.p.reg.stiffness * (self.sve.d_free - self.contact.lowpassed());
        self.sve.force_slow += self.p.force_slow_weight * (force - self.sve.force_slow);
        if !FAST && self.sve.lost {
            let (u, bits) = self.sve_reapproach(t, z, sink);
            *st |= bits;
            return u;
        }
        *st |= status::CONTACT;
        if force > self.p.guard_sve.force_max {
            // Clear of the surface at once (the indentation and the clearance), then
            // come back down while the scan goes on.
            *st |= status::FORCE_LIMIT;
            self.exc.silence();
            let k = match self.p.sve.regressor {
                SveRegressor::Decoupled => self.theta2[1],
                SveRegressor::Paper => self.theta3[1],
            };
            // Up by the cantilever's bend and the indentation (springs in series), and
            // the clearance.
            self.sve.u_cmd += force / self.p.reg.stiffness + force / k + self.p.clearance;
            self.guard.reprime();
            if FAST {
                // The fast path's samples before this one (not added) counted.
                self.sve_fold(t.wrapping_sub(1));
            }
            self.sve_lose_surface();
            return self.sve.u_cmd;
        }
        if self.guard.surface_lost(
            &self.p.guard_sve,
            // Not while settling: the depth is still being reached.
            (FAST || self.phase != Phase::Settle) && self.sve.force_slow < self.p.lost_force,
        ) {
            *st |= status::CONTACT_LOST;
            if FAST {
                // This sample is added below, uncounted: counted with those before it.
                self.sve_fold(t);
            }
            self.sve_lose_surface();
        }
        let mut f = 0;
        // θ̂₂ ≥ k_min > 0 by projection, so the divisions are safe.
        let decoupled = FAST || matches!(self.p.sve.regressor, SveRegressor::Decoupled);
        let (th, h_hat, depth) = match decoupled {
            true => {
                // The task's high-passes run every sample, so their state stays
                // continuous.
                // `SAMPLE_EST` when the input is good, as a product (one OR of the flag's 0
                // or 1, where the choice took a move, a test and a conditional move).
                let flags = SAMPLE_HP | (SAMPLE_EST * u32::from(input_ok));
                // FAST: the usual path, no adopted bits (`update_hot`).
                let fe = if FAST {
                    self.feed_block_as::<true>(sink, z, self.sve.z0, flags)
                } else {
                    self.feed(sink, z, self.sve.z0, flags)
                };
                if input_ok {
                    f = fe;
                }
                let th = self.theta2;
                let depth = force / th[1];
                // The height from Z itself (the prefiltered Z/Λ is the task's): the
                // pixel's mean is the same but for the tones' residue.
                ([th[0], th[1], T::ZERO], z + depth, depth)
            }
            false => {
                let fe = self.feed(sink, z, self.sve.z0, if input_ok { SAMPLE_EST } else { 0 });
                if input_ok {
                    f = fe;
                }
                let th = self.theta3;
                let h = self.sve.z0 + th[2] / th[1];
                (th, h, h - z)
            }
        };
        *fed = true;
        let (u_d, sat) = self
            .depth
            .update(&self.p.sve.depth, self.p.sve.depth_eff - depth);
        if sat {
            f |= status::DEPTH_SATURATED;
        }
        *st |= f;
        self.sve.u_cmd = u_d;
        if self.sve_sequence::<FAST>(t, [th[0], th[1], h_hat, depth], f) {
            *st |= status::READOUT;
        }
        u_d + self.exc.next(&self.p.sve.exc, sink)
    }

    /// The surface is gone (a pit, the force limit): excitation out, estimator and depth
    /// integrator frozen, re-approach from here while the scan goes on.
    fn sve_lose_surface(&mut self) {
        self.sve.lost = true;
        self.set_sve_fast(false);
        self.sve.left = false;
        self.sve.reapproach_from = self.sve.u_cmd;
        self.exc.set_on(false);
    }

    /// One sample of the SVE re-approach: lower the base at the approach speed until the
    /// force is back (then resume with the depth integrator starting where the contact was
    /// found), give up after the approach's travel. The scan and its pixels go on, flagged.
    /// Returns U and the sample's status bits, for the caller to OR into its own (issue 14,
    /// round 18: out of line, this function took the caller's status word by reference, and
    /// that address kept the word in memory on every path of the step, a store at each of its
    /// changes and a load at its end).
    fn sve_reapproach(&mut self, t: u32, z: T, sink: &mut impl SampleSink<T>) -> (T, u32) {
        let mut st = status::CONTACT_LOST;
        if !self.sve.left {
            // Wait, holding U, until the tip is off the surface (after a force-limit jump the
            // slow force takes a few of its time constants to fall).
            self.sve.left = self.sve.force_slow < self.p.lost_force;
        } else if self.sve.force_slow > self.p.lost_force {
            // Found on the slow force too: the free cantilever's ringing and the tones' swing
            // reach the fast one.
            self.sve.lost = false;
            self.guard.surface_found();
            self.restart_watch();
            self.depth = DepthController::new(self.sve.u_cmd);
            self.exc.set_on(true);
        } else {
            match self.approach_u(self.sve.u_cmd, self.sve.reapproach_from) {
                Some(u) => self.sve.u_cmd = u,
                None => {
                    st |= status::NO_CONTACT;
                    self.set_phase(Phase::Retract);
                    return (self.sve.u_cmd, st);
                }
            }
        }
        let th = self.theta2;
        let th3 = self.theta3;
        let (c, k) = match self.p.sve.regressor {
            SveRegressor::Decoupled => (th[0], th[1]),
            SveRegressor::Paper => (th3[0], th3[1]),
        };
        let h = z;
        if self.sve_sequence::<false>(t, [c, k, h, T::ZERO], status::CONTACT_LOST) {
            st |= status::READOUT;
        }
        (self.sve.u_cmd + self.exc.next(&self.p.sve.exc, sink), st)
    }

    /// The raster: settle, then forward, backward, turn per line; pixel bins along the way.
    #[inline(always)]
    /// Returns true when the sample went into a pixel.
    fn sve_sequence<const FAST: bool>(&mut self, t: u32, v: [T; 4], flags: u32) -> bool {
        let mut read = false;
        // FAST: a pass (see `sve_contact`).
        let phase = if FAST { Phase::Forward } else { self.phase };
        match phase {
            Phase::Settle if t >= self.p.sve.settle_samples => self.begin_line(true),
            Phase::Forward | Phase::Backward => {
                // The ramp's nearest code (`Dac::ramp`: no overflow for t ≤ half_samples, any
                // DAC the configuration allows).
                let q = self
                    .sve
                    .x_q0
                    .wrapping_add(self.sve.x_dq.wrapping_mul(i64::from(t)));
                let raw = (q >> RAMP_FRAC) as i32;
                if FAST {
                    // y is settled (`ModeNow::sve_fast`): `set_x_code_same_y` would store x only.
                    let (xc, xv, _) = self.p.xy_dac.at_code(raw);
                    self.x = xv;
                    self.x_code = xc;
                } else {
                    self.set_x_code_same_y(raw);
                }
                if FAST {
                    // Counted by the clock (`SveState::fast_mark`).
                    self.sve.acc.add_uncounted::<2>(v);
                    self.sve.acc.flags |= flags;
                } else if self.now.last > 0 {
                    self.sve.acc.add_held::<2>(v, flags);
                    // The sums have begun: the next samples of the pass can take the fast
                    // path, while the surface holds.
                    self.set_sve_fast(self.now.sve_blocks && !self.sve.lost && self.y_settled);
                } else {
                    self.sve.acc.add(v, flags);
                }
                read = true;
                self.sve.x_acc += self.x - self.p.sve.x0;
                if t >= self.sve.next_boundary {
                    if FAST {
                        // The pixel's sums are read: this sample and those before it counted.
                        self.sve_fold(t);
                    }
                    // Read here, at a pixel's end: not loaded every sample.
                    let forward = self.phase == Phase::Forward;
                    self.finish_pixel(forward);
                    self.sve.pixel += 1;
                    if self.sve.pixel >= self.p.sve.pixels.get() {
                        if forward {
                            self.begin_line(false);
                        } else {
                            self.sve.line += 1;
                            self.sve.t = 0;
                            if self.sve.line >= self.p.sve.lines {
                                self.exc.set_on(false);
                                self.set_phase(Phase::Retract);
                            } else {
                                self.set_phase(Phase::Turn);
                            }
                        }
                    } else {
                        self.sve.next_boundary = ((self.sve.pixel as u64 + 1)
                            * self.p.sve.half_samples as u64
                            / NonZeroU64::from(self.p.sve.pixels))
                            as u32;
                    }
                }
            }
            Phase::Turn => {
                let f = T::from_i32(t.min(self.p.sve.turn_samples) as i32) * self.p.sve.inv_turn;
                let y_from = self.p.sve.y0 + self.p.sve.dy * T::from_i32(self.sve.line as i32 - 1);
                let y = y_from + self.p.sve.dy * f;
                let x = self.x;
                self.set_xy(x, y);
                if t >= self.p.sve.turn_samples {
                    self.begin_line(true);
                }
            }
            _ => {}
        }
        read
    }

    fn begin_line(&mut self, forward: bool) {
        let p = self.p.sve;
        self.sve.t = 0;
        self.sve.pixel = 0;
        self.sve.next_boundary = (p.half_samples as u64 / NonZeroU64::from(p.pixels)) as u32;
        self.sve.acc.clear();
        self.set_sve_fast(false);
        self.sve.x_acc = T::ZERO;
        (self.sve.x_q0, self.sve.x_dq) = if forward {
            self.p.xy_dac.ramp(p.x0, p.x1 - p.x0, p.half_samples)
        } else {
            self.p.xy_dac.ramp(p.x1, p.x0 - p.x1, p.half_samples)
        };
        self.set_phase(if forward {
            Phase::Forward
        } else {
            Phase::Backward
        });
    }

    fn finish_pixel(&mut self, forward: bool) {
        let p = self.p.sve;
        let th = self.sve_theta();
        let s = &mut self.sve;
        let m = s.acc.mean::<2>(th);
        let n = s.acc.count().max(1);
        let pixel = if forward {
            s.pixel
        } else {
            p.pixels.get() - 1 - s.pixel
        };
        // In internal units: `take_record` converts to SI.
        let rec = PixelRecord {
            line: s.line as u16,
            pixel: pixel as u16,
            forward,
            x_m: p.x0 + s.x_acc / T::from_i32(n as i32),
            y_m: self.y,
            c_ns_per_m: m[0],
            k_n_per_m: m[1],
            bed_height_m: m[2],
            depth_m: m[3],
            flags: s.acc.flags,
            samples: s.acc.count(),
        };
        s.acc.clear();
        s.x_acc = T::ZERO;
        self.set_sve_fast(false);
        self.set_record(Record::Pixel(rec));
    }
}

#[cfg(test)]
mod accumulator_tests {
    use super::Accumulator;

    /// Means equal to rounding (1e-12 relative), entry by entry: `a` per sample, `b` held
    /// with θ̂ `th` since its last settle.
    fn assert_means_equal<const L: usize>(
        a: &Accumulator<f64>,
        b: &Accumulator<f64>,
        th: [f64; 3],
    ) {
        let (a, b) = (a.mean::<L>([f64::NAN; 3]), b.mean::<L>(th));
        for i in 0..4 {
            assert!(
                (a[i] - b[i]).abs() <= 1e-12 * a[i].abs().max(1.0),
                "entry {i}: {} vs {}",
                a[i],
                b[i]
            );
        }
    }

    /// The per-block sums of θ̂ give the mean of the per-sample sums: θ̂ held over blocks of
    /// uneven length (a restart mid-block included), the other entries per sample. In f64 the
    /// two differ only by rounding (n·x against n additions of x).
    #[test]
    fn held_sums_equal_per_sample_sums() {
        let mut per_sample = Accumulator::<f64>::default();
        let mut held = Accumulator::<f64>::default();
        let mut theta = [3.0, 50.0, -7.0];
        let mut k = 0u32;
        for block in [1u32, 32, 17, 32, 5, 32, 32, 9] {
            for _ in 0..block {
                let x = 0.37 * f64::from(k) - 1e-3 * f64::from(k * k % 97);
                let v = [theta[0], theta[1], theta[2], x];
                per_sample.add(v, k & 3);
                // The held entries are not read (NaN would show): they come with `settle`.
                held.add_held::<3>([f64::NAN, f64::NAN, f64::NAN, x], k & 3);
                k += 1;
            }
            // A block's result adopted: θ̂ moves; the held sums take their samples first.
            held.settle::<3>(theta);
            theta = [
                theta[0] * 1.01 + 0.2,
                theta[1] - 0.7,
                theta[2] + 0.05 * f64::from(block),
            ];
        }
        // The last stretch without a settle: the mean must take it too.
        for _ in 0..13 {
            let v = [theta[0], theta[1], theta[2], 2.5];
            per_sample.add(v, 0);
            held.add_held::<3>([f64::NAN, f64::NAN, f64::NAN, 2.5], 0);
        }
        assert_eq!(
            (per_sample.count(), per_sample.flags),
            (held.count(), held.flags)
        );
        assert_means_equal::<3>(&per_sample, &held, theta);
        // An SVE-style accumulator (two held entries): the third and fourth per sample.
        let (mut p2, mut h2) = (Accumulator::<f64>::default(), Accumulator::<f64>::default());
        let theta2 = |k: u32| {
            let c = 1.0 + f64::from(k / 32);
            [c, 2.0 * c, f64::NAN]
        };
        for k in 0..100u32 {
            if k % 32 == 0 && k > 0 {
                h2.settle::<2>(theta2(k - 1));
            }
            let th = theta2(k);
            let (h, d) = (f64::from(k) * 0.1, -f64::from(k));
            p2.add([th[0], th[1], h, d], 0);
            h2.add_held::<2>([f64::NAN, f64::NAN, h, d], 0);
        }
        assert_means_equal::<2>(&p2, &h2, theta2(99));
    }
}

#[cfg(test)]
mod dac_tests {
    use super::{Dac, RAMP_FRAC};

    /// The SVE pass's integer ramp (`Dac::ramp`) lands on the line's nearest code at every
    /// step, against the line formed in f64 from the same f32 ends (a tie, or a line within
    /// 10⁻⁶ code of one, may go either way), and its codes are clamped like any other.
    #[test]
    fn the_pass_ramp_is_the_nearest_code_of_the_line() {
        let dac = Dac::<f32>::new(-10_000.0, 10_000.0, 16);
        let (mid, lsb) = (dac.mid as f64, dac.lsb as f64);
        for (from, to, n) in [
            (0.0f32, 5_000.0f32, 5_000u32),
            (5_000.0, 0.0, 5_000),
            (-9_999.7, 9_999.9, 37),
            (1.234, 1.734, 250_000),
            (-3_000.0, 7_321.5, 1),
        ] {
            let (q0, dq) = dac.ramp(from, to - from, n);
            let (c0, span) = ((from as f64 - mid) / lsb, (to - from) as f64 / lsb);
            let mut ties = 0;
            for t in 0..=n {
                let code = (q0.wrapping_add(dq.wrapping_mul(i64::from(t))) >> RAMP_FRAC) as i32;
                let exact = c0 + span * t as f64 / n as f64;
                let frac = exact - exact.floor();
                if (frac - 0.5).abs() < 1e-6 {
                    ties += 1;
                    continue;
                }
                assert_eq!(code as f64, (exact + 0.5).floor(), "{from}..{to} step {t}");
            }
            assert!(ties <= 2 + n / 1000, "{ties} near-ties");
            // Beyond the DAC's range the code clamps (at_code), as the float path did.
            let (code, _, clamped) = dac.at_code((q0 >> RAMP_FRAC) as i32 + 1_000_000);
            assert!(clamped && code == dac.code_max);
        }
    }

    /// A 24-bit DAC (the configuration's widest; f64 and Q31.32 take it) scanned over its
    /// whole range, to and from its top (one code above the highest, clamped), also in one
    /// step: every step's code is the line's nearest, clamped, with no overflow.
    #[test]
    fn the_pass_ramp_holds_over_a_24_bit_range() {
        let (lo, hi) = (-5_000.0, 5_000.0);
        let dac = Dac::<f64>::new(lo, hi, 24);
        for (from, to, n) in [
            (lo, hi, 1_001u32),
            (hi, lo, 1_001),
            (lo, hi, 1),
            (hi, lo, 2),
        ] {
            let (q0, dq) = dac.ramp(from, to - from, n);
            for t in 0..=n {
                let q = q0.wrapping_add(dq.wrapping_mul(i64::from(t)));
                let (code, _, _) = dac.at_code((q >> RAMP_FRAC) as i32);
                let exact =
                    (from - dac.mid) / dac.lsb + (to - from) / dac.lsb * t as f64 / n as f64;
                let want = ((exact + 0.5).floor() as i32).clamp(dac.code_min, dac.code_max);
                assert_eq!(code, want, "{from}..{to} in {n}, step {t}");
            }
        }
    }
}
