//! The boundary between the firmware and the identification core, `visco_core::Controller`.
//!
//! The loop needs only [`LoopCore`] (so its host tests can use a mock); [`ActiveCore`] is
//! the real core: `Controller<f32>` on the Cortex-M7's FPU, or `Controller<Q32>` with the
//! cargo feature `fixed-point` (boards without an FPU) — the same code, one type parameter
//! ([`Number`]) apart; the conversions at the edge are in [`crate::core_number`].
//! [`build_core`] makes the core from the staged configuration in thread mode, outside the
//! loop (see [`crate::core_config`] for the parameters). Everything here is
//! `#[inline(always)]` so that the loop interrupt is one function with the core's per-sample
//! path inside (on the STM32H743: in ITCM).

pub use crate::core_config::{StagedConfig, MAX_PARAMS};
pub use crate::core_number::LoopReal;
use crate::scale::Scale;
pub use visco_protocol::Mode;

/// The number type the core computes in (f32; `Q32` with the feature `fixed-point`).
#[cfg(not(feature = "fixed-point"))]
pub type Number = f32;
/// The number type the core computes in (f32; `Q32` with the feature `fixed-point`).
#[cfg(feature = "fixed-point")]
pub type Number = visco_core::fixed::Q32;

/// Announced in the Hello frame: 1 = visco-core in f32, 2 = visco-core in Q31.32.
pub const CORE_ID: u8 = <Number as LoopReal>::CORE_ID;

/// The core in use.
pub type ActiveCore = visco_core::Controller<Number>;

/// What the ADC code → deflection conversion of [`Number`] needs besides the metres per code
/// (nothing in f32, nm per code in Q32).
pub type AdcScale = <Number as LoopReal>::AdcScale;

/// Why a configuration was rejected: the core's own error, naming the field.
pub type ConfigError = visco_core::ConfigError;

/// A block header for the estimator task (loop → estimator interrupt).
pub type Block = visco_core::schedule::Block<Number>;
/// One sample for the estimator task, its regressor's raw inputs (loop → estimator interrupt).
pub type Sample = visco_core::schedule::Sample<Number>;
pub use visco_core::excitation::ToneSource;
pub use visco_core::schedule::SampleSink;
/// A chunk of tones computed ahead by the estimator task (estimator interrupt → loop).
pub type ToneChunk = visco_core::excitation::ToneChunk<Number>;
/// What identifies a chunk of tones.
pub type ChunkKey = visco_core::excitation::ChunkKey<Number>;
/// The estimator task's result (estimator interrupt → loop).
pub type BlockResult = visco_core::schedule::BlockResult<Number>;
/// The estimator task, run by the lower-priority estimator interrupt.
pub type EstimatorTask = visco_core::schedule::EstimatorTask<Number>;

/// The core and the board settings derived from one configuration.
pub struct Built {
    /// The controller, idle.
    pub core: ActiveCore,
    /// Its estimator task (the estimator interrupt's).
    pub task: EstimatorTask,
    /// The ADC's code → metres scale (the board parameter, or the core's full scale).
    pub adc: Scale,
}

/// Makes the core from the staged configuration (thread mode; never in the loop). `adc`:
/// the board's ADC metres per code if the host set it, else the default for the core's
/// full scale ([`crate::core_config::default_adc_metres_per_code`]).
pub fn build_core(
    cfg: &StagedConfig,
    adc_metres_per_code: Option<f64>,
) -> Result<Built, ConfigError> {
    let config = crate::core_config::build_config(cfg)?;
    let core = visco_core::Controller::new(&config)?;
    let m = adc_metres_per_code
        .unwrap_or_else(|| crate::core_config::default_adc_metres_per_code(&config));
    let adc = Scale::new_16bit(m as f32).ok_or(ConfigError {
        field: "adc_metres_per_code",
        value: m,
        reason: "must be finite and non-zero (and below 4 µm per code in fixed point)",
    })?;
    let task = core.estimator_task();
    Ok(Built { core, task, adc })
}

/// A command for the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CoreCommand {
    /// Start identification in a mode.
    Start(Mode),
    /// Stop (outputs hold).
    Stop,
}

/// What one `step` produces (the core's `StepOut`).
pub type StepOut = visco_core::StepOut<Number>;

/// Status bit: a record waits in [`LoopCore::take_record`].
pub const RECORD_READY: u32 = visco_core::status::RECORD_READY;

