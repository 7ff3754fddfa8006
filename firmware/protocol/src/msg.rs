//! The messages: commands from the host and telemetry from the firmware.
//!
//! Every message is a kind byte followed by fixed little-endian fields (see [`crate::wire`]);
//! there is no self-description on the wire, so both ends must agree on
//! [`PROTOCOL_VERSION`], which the firmware announces in [`Telemetry::Hello`]. The layouts
//! are written out by hand rather than derived (serde/postcard) to keep the firmware free of
//! dependencies and panic paths and to make the byte cost of a replay sample explicit.

use crate::wire::{Reader, Short, Writer};

/// Bumped whenever a layout below changes.
pub const PROTOCOL_VERSION: u16 = 3;

/// The most samples one [`Command::Feed`] block carries (f32 samples: 4 bytes each).
pub const MAX_FEED: usize = 48;

/// Why a message could not be decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// The frame ended before the message did.
    Short,
    /// Bytes were left over after the message.
    Trailing,
    /// Unknown message kind byte.
    UnknownKind(u8),
    /// A field holds a value outside its range.
    BadValue,
}

impl From<Short> for DecodeError {
    fn from(_: Short) -> Self {
        DecodeError::Short
    }
}

/// The identification mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Tap-by-tap identification (dive and retract).
    Dive,
    /// Scanning viscoelastic identification: one record per pixel.
    Sve,
}

impl Mode {
    fn to_u8(self) -> u8 {
        match self {
            Mode::Dive => 1,
            Mode::Sve => 2,
        }
    }
    fn from_u8(v: u8) -> Result<Self, DecodeError> {
        match v {
            1 => Ok(Mode::Dive),
            2 => Ok(Mode::Sve),
            _ => Err(DecodeError::BadValue),
        }
    }
}

/// What drives the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// A hardware timer at a fixed period (board timer ticks); the ADC is sampled each tick.
    /// Under QEMU the "ADC" then produces a synthetic deterministic signal.
    Timer {
        /// Timer reload in board ticks (QEMU: 25 MHz CMSDK timer; STM32H743: TIM2 ticks).
        period_ticks: u32,
    },
    /// Replay: one loop step per sample fed by [`Command::Feed`] (QEMU board only).
    Feed,
    /// [`Command::Feed`] blocks (codes) fill the QEMU board's bench table instead of stepping
    /// the loop; a [`BenchMode::Continue`] bench then reads the table through the ADC path.
    Table,
}

/// How the loop's per-sample outputs are reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PerSample {
    /// Not at all (real-time running: records and status only).
    Off,
    /// One [`Telemetry::Step`] per sample: every field (≈ 50 bytes per sample on the wire).
    Full,
    /// [`Telemetry::StepBlock`]s: the DAC code and status of each sample plus a CRC-32
    /// digest of all the Step fields of the block (≈ 4.4 bytes per sample): what a long
    /// replay uses; rerun the failing part with `Full` to see the differing values.
    Blocks,
}

impl PerSample {
    fn to_u8(self) -> u8 {
        match self {
            PerSample::Off => 0,
            PerSample::Full => 1,
            PerSample::Blocks => 2,
        }
    }
    fn from_u8(v: u8) -> Result<Self, DecodeError> {
        match v {
            0 => Ok(PerSample::Off),
            1 => Ok(PerSample::Full),
            2 => Ok(PerSample::Blocks),
            _ => Err(DecodeError::BadValue),
        }
    }
}

/// The samples of one [`Command::Feed`] block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FeedSamples {
    /// Raw ADC codes, signed relative to mid-scale, converted on target exactly as on the
    /// board (`code as f32 * metres_per_code`).
    Codes([i16; MAX_FEED]),
    /// Deflection in metres, handed to `step` unchanged (bypasses the ADC quantisation).
    Metres([f32; MAX_FEED]),
}

/// A block of replay samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeedBlock {
    /// Index of the first sample in the replay (lets the firmware detect a lost block).
    pub first_index: u32,
    /// Number of valid samples (≤ [`MAX_FEED`]).
    pub len: u8,
    /// The samples; entries past `len` are zero.
    pub samples: FeedSamples,
}

