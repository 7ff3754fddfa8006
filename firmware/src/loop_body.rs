//! What the loop interrupt does for one sample, independent of the board:
//! command → ADC → `step` → DAC → lateral outputs → telemetry.
//!
//! It never blocks, never allocates and has no panic path: a missing ADC sample is counted
//! and the step skipped; a full telemetry queue is counted, and the main loop turns that
//! count into a gap in the frame sequence numbers, so the host sees the loss too.

use crate::core_glue::{CoreCommand, LoopCore, Mode};
use crate::spsc::Producer;
use core::sync::atomic::{AtomicU32, AtomicU8, Ordering};
use visco_protocol::{RecordFrame, StepFrame};

/// The deflection input (ADC driver and code → metres).
pub trait Adc {
    /// The next sample in metres, or `None` when there is none (counted as starved).
    fn sample(&mut self) -> Option<f32>;
}

/// The actuator output U (DAC driver).
pub trait UOutput {
    /// Writes a signed code relative to mid-scale; returns the DAC word sent.
    fn write(&mut self, code: i32) -> u16;
}

/// The lateral outputs X and Y (metres → codes → DACs).
pub trait XyOutput {
    /// Writes new lateral setpoints (called only when they change).
    fn write(&mut self, x_m: f32, y_m: f32);
}

/// What the loop reports.
#[derive(Clone, Copy, Debug)]
pub enum Item {
    /// One loop sample (replay).
    Step(StepFrame),
    /// One finished tap or pixel.
    Record(RecordFrame),
}

/// Counters written by the loop only and read by the main loop.
#[derive(Debug, Default)]
pub struct Counters {
    /// Samples stepped.
    pub samples: AtomicU32,
    /// Interrupts without a sample (or without a configured core).
    pub starved: AtomicU32,
    /// Telemetry items lost to a full queue.
    pub telemetry_dropped: AtomicU32,
}

impl Counters {
    /// All zero.
    pub const fn new() -> Self {
        Self {
            samples: AtomicU32::new(0),
            starved: AtomicU32::new(0),
            telemetry_dropped: AtomicU32::new(0),
        }
    }
}

