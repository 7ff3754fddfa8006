//! The boundary between the firmware and the identification core.
//!
//! The loop only needs [`LoopCore`]; [`ActiveCore`] names the implementation and
//! [`build_core`] makes one from the staged configuration (in thread mode, outside the
//! loop). Until `visco-core`'s `Controller` lands, [`StandInCore`] does a few float
//! operations per sample with the same shape of output, so that the interrupt, drivers,
//! telemetry, replay and instruction counting are all exercised.
//!
//! Swapping in the real core is this file only:
//! ```ignore
//! pub const CORE_ID: u8 = 1;
//! pub type ActiveCore = visco_core::Controller<f32>;
//! impl LoopCore for visco_core::Controller<f32> {
//!     fn command(&mut self, c: CoreCommand) {
//!         let _ = visco_core::Controller::command(self, match c {
//!             CoreCommand::Start(Mode::Dive) => visco_core::Command::Start(visco_core::Mode::Dive),
//!             CoreCommand::Start(Mode::Sve) => visco_core::Command::Start(visco_core::Mode::Sve),
//!             CoreCommand::Stop => visco_core::Command::Stop,
//!         });
//!     }
//!     #[inline(always)]
//!     fn step(&mut self, d_m: f32) -> StepOut {
//!         let o = visco_core::Controller::step(self, d_m);
//!         StepOut { u_code: o.u_code, u_m: o.u_m, x_m: o.x_m, y_m: o.y_m, status: o.status,
//!                   record: o.record.map(|r| RecordOut { /* fields of visco_core::Record */ }) }
//!     }
//!     fn estimates(&self) -> [f32; 3] { let (c, k, h) = visco_core::Controller::estimates(self); [c as f32, k as f32, h as f32] }
//!     fn mode(&self) -> Option<Mode> { /* from the controller's state */ }
//! }
//! pub fn build_core(cfg: &StagedConfig, _dac: &Scale) -> Result<ActiveCore, ConfigError> {
//!     let config = visco_core::Config { /* cfg.get(param::CORE_BASE + i) for each field */ };
//!     visco_core::Controller::new(&config).map_err(|_| ConfigError::Invalid)
//! }
//! ```

use crate::scale::Scale;
use visco_protocol::param;
pub use visco_protocol::Mode;

/// 0 = the stand-in core, 1 = visco-core (announced in the Hello frame).
pub const CORE_ID: u8 = 0;

/// The core in use.
pub type ActiveCore = StandInCore;

/// Makes the core from the staged configuration (thread mode; never in the loop).
pub fn build_core(cfg: &StagedConfig, dac: &Scale) -> Result<ActiveCore, ConfigError> {
    StandInCore::new(cfg, dac)
}

/// A command for the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CoreCommand {
    /// Start identification in a mode.
    Start(Mode),
    /// Stop (outputs hold).
    Stop,
}

/// One finished DIVE tap or SVE pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordOut {
    /// The mode that produced it.
    pub mode: Mode,
    /// Aggregate estimates (c, k, h).
    pub estimates: [f32; 3],
    /// Lateral position (metres).
    pub x_m: f32,
    /// Lateral position (metres).
    pub y_m: f32,
    /// Status flags.
    pub status: u16,
}

/// What one `step` produces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOut {
    /// DAC code, signed relative to mid-scale, on the DAC grid and clamped.
    pub u_code: i32,
    /// U in metres.
    pub u_m: f32,
    /// Lateral setpoint (metres).
    pub x_m: f32,
    /// Lateral setpoint (metres).
    pub y_m: f32,
    /// Status flags.
    pub status: u16,
    /// A finished tap or pixel.
    pub record: Option<RecordOut>,
}

/// What the loop needs from the core.
pub trait LoopCore {
    /// Applies a command (called in the loop interrupt, before the step).
    fn command(&mut self, cmd: CoreCommand);
    /// One loop sample: measured deflection in metres.
    fn step(&mut self, d_m: f32) -> StepOut;
    /// Current aggregate estimates (c, k, h).
    fn estimates(&self) -> [f32; 3];
    /// The running mode, if any.
    fn mode(&self) -> Option<Mode>;
}

/// Why a configuration was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigError {
    /// A value is out of range or missing.
    Invalid,
}

/// How many core parameter ids can be staged (ids `CORE_BASE .. CORE_BASE + MAX_PARAMS`).
pub const MAX_PARAMS: usize = 64;