/// A host → firmware command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// Answered by an [`Telemetry::Ack`] with the same frame sequence number.
    Ping {
        /// Echoed in the status code field of nothing; for the host's own matching.
        nonce: u32,
    },
    /// Stages one configuration value (SI units); see [`param`] for the ids.
    SetParam {
        /// Parameter id.
        id: u16,
        /// Value in SI units.
        value: f64,
    },
    /// Validates the staged configuration and rebuilds the controller (only while stopped).
    ApplyConfig,
    /// Starts identification in a mode.
    Start(Mode),
    /// Stops identification (the outputs hold).
    Stop,
    /// Selects what drives the loop.
    SetSource(Source),
    /// Replay samples.
    Feed(FeedBlock),
    /// Telemetry choices.
    SetTelemetry {
        /// Per-sample outputs (replay); off for real-time running.
        per_sample: PerSample,
        /// A [`Telemetry::Status`] every this many samples (0: only on request).
        status_every: u32,
    },
    /// Sends a [`Telemetry::Status`] now.
    RequestStatus,
    /// Measures the loop interrupt (QEMU board: instructions via SysTick under `-icount`).
    Bench {
        /// What the core does while measured.
        mode: BenchMode,
        /// Number of loop interrupts to measure (≥ 10 000 for the report).
        steps: u32,
        /// Loop timer period in board ticks during the measurement.
        period_ticks: u32,
    },
    /// Runs the SysTick calibration loop (QEMU board).
    Calibrate {
        /// Iterations of the two-instruction `subs`/`bne` loop.
        iterations: u32,
    },
    /// Ends the emulation with an exit code (QEMU board: semihosting exit, after the Ack).
    Exit {
        /// Process exit code of QEMU (0 = success).
        code: u8,
    },
}

/// What the core does during a [`Command::Bench`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchMode {
    /// Stopped (outputs hold): the interrupt around an idle `step`, synthetic ADC input.
    Stopped,
    /// Started in a mode at the beginning of the window, synthetic ADC input.
    Start(Mode),
    /// Carries on from where a replay left it, reading the bench table ([`Source::Table`])
    /// as the ADC input: the estimating phases of a real recording. With `time_step`, first
    /// measures `step` alone on a copy of the core over the same input (thread mode,
    /// interrupts masked).
    Continue {
        /// Also time `step` alone.
        time_step: bool,
    },
}

impl BenchMode {
    fn to_u8(self) -> u8 {
        match self {
            BenchMode::Stopped => 0,
            BenchMode::Start(m) => m.to_u8(),
            BenchMode::Continue { time_step: true } => 3,
            BenchMode::Continue { time_step: false } => 4,
        }
    }
    fn from_u8(v: u8) -> Result<Self, DecodeError> {
        match v {
            0 => Ok(BenchMode::Stopped),
            3 => Ok(BenchMode::Continue { time_step: true }),
            4 => Ok(BenchMode::Continue { time_step: false }),
            m => Ok(BenchMode::Start(Mode::from_u8(m)?)),
        }
    }
}

/// Parameter ids of [`Command::SetParam`]. The board's own conversion factors live here;
/// the core's configuration fields get ids from 100 on, assigned where the core's `Config`
/// is mapped (`firmware/src/core_glue.rs`).
pub mod param {
    /// ADC: metres of deflection per code (default: the core's `limits.d_full_scale_m` /
    /// 32768, a 16-bit converter spanning the core's full scale). The DACs of U, X and Y
    /// are the core's own grids (`limits.*`), so they have no board parameter.
    pub const ADC_METRES_PER_CODE: u16 = 1;
    /// First id of the core's configuration fields.
    pub const CORE_BASE: u16 = 100;
}

/// Board ids announced in [`Telemetry::Hello`].
pub mod board {
    /// QEMU `mps2-an500`.
    pub const QEMU_MPS2_AN500: u8 = 1;
    /// STM32H743.
    pub const STM32H743: u8 = 2;
}

/// Result codes of [`Telemetry::Ack`].
pub mod ack {
    /// Done.
    pub const OK: u8 = 0;
    /// Not possible in the current state (e.g. `ApplyConfig` while running).
    pub const BUSY: u8 = 1;
    /// A value was rejected (configuration validation, unknown parameter id).
    pub const INVALID: u8 = 2;
    /// Not supported on this board (e.g. `Feed` on real hardware).
    pub const UNSUPPORTED: u8 = 3;
    /// A replay block did not start where the previous one ended.
    pub const FEED_GAP: u8 = 4;
}