/// One writer, so a plain load and store (no exclusive-access loop) is enough.
#[inline(always)]
fn bump(c: &AtomicU32) {
    c.store(c.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
}

/// Depth of the loop → main telemetry queue.
pub const TELEMETRY_DEPTH: usize = 64;
/// The core command waiting for the loop interrupt: Start or Stop, the latest one wins.
///
/// A single byte rather than a queue because the loop checks it on every sample: one
/// relaxed load, no barrier, when empty. The main loop overwrites an untaken command (only
/// the latest intent matters: Stop then Start is a Start); the loop takes it with an atomic
/// swap, so a command posted while the loop takes the previous one is never lost.
#[derive(Debug, Default)]
pub struct CommandSlot(AtomicU8);

impl CommandSlot {
    /// Empty.
    pub const fn new() -> Self {
        Self(AtomicU8::new(0))
    }
    /// Posts a command (main loop), replacing one not taken yet.
    pub fn post(&self, c: CoreCommand) {
        self.0.store(
            match c {
                CoreCommand::Stop => 1,
                CoreCommand::Start(Mode::Dive) => 2,
                CoreCommand::Start(Mode::Sve) => 3,
            },
            Ordering::Release,
        );
    }
    /// Takes the waiting command, if any (loop interrupt).
    #[inline(always)]
    pub fn take(&self) -> Option<CoreCommand> {
        if self.0.load(Ordering::Relaxed) == 0 {
            return None;
        }
        match self.0.swap(0, Ordering::Acquire) {
            1 => Some(CoreCommand::Stop),
            2 => Some(CoreCommand::Start(Mode::Dive)),
            3 => Some(CoreCommand::Start(Mode::Sve)),
            _ => None,
        }
    }
}

/// Everything the loop interrupt owns.
pub struct LoopState<A, U, X, C> {
    /// Deflection input.
    pub adc: A,
    /// Actuator output.
    pub u_out: U,
    /// Lateral outputs.
    pub xy_out: X,
    /// The identification core (`None` until a configuration was applied: no steps).
    pub core: Option<C>,
    /// Loop → main telemetry.
    pub telemetry: Producer<'static, Item, TELEMETRY_DEPTH>,
    /// Main → loop commands.
    pub commands: &'static CommandSlot,
    /// Shared counters.
    pub counters: &'static Counters,
    /// Emit a Step item per sample.
    pub per_sample: bool,
    /// Sample index (since the source was last set).
    pub index: u32,
    last_xy: (u32, u32),
}

impl<A: Adc, U: UOutput, X: XyOutput, C: LoopCore> LoopState<A, U, X, C> {
    /// Assembles the loop state.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        adc: A,
        u_out: U,
        xy_out: X,
        core: Option<C>,
        telemetry: Producer<'static, Item, TELEMETRY_DEPTH>,
        commands: &'static CommandSlot,
        counters: &'static Counters,
    ) -> Self {
        Self {
            adc,
            u_out,
            xy_out,
            core,
            telemetry,
            commands,
            counters,
            per_sample: false,
            index: 0,
            // NaN bits: the first step always writes the lateral outputs.
            last_xy: (u32::MAX, u32::MAX),
        }
    }

    /// One loop sample. Called from the loop interrupt only.
    #[inline(always)]
    pub fn on_sample(&mut self) {
        let Some(core) = self.core.as_mut() else {
            bump(&self.counters.starved);
            return;
        };
        if let Some(cmd) = self.commands.take() {
            core.command(cmd);
        }
        let Some(d) = self.adc.sample() else {
            bump(&self.counters.starved);
            return;
        };
        let out = core.step(d);
        let dac_word = self.u_out.write(out.u_code);
        // Lateral DACs are written only when the setpoint moves (once per pixel in SVE):
        // three SPI writes per sample would not fit 1 MHz.
        let xy = (out.x_m.to_bits(), out.y_m.to_bits());
        if xy != self.last_xy {
            self.last_xy = xy;
            self.xy_out.write(out.x_m, out.y_m);
        }
        if self.per_sample {
            let estimates = core.estimates();
            self.emit(Item::Step(StepFrame {
                index: self.index,
                d_m: d,
                u_code: out.u_code,
                dac_word,
                u_m: out.u_m,
                x_m: out.x_m,
                y_m: out.y_m,
                status: out.status,
                estimates,
            }));
        }
        if let Some(r) = out.record {
            self.emit(Item::Record(RecordFrame {
                index: self.index,
                mode: match r.mode {
                    crate::core_glue::Mode::Dive => 1,
                    crate::core_glue::Mode::Sve => 2,
                },
                estimates: r.estimates,
                x_m: r.x_m,
                y_m: r.y_m,
                status: r.status,
            }));
        }
        self.index = self.index.wrapping_add(1);
        bump(&self.counters.samples);
    }

    #[inline(always)]
    fn emit(&mut self, item: Item) {
        if self.telemetry.push(item).is_err() {
            bump(&self.counters.telemetry_dropped);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core_glue::{build_core, StagedConfig};
    use crate::scale::Scale;
    use crate::spsc::Spsc;
    use std::vec::Vec;

    struct Fed(Vec<f32>);
    impl Adc for Fed {
        fn sample(&mut self) -> Option<f32> {
            if self.0.is_empty() {
                None
            } else {
                Some(self.0.remove(0))
            }
        }
    }
    #[derive(Default)]
    struct Words(Vec<u16>);
    impl UOutput for Words {
        fn write(&mut self, code: i32) -> u16 {
            let w = crate::drivers::ad5541::word_for(code);
            self.0.push(w);
            w
        }
    }
    #[derive(Default)]
    struct Xy(Vec<(f32, f32)>);
    impl XyOutput for Xy {
        fn write(&mut self, x: f32, y: f32) {
            self.0.push((x, y));
        }
    }

    #[test]
    fn steps_counts_and_reports_drops() {
        static TEL: Spsc<Item, TELEMETRY_DEPTH> = Spsc::new();
        static CMD: CommandSlot = CommandSlot::new();
        static COUNTERS: Counters = Counters::new();
        let (tp, mut tc) = TEL.split().unwrap();
        let scale = Scale::new_16bit(1e-9).unwrap();
        let mut cfg = StagedConfig::new();
        assert!(cfg.stage(crate::core_glue::standin_param::RECORD_EVERY, 10.0));
        let core = build_core(&cfg, &scale).unwrap();
        let input: Vec<f32> = (0..100).map(|i| i as f32 * 1e-10).collect();
        let mut st = LoopState::new(
            Fed(input),
            Words::default(),
            Xy::default(),
            Some(core),
            tp,
            &CMD,
            &COUNTERS,
        );
        st.per_sample = true;
        CMD.post(CoreCommand::Stop);
        CMD.post(CoreCommand::Start(Mode::Sve)); // the latest intent wins
        for _ in 0..101 {
            st.on_sample();
        }
        assert_eq!(COUNTERS.samples.load(Ordering::Relaxed), 100);
        assert_eq!(COUNTERS.starved.load(Ordering::Relaxed), 1);
        // 100 steps + 10 records = 110 items, 64 fit: 46 dropped and counted.
        assert_eq!(COUNTERS.telemetry_dropped.load(Ordering::Relaxed), 46);
        let mut n = 0;
        while tc.pop().is_some() {
            n += 1;
        }
        assert_eq!(n, 64);
        assert_eq!(st.u_out.0.len(), 100);
        assert!(st.xy_out.0.len() >= 2);
        assert_eq!(st.core.as_ref().unwrap().mode(), Some(Mode::Sve));
    }
}