/// Configuration values staged by `SetParam`, applied by `ApplyConfig`.
#[derive(Clone, Copy, Debug)]
pub struct StagedConfig {
    values: [f64; MAX_PARAMS],
    set: u64,
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
        let Some(i) = id.checked_sub(param::CORE_BASE) else {
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
    /// A staged value, if set.
    pub fn get(&self, id: u16) -> Option<f64> {
        let i = id.checked_sub(param::CORE_BASE)? as usize;
        if self.set & (1u64 << (i % 64)) == 0 {
            return None;
        }
        self.values.get(i).copied()
    }
}

/// Stand-in parameter ids.
pub mod standin_param {
    use visco_protocol::param::CORE_BASE;
    /// Integral gain of the stand-in depth loop (1/sample).
    pub const GAIN: u16 = CORE_BASE;
    /// Deflection setpoint (m).
    pub const SETPOINT: u16 = CORE_BASE + 1;
    /// Samples per DIVE tap / SVE pixel record.
    pub const RECORD_EVERY: u16 = CORE_BASE + 2;
    /// SVE pixel pitch (m).
    pub const PITCH: u16 = CORE_BASE + 3;
    /// SVE pixels per line.
    pub const PIXELS_PER_LINE: u16 = CORE_BASE + 4;
}

/// The stand-in: a first-order prefilter, an integral depth loop, a leaky "estimator" and
/// (SVE) a raster of pixels. Only +, −, ×, ÷ and comparisons, like the real core, so its
/// f32 results are bit-identical on the host and on the target.
#[derive(Clone, Copy, Debug)]
pub struct StandInCore {
    mode: Option<Mode>,
    dac: Scale,
    gain: f32,
    setpoint: f32,
    record_every: u32,
    pitch: f32,
    pixels_per_line: u32,
    filt: f32,
    filt2: f32,
    integ: f32,
    u_m: f32,
    u_code: i32,
    est: [f32; 3],
    n_in_record: u32,
    pixel: u32,
    x_m: f32,
    y_m: f32,
}

impl StandInCore {
    /// From staged values (defaults for those not staged).
    pub fn new(cfg: &StagedConfig, dac: &Scale) -> Result<Self, ConfigError> {
        let gain = cfg.get(standin_param::GAIN).unwrap_or(0.01);
        let setpoint = cfg.get(standin_param::SETPOINT).unwrap_or(5e-9);
        let record_every = cfg.get(standin_param::RECORD_EVERY).unwrap_or(1000.0);
        let pitch = cfg.get(standin_param::PITCH).unwrap_or(1e-7);
        let ppl = cfg.get(standin_param::PIXELS_PER_LINE).unwrap_or(64.0);
        let ok = gain.is_finite()
            && gain > 0.0
            && gain < 1.0
            && setpoint.is_finite()
            && (1.0..=1e9).contains(&record_every)
            && pitch.is_finite()
            && (1.0..=65536.0).contains(&ppl);
        if !ok {
            return Err(ConfigError::Invalid);
        }
        Ok(Self {
            mode: None,
            dac: *dac,
            gain: gain as f32,
            setpoint: setpoint as f32,
            record_every: record_every as u32,
            pitch: pitch as f32,
            pixels_per_line: ppl as u32,
            filt: 0.0,
            filt2: 0.0,
            integ: 0.0,
            u_m: 0.0,
            u_code: 0,
            est: [0.0; 3],
            n_in_record: 0,
            pixel: 0,
            x_m: 0.0,
            y_m: 0.0,
        })
    }

    #[inline(always)]
    fn quantise(&mut self, u: f32) {
        self.u_code = self.dac.to_code(u);
        self.u_m = self.dac.to_metres(self.u_code);
    }
}

impl LoopCore for StandInCore {
    fn command(&mut self, cmd: CoreCommand) {
        match cmd {
            CoreCommand::Start(m) => {
                self.mode = Some(m);
                self.n_in_record = 0;
                self.pixel = 0;
            }
            CoreCommand::Stop => self.mode = None,
        }
    }

    #[inline(always)]
    fn step(&mut self, d: f32) -> StepOut {
        let mut status = 0u16;
        let mut record = None;
        match self.mode {
            None => status |= 1, // idle: outputs hold
            Some(mode) => {
                self.filt += 0.125 * (d - self.filt);
                let e = self.setpoint - self.filt;
                self.integ += self.gain * e;
                let u = self.integ;
                self.quantise(u);
                // A leaky correlation standing in for the estimator.
                self.est[0] += 0.001 * (self.filt * self.u_m - self.est[0]);
                self.est[1] += 0.001 * (e * e - self.est[1]);
                if mode == Mode::Sve {
                    self.filt2 += 0.25 * (self.filt - self.filt2);
                    self.est[2] += 0.001 * (self.filt2 * e - self.est[2]);
                }
                self.n_in_record += 1;
                if self.n_in_record >= self.record_every {
                    self.n_in_record = 0;
                    if mode == Mode::Sve {
                        self.pixel += 1;
                        if self.pixel >= self.pixels_per_line {
                            self.pixel = 0;
                            self.y_m += self.pitch;
                        }
                        self.x_m = self.pixel as f32 * self.pitch;
                    }
                    record = Some(RecordOut {
                        mode,
                        estimates: self.est,
                        x_m: self.x_m,
                        y_m: self.y_m,
                        status,
                    });
                }
                if mode == Mode::Sve {
                    status |= 4;
                } else {
                    status |= 2;
                }
            }
        }
        StepOut {
            u_code: self.u_code,
            u_m: self.u_m,
            x_m: self.x_m,
            y_m: self.y_m,
            status,
            record,
        }
    }

    fn estimates(&self) -> [f32; 3] {
        self.est
    }

    fn mode(&self) -> Option<Mode> {
        self.mode
    }
}