/// One loop sample as the firmware computed it (replay and debugging).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct StepFrame {
    /// Loop sample index since start of the source.
    pub index: u32,
    /// The deflection handed to `step` (metres), to check both sides used the same input.
    pub d_m: f32,
    /// The core's DAC code (signed, relative to mid-scale).
    pub u_code: i32,
    /// The word written to the DAC over SPI (offset binary), as the hardware would see it.
    pub dac_word: u16,
    /// U in metres.
    pub u_m: f32,
    /// Lateral setpoints in metres.
    pub x_m: f32,
    /// Lateral setpoints in metres.
    pub y_m: f32,
    /// The core's status word (flags and, from bit 24, the phase code).
    pub status: u32,
    /// Current aggregate estimates (c, k, h) in SI, as f32.
    pub estimates: [f32; 3],
}

impl StepFrame {
    /// The fields as they travel in a Step message (after the kind byte); also the input of
    /// [`step_digest`].
    pub fn encode_fields(&self, w: &mut Writer<'_>) -> Result<(), Short> {
        w.u32(self.index)?;
        w.f32(self.d_m)?;
        w.i32(self.u_code)?;
        w.u16(self.dac_word)?;
        w.f32(self.u_m)?;
        w.f32(self.x_m)?;
        w.f32(self.y_m)?;
        w.u32(self.status)?;
        est(w, &self.estimates)
    }
    fn decode_fields(r: &mut Reader<'_>) -> Result<Self, Short> {
        Ok(StepFrame {
            index: r.u32()?,
            d_m: r.f32()?,
            u_code: r.i32()?,
            dac_word: r.u16()?,
            u_m: r.f32()?,
            x_m: r.f32()?,
            y_m: r.f32()?,
            status: r.u32()?,
            estimates: read_est(r)?,
        })
    }
}

/// Bytes of one Step frame's fields.
pub const STEP_FIELDS_LEN: usize = 42;

/// Incremental CRC-32 over the encoded fields of consecutive Step frames: the digest of a
/// [`StepBlockFrame`]. Equal digests mean bit-identical samples (up to a 2⁻³² chance).
#[derive(Clone, Copy, Debug, Default)]
pub struct StepDigest(crate::crc::Crc32);

impl StepDigest {
    /// An empty digest.
    pub const fn new() -> Self {
        Self(crate::crc::Crc32::new())
    }
    /// Adds one sample.
    pub fn add(&mut self, s: &StepFrame) {
        let mut b = [0u8; STEP_FIELDS_LEN];
        let mut w = Writer::new(&mut b);
        if s.encode_fields(&mut w).is_ok() {
            self.0.update(&b);
        }
    }
    /// The digest.
    pub fn finish(self) -> u32 {
        self.0.finish()
    }
}

/// The digest of a run of Step frames.
pub fn step_digest<'a>(frames: impl IntoIterator<Item = &'a StepFrame>) -> u32 {
    let mut d = StepDigest::new();
    for f in frames {
        d.add(f);
    }
    d.finish()
}

/// Up to [`MAX_FEED`] consecutive samples in compact form (see [`PerSample::Blocks`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepBlockFrame {
    /// Index of the first sample.
    pub first_index: u32,
    /// Number of samples (≤ [`MAX_FEED`]).
    pub len: u8,
    /// DAC codes (saturated to i16; the digest has the full value).
    pub u_codes: [i16; MAX_FEED],
    /// The low 16 bits of each status word (the flags; the phase code above them is
    /// covered by the digest).
    pub status: [u16; MAX_FEED],
    /// [`step_digest`] of the block's full Step frames.
    pub digest: u32,
}

impl Default for StepBlockFrame {
    fn default() -> Self {
        Self {
            first_index: 0,
            len: 0,
            u_codes: [0; MAX_FEED],
            status: [0; MAX_FEED],
            digest: 0,
        }
    }
}

impl StepBlockFrame {
    /// True when `frames` (the full samples `first_index ..`, e.g. computed on the host)
    /// are bit-identical to what this block summarises.
    pub fn matches(&self, frames: &[StepFrame]) -> bool {
        let n = self.len as usize;
        frames.len() == n
            && frames.iter().enumerate().all(|(i, f)| {
                f.index == self.first_index.wrapping_add(i as u32)
                    && self.u_codes.get(i) == Some(&(f.u_code.clamp(-32768, 32767) as i16))
                    && self.status.get(i) == Some(&(f.status as u16))
            })
            && step_digest(frames) == self.digest
    }
}