/// What the loop needs from the core.
pub trait LoopCore {
    /// Applies a command (called in the loop interrupt, before the step).
    fn apply_command(&mut self, cmd: CoreCommand);
    /// One loop sample: the measured deflection as [`crate::scale::Scale::to_input`] gives it;
    /// while a mode runs, the sample goes to `sink` (the estimator task's inputs). When [`Self::block_due`], the block is taken
    /// first ([`Self::close_block`]).
    fn step(&mut self, d: Number, sink: &mut impl SampleSink<Number>) -> StepOut;
    /// The block clock's tick for the next step (call once before each step): true when it
    /// closes a block: deliver the estimator's result, then close the block.
    fn block_due(&mut self) -> bool;
    /// [`Self::block_due`]'s usual case: the clock advanced and true where the step closes no
    /// block; false, the clock as it was, where [`Self::block_due`] is to be called.
    fn block_continues(&mut self) -> bool;
    /// [`Self::block_due`] where [`Self::block_continues`] returned false.
    fn block_closes(&mut self) -> bool;
    /// Adopts the estimator task's result.
    fn deliver(&mut self, r: &BlockResult);
    /// Closes the block (when [`Self::block_due`], before the step) and hands its header to
    /// `send` (the queue's enqueue); `None` when it is empty.
    fn close_block<R>(&mut self, send: impl FnOnce(Block) -> R) -> Option<R>;
    /// [`Self::close_block`] in two: the block's samples (0: no header, nothing to send) ...
    fn block_samples(&mut self) -> u32;
    /// ... and its header (of `n` > 0 samples), taken.
    fn header(&mut self, n: u32) -> Block;
    /// U, X, Y of the step just taken, in metres (telemetry).
    fn outputs_m(&self, out: &StepOut) -> [f32; 3];
    /// The finished tap or pixel as a telemetry frame (status bit [`RECORD_READY`]).
    fn take_record(&mut self, index: u32) -> Option<visco_protocol::RecordFrame>;
    /// Current aggregate estimates (c, k, h).
    fn estimate_array(&self) -> [f32; 3];
    /// The running mode, if any.
    fn running_mode(&self) -> Option<Mode>;
}

impl LoopCore for ActiveCore {
    fn apply_command(&mut self, c: CoreCommand) {
        visco_core::Controller::command(
            self,
            match c {
                CoreCommand::Start(Mode::Dive) => {
                    visco_core::Command::Start(visco_core::Mode::Dive)
                }
                CoreCommand::Start(Mode::Sve) => visco_core::Command::Start(visco_core::Mode::Sve),
                CoreCommand::Stop => visco_core::Command::Stop,
            },
        );
    }
    #[inline(always)]
    fn step(&mut self, d: Number, sink: &mut impl SampleSink<Number>) -> StepOut {
        Number::step_loop(self, d, sink)
    }
    #[inline(always)]
    fn block_due(&mut self) -> bool {
        visco_core::Controller::block_due(self)
    }
    #[inline(always)]
    fn block_continues(&mut self) -> bool {
        visco_core::Controller::block_continues(self)
    }
    #[inline(always)]
    fn block_closes(&mut self) -> bool {
        visco_core::Controller::block_closes(self)
    }
    #[inline(always)]
    fn deliver(&mut self, r: &BlockResult) {
        visco_core::Controller::deliver(self, r)
    }
    #[inline(always)]
    fn close_block<R>(&mut self, send: impl FnOnce(Block) -> R) -> Option<R> {
        visco_core::Controller::close_block(self, send)
    }
    #[inline(always)]
    fn block_samples(&mut self) -> u32 {
        visco_core::Controller::block_samples(self)
    }
    #[inline(always)]
    fn header(&mut self, n: u32) -> Block {
        visco_core::Controller::header(self, n)
    }
    #[inline(always)]
    fn outputs_m(&self, out: &StepOut) -> [f32; 3] {
        Number::outputs_m(self, out)
    }
    #[inline]
    fn take_record(&mut self, index: u32) -> Option<visco_protocol::RecordFrame> {
        Number::take_record(self).map(|r| crate::core_config::record_frame(index, &r))
    }
    fn estimate_array(&self) -> [f32; 3] {
        Number::estimates_si(self)
    }
    fn running_mode(&self) -> Option<Mode> {
        visco_core::Controller::mode(self).map(|m| match m {
            visco_core::Mode::Dive => Mode::Dive,
            visco_core::Mode::Sve => Mode::Sve,
        })
    }
}