/// One finished DIVE tap or SVE pixel: every field of the core's `TapRecord` /
/// `PixelRecord` (f32 values in SI, as the core computed them).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RecordFrame {
    /// Loop sample index at which the record was taken.
    pub index: u32,
    /// 1 = DIVE tap, 2 = SVE pixel.
    pub mode: u8,
    /// Tap: the tap's number in the sequence. Pixel: the line number.
    pub number: u32,
    /// Tap: grid column. Pixel: pixel along the line (0 at x0).
    pub ix: u16,
    /// Tap: grid row. Pixel: the line number again (the image row).
    pub iy: u16,
    /// Tap: the regressor (0 paper, 1 offset). Pixel: 1 forward, 0 backward.
    pub variant: u8,
    /// Lateral position (m).
    pub x_m: f32,
    /// Lateral position (m).
    pub y_m: f32,
    /// Aggregate damping ĉ (N·s/m).
    pub c_ns_per_m: f32,
    /// Aggregate spring constant k̂ (N/m).
    pub k_n_per_m: f32,
    /// Tap: the contact height Z(t₁). Pixel: the bed height ĥ (m).
    pub height_m: f32,
    /// Mean depth (m).
    pub depth_m: f32,
    /// Tap: θ̂₃ of the offset regressor (N); pixel: 0.
    pub offset_n: f32,
    /// Tap: the offset regressor's centre z₀ (m); pixel: 0.
    pub centre_m: f32,
    /// Status bits gathered over the tap or pixel.
    pub flags: u32,
    /// Samples averaged.
    pub samples: u32,
}

/// Firmware counters: everything that was lost or refused is counted here, never dropped
/// silently.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct StatusFrame {
    /// Loop samples stepped since boot.
    pub samples: u32,
    /// Loop interrupts without an ADC sample (replay starved, ADC error).
    pub starved: u32,
    /// Telemetry items the loop could not queue (queue full). They also leave a gap in the
    /// frame sequence numbers.
    pub telemetry_dropped: u32,
    /// Host frames that failed COBS/CRC/decoding.
    pub rx_bad_frames: u32,
    /// Host frames missing by sequence number.
    pub rx_lost_frames: u32,
    /// 0 = stopped, 1 = DIVE, 2 = SVE.
    pub state: u8,
    /// Current aggregate estimates (c, k, h).
    pub estimates: [f32; 3],
    /// Block closes at which an estimator result was still out (the estimator interrupt
    /// overran its N samples): the result was adopted at a later close, so the firmware's
    /// estimates then differ from the host's schedule (version 3).
    pub estimator_late: u32,
    /// Blocks lost to a full estimator queue, with their samples' information (version 3).
    pub blocks_dropped: u32,
    /// Samples that did not fit their block (never, by the schedule; version 3).
    pub samples_dropped: u32,
    /// Chunks of tones the estimator task had not computed when they began: the loop ran its
    /// own oscillators for them, with the same values (a cost, not a loss; version 3).
    pub tones_late: u32,
}

impl StatusFrame {
    /// What the firmware counted as lost or late, each count with its name (zero: none).
    /// Late chunks of tones are not among them: the loop computes those itself, with the
    /// same values.
    pub fn losses(&self) -> [(&'static str, u32); 5] {
        [
            ("loop interrupts starved", self.starved),
            ("telemetry items dropped", self.telemetry_dropped),
            (
                "block closes with an estimator result out",
                self.estimator_late,
            ),
            ("blocks dropped", self.blocks_dropped),
            ("samples dropped", self.samples_dropped),
        ]
    }
}

/// The result of [`Command::Bench`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct BenchFrame {
    /// Mode measured (0: core stopped, 1 DIVE, 2 SVE).
    pub mode: u8,
    /// Loop interrupts in the window.
    pub steps: u32,
    /// SysTick ticks (core clock source) elapsed in the window.
    pub ticks: u32,
    /// Iterations of the counted idle loop that ran in thread mode in the window.
    pub idle_iterations: u32,
    /// Instructions of one idle loop iteration.
    pub idle_insns_per_iteration: u8,
    /// Instructions in the window outside the interrupts and the idle loop (fixed).
    pub fixed_insns: u8,
    /// [`BenchMode::Continue`] with `time_step`: SysTick ticks of `steps` calls of `step` alone, on a copy of
    /// the core over the same input, in thread mode with interrupts masked (0 otherwise).
    pub step_ticks: u32,
    /// The same loop without the `step` call (its own cost, to subtract).
    pub loop_ticks: u32,
    /// With `time_step`: SysTick ticks of the estimator task's block updates over the same
    /// input (every closed block run through a copy of the task, each timed alone; 0
    /// otherwise).
    pub estimator_ticks: u32,
    /// Blocks the estimator task ran in that loop.
    pub estimator_blocks: u32,
}

/// The result of [`Command::Calibrate`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct CalibrationFrame {
    /// Iterations run.
    pub iterations: u32,
    /// Instructions executed between the two SysTick reads (counted from the code).
    pub instructions: u32,
    /// SysTick ticks elapsed.
    pub ticks: u32,
}

/// A firmware → host message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Telemetry {
    /// Sent once at boot.
    Hello {
        /// [`PROTOCOL_VERSION`] of the firmware.
        protocol: u16,
        /// See [`board`].
        board: u8,
        /// 0 = stand-in core, 1 = visco-core.
        core: u8,
    },
    /// Answer to a command frame.
    Ack {
        /// Sequence number of the command frame.
        cmd_seq: u32,
        /// See [`ack`].
        code: u8,
    },
    /// One loop sample.
    Step(StepFrame),
    /// Consecutive loop samples, compact.
    StepBlock(StepBlockFrame),
    /// One finished tap or pixel.
    Record(RecordFrame),
    /// Counters.
    Status(StatusFrame),
    /// Loop measurement.
    Bench(BenchFrame),
    /// SysTick calibration.
    Calibration(CalibrationFrame),
    /// `ApplyConfig` refused: the configuration field at fault, its value and why (sent
    /// before the refusing Ack).
    ConfigRejected(ConfigRejectedFrame),
}

/// Longest field name in a [`ConfigRejectedFrame`].
pub const FIELD_LEN: usize = 48;
/// Longest reason in a [`ConfigRejectedFrame`] (longer ones are cut).
pub const REASON_LEN: usize = 160;

/// Why the core refused its configuration (the core's `ConfigError`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConfigRejectedFrame {
    /// The field's dotted path (UTF-8, `field_len` bytes), e.g. `dive.estimator.alpha`.
    pub field: [u8; FIELD_LEN],
    /// Bytes of `field` used.
    pub field_len: u8,
    /// The value.
    pub value: f64,
    /// What is wrong (UTF-8, `reason_len` bytes, cut at a character boundary).
    pub reason: [u8; REASON_LEN],
    /// Bytes of `reason` used.
    pub reason_len: u8,
}

impl Default for ConfigRejectedFrame {
    fn default() -> Self {
        Self {
            field: [0; FIELD_LEN],
            field_len: 0,
            value: 0.0,
            reason: [0; REASON_LEN],
            reason_len: 0,
        }
    }
}

/// The longest prefix of `s` of at most `max` bytes that ends on a character boundary.
fn cut(s: &str, max: usize) -> &[u8] {
    let mut n = s.len().min(max);
    while n > 0 && !s.is_char_boundary(n) {
        n -= 1;
    }
    s.as_bytes().get(..n).unwrap_or(&[])
}

impl ConfigRejectedFrame {
    /// From the field name, value and reason (cut to fit).
    pub fn new(field: &str, value: f64, reason: &str) -> Self {
        let mut f = Self {
            value,
            ..Self::default()
        };
        let a = cut(field, FIELD_LEN);
        if let Some(dst) = f.field.get_mut(..a.len()) {
            dst.copy_from_slice(a);
            f.field_len = a.len() as u8;
        }
        let b = cut(reason, REASON_LEN);
        if let Some(dst) = f.reason.get_mut(..b.len()) {
            dst.copy_from_slice(b);
            f.reason_len = b.len() as u8;
        }
        f
    }
    /// The field name.
    pub fn field(&self) -> &str {
        let b = self.field.get(..self.field_len as usize).unwrap_or(&[]);
        core::str::from_utf8(b).unwrap_or("?")
    }
    /// The reason.
    pub fn reason(&self) -> &str {
        let b = self.reason.get(..self.reason_len as usize).unwrap_or(&[]);
        core::str::from_utf8(b).unwrap_or("?")
    }
}

mod kind {
    pub const PING: u8 = 0x01;
    pub const SET_PARAM: u8 = 0x02;
    pub const APPLY_CONFIG: u8 = 0x03;
    pub const START: u8 = 0x04;
    pub const STOP: u8 = 0x05;
    pub const SET_SOURCE: u8 = 0x06;
    pub const FEED_CODES: u8 = 0x07;
    pub const FEED_METRES: u8 = 0x08;
    pub const SET_TELEMETRY: u8 = 0x09;
    pub const REQUEST_STATUS: u8 = 0x0A;
    pub const BENCH: u8 = 0x0B;
    pub const CALIBRATE: u8 = 0x0C;
    pub const EXIT: u8 = 0x0D;

    pub const HELLO: u8 = 0x81;
    pub const ACK: u8 = 0x82;
    pub const STEP: u8 = 0x83;
    pub const RECORD: u8 = 0x84;
    pub const STATUS: u8 = 0x85;
    pub const BENCH_RESULT: u8 = 0x86;
    pub const CALIBRATION: u8 = 0x87;
    pub const STEP_BLOCK: u8 = 0x88;
    pub const CONFIG_REJECTED: u8 = 0x89;
}

fn est(w: &mut Writer<'_>, e: &[f32; 3]) -> Result<(), Short> {
    for &v in e {
        w.f32(v)?;
    }
    Ok(())
}

fn read_est(r: &mut Reader<'_>) -> Result<[f32; 3], Short> {
    Ok([r.f32()?, r.f32()?, r.f32()?])
}

fn finish<T>(r: &Reader<'_>, v: T) -> Result<T, DecodeError> {
    if r.remaining() == 0 {
        Ok(v)
    } else {
        Err(DecodeError::Trailing)
    }
}

impl Command {
    /// Writes the message (kind byte and fields).
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), Short> {
        match *self {
            Command::Ping { nonce } => {
                w.u8(kind::PING)?;
                w.u32(nonce)
            }
            Command::SetParam { id, value } => {
                w.u8(kind::SET_PARAM)?;
                w.u16(id)?;
                w.f64(value)
            }
            Command::ApplyConfig => w.u8(kind::APPLY_CONFIG),
            Command::Start(mode) => {
                w.u8(kind::START)?;
                w.u8(mode.to_u8())
            }
            Command::Stop => w.u8(kind::STOP),
            Command::SetSource(src) => {
                w.u8(kind::SET_SOURCE)?;
                match src {
                    Source::Timer { period_ticks } => {
                        w.u8(1)?;
                        w.u32(period_ticks)
                    }
                    Source::Feed => {
                        w.u8(2)?;
                        w.u32(0)
                    }
                    Source::Table => {
                        w.u8(3)?;
                        w.u32(0)
                    }
                }
            }
            Command::Feed(block) => {
                let n = (block.len as usize).min(MAX_FEED);
                match &block.samples {
                    FeedSamples::Codes(c) => {
                        w.u8(kind::FEED_CODES)?;
                        w.u32(block.first_index)?;
                        w.u8(n as u8)?;
                        for &v in c.iter().take(n) {
                            w.bytes(&v.to_le_bytes())?;
                        }
                    }
                    FeedSamples::Metres(m) => {
                        w.u8(kind::FEED_METRES)?;
                        w.u32(block.first_index)?;
                        w.u8(n as u8)?;
                        for &v in m.iter().take(n) {
                            w.f32(v)?;
                        }
                    }
                }
                Ok(())
            }
            Command::SetTelemetry {
                per_sample,
                status_every,
            } => {
                w.u8(kind::SET_TELEMETRY)?;
                w.u8(per_sample.to_u8())?;
                w.u32(status_every)
            }
            Command::RequestStatus => w.u8(kind::REQUEST_STATUS),
            Command::Bench {
                mode,
                steps,
                period_ticks,
            } => {
                w.u8(kind::BENCH)?;
                w.u8(mode.to_u8())?;
                w.u32(steps)?;
                w.u32(period_ticks)
            }
            Command::Calibrate { iterations } => {
                w.u8(kind::CALIBRATE)?;
                w.u32(iterations)
            }
            Command::Exit { code } => {
                w.u8(kind::EXIT)?;
                w.u8(code)
            }
        }
    }

    /// Reads a message; the whole slice must be consumed.
    pub fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let k = r.u8()?;
        let cmd = match k {
            kind::PING => Command::Ping { nonce: r.u32()? },
            kind::SET_PARAM => Command::SetParam {
                id: r.u16()?,
                value: r.f64()?,
            },
            kind::APPLY_CONFIG => Command::ApplyConfig,
            kind::START => Command::Start(Mode::from_u8(r.u8()?)?),
            kind::STOP => Command::Stop,
            kind::SET_SOURCE => {
                let tag = r.u8()?;
                let period_ticks = r.u32()?;
                match tag {
                    1 => Command::SetSource(Source::Timer { period_ticks }),
                    2 => Command::SetSource(Source::Feed),
                    3 => Command::SetSource(Source::Table),
                    _ => return Err(DecodeError::BadValue),
                }
            }
            kind::FEED_CODES | kind::FEED_METRES => {
                let first_index = r.u32()?;
                let len = r.u8()?;
                if len as usize > MAX_FEED {
                    return Err(DecodeError::BadValue);
                }
                let samples = if k == kind::FEED_CODES {
                    let mut c = [0i16; MAX_FEED];
                    for v in c.iter_mut().take(len as usize) {
                        *v = r.i16()?;
                    }
                    FeedSamples::Codes(c)
                } else {
                    let mut m = [0f32; MAX_FEED];
                    for v in m.iter_mut().take(len as usize) {
                        *v = r.f32()?;
                    }
                    FeedSamples::Metres(m)
                };
                Command::Feed(FeedBlock {
                    first_index,
                    len,
                    samples,
                })
            }
            kind::SET_TELEMETRY => {
                let per_sample = PerSample::from_u8(r.u8()?)?;
                Command::SetTelemetry {
                    per_sample,
                    status_every: r.u32()?,
                }
            }
            kind::REQUEST_STATUS => Command::RequestStatus,
            kind::BENCH => Command::Bench {
                mode: BenchMode::from_u8(r.u8()?)?,
                steps: r.u32()?,
                period_ticks: r.u32()?,
            },
            kind::CALIBRATE => Command::Calibrate {
                iterations: r.u32()?,
            },
            kind::EXIT => Command::Exit { code: r.u8()? },
            other => return Err(DecodeError::UnknownKind(other)),
        };
        finish(&r, cmd)
    }
}

impl Telemetry {
    /// Writes the message (kind byte and fields).
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), Short> {
        match self {
            Telemetry::Hello {
                protocol,
                board,
                core,
            } => {
                w.u8(kind::HELLO)?;
                w.u16(*protocol)?;
                w.u8(*board)?;
                w.u8(*core)
            }
            Telemetry::Ack { cmd_seq, code } => {
                w.u8(kind::ACK)?;
                w.u32(*cmd_seq)?;
                w.u8(*code)
            }
            Telemetry::Step(s) => {
                w.u8(kind::STEP)?;
                s.encode_fields(w)
            }
            Telemetry::StepBlock(b) => {
                w.u8(kind::STEP_BLOCK)?;
                w.u32(b.first_index)?;
                let n = (b.len as usize).min(MAX_FEED);
                w.u8(n as u8)?;
                for (&c, &st) in b.u_codes.iter().zip(&b.status).take(n) {
                    w.bytes(&c.to_le_bytes())?;
                    w.u16(st)?;
                }
                w.u32(b.digest)
            }
            Telemetry::Record(rf) => {
                w.u8(kind::RECORD)?;
                w.u32(rf.index)?;
                w.u8(rf.mode)?;
                w.u32(rf.number)?;
                w.u16(rf.ix)?;
                w.u16(rf.iy)?;
                w.u8(rf.variant)?;
                for v in [
                    rf.x_m,
                    rf.y_m,
                    rf.c_ns_per_m,
                    rf.k_n_per_m,
                    rf.height_m,
                    rf.depth_m,
                    rf.offset_n,
                    rf.centre_m,
                ] {
                    w.f32(v)?;
                }
                w.u32(rf.flags)?;
                w.u32(rf.samples)
            }
            Telemetry::Status(s) => {
                w.u8(kind::STATUS)?;
                w.u32(s.samples)?;
                w.u32(s.starved)?;
                w.u32(s.telemetry_dropped)?;
                w.u32(s.rx_bad_frames)?;
                w.u32(s.rx_lost_frames)?;
                w.u8(s.state)?;
                est(w, &s.estimates)?;
                w.u32(s.estimator_late)?;
                w.u32(s.blocks_dropped)?;
                w.u32(s.samples_dropped)?;
                w.u32(s.tones_late)
            }
            Telemetry::Bench(b) => {
                w.u8(kind::BENCH_RESULT)?;
                w.u8(b.mode)?;
                w.u32(b.steps)?;
                w.u32(b.ticks)?;
                w.u32(b.idle_iterations)?;
                w.u8(b.idle_insns_per_iteration)?;
                w.u8(b.fixed_insns)?;
                w.u32(b.step_ticks)?;
                w.u32(b.loop_ticks)?;
                w.u32(b.estimator_ticks)?;
                w.u32(b.estimator_blocks)
            }
            Telemetry::Calibration(c) => {
                w.u8(kind::CALIBRATION)?;
                w.u32(c.iterations)?;
                w.u32(c.instructions)?;
                w.u32(c.ticks)
            }
            Telemetry::ConfigRejected(c) => {
                w.u8(kind::CONFIG_REJECTED)?;
                w.f64(c.value)?;
                let f = c.field.get(..c.field_len as usize).unwrap_or(&[]);
                w.u8(f.len() as u8)?;
                w.bytes(f)?;
                let m = c.reason.get(..c.reason_len as usize).unwrap_or(&[]);
                w.u8(m.len() as u8)?;
                w.bytes(m)
            }
        }
    }

    /// Reads a message; the whole slice must be consumed.
    pub fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(bytes);
        let t = match r.u8()? {
            kind::HELLO => Telemetry::Hello {
                protocol: r.u16()?,
                board: r.u8()?,
                core: r.u8()?,
            },
            kind::ACK => Telemetry::Ack {
                cmd_seq: r.u32()?,
                code: r.u8()?,
            },
            kind::STEP => Telemetry::Step(StepFrame::decode_fields(&mut r)?),
            kind::STEP_BLOCK => {
                let mut b = StepBlockFrame {
                    first_index: r.u32()?,
                    len: r.u8()?,
                    ..Default::default()
                };
                if b.len as usize > MAX_FEED {
                    return Err(DecodeError::BadValue);
                }
                for (c, st) in b
                    .u_codes
                    .iter_mut()
                    .zip(b.status.iter_mut())
                    .take(b.len as usize)
                {
                    *c = r.i16()?;
                    *st = r.u16()?;
                }
                b.digest = r.u32()?;
                Telemetry::StepBlock(b)
            }
            kind::RECORD => Telemetry::Record(RecordFrame {
                index: r.u32()?,
                mode: r.u8()?,
                number: r.u32()?,
                ix: r.u16()?,
                iy: r.u16()?,
                variant: r.u8()?,
                x_m: r.f32()?,
                y_m: r.f32()?,
                c_ns_per_m: r.f32()?,
                k_n_per_m: r.f32()?,
                height_m: r.f32()?,
                depth_m: r.f32()?,
                offset_n: r.f32()?,
                centre_m: r.f32()?,
                flags: r.u32()?,
                samples: r.u32()?,
            }),
            kind::STATUS => Telemetry::Status(StatusFrame {
                samples: r.u32()?,
                starved: r.u32()?,
                telemetry_dropped: r.u32()?,
                rx_bad_frames: r.u32()?,
                rx_lost_frames: r.u32()?,
                state: r.u8()?,
                estimates: read_est(&mut r)?,
                estimator_late: r.u32()?,
                blocks_dropped: r.u32()?,
                samples_dropped: r.u32()?,
                tones_late: r.u32()?,
            }),
            kind::BENCH_RESULT => Telemetry::Bench(BenchFrame {
                mode: r.u8()?,
                steps: r.u32()?,
                ticks: r.u32()?,
                idle_iterations: r.u32()?,
                idle_insns_per_iteration: r.u8()?,
                fixed_insns: r.u8()?,
                step_ticks: r.u32()?,
                loop_ticks: r.u32()?,
                estimator_ticks: r.u32()?,
                estimator_blocks: r.u32()?,
            }),
            kind::CALIBRATION => Telemetry::Calibration(CalibrationFrame {
                iterations: r.u32()?,
                instructions: r.u32()?,
                ticks: r.u32()?,
            }),
            kind::CONFIG_REJECTED => {
                let mut c = ConfigRejectedFrame {
                    value: r.f64()?,
                    ..Default::default()
                };
                let n = r.u8()? as usize;
                if n > FIELD_LEN {
                    return Err(DecodeError::BadValue);
                }
                for b in c.field.iter_mut().take(n) {
                    *b = r.u8()?;
                }
                c.field_len = n as u8;
                let n = r.u8()? as usize;
                if n > REASON_LEN {
                    return Err(DecodeError::BadValue);
                }
                for b in c.reason.iter_mut().take(n) {
                    *b = r.u8()?;
                }
                c.reason_len = n as u8;
                Telemetry::ConfigRejected(c)
            }
            other => return Err(DecodeError::UnknownKind(other)),
        };
        finish(&r, t)
    }
}
