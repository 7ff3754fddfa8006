//! What the loop interrupt does for one sample, independent of the board:
//! command → ADC → at a block close: the estimator's result adopted and the block's header
//! handed to the estimator → `step` (while a mode runs, the sample's Z and U queued for the
//! estimator task, which runs the prefilters and the regressor) → DAC → lateral outputs →
//! telemetry.
//!
//! It never blocks, never allocates and has no panic path: a missing ADC sample is counted
//! and the step skipped; a full telemetry queue is counted, and the main loop turns that
//! count into a gap in the frame sequence numbers, so the host sees the loss too.

use crate::core_glue::{
    Block, BlockResult, CoreCommand, EstimatorTask, LoopCore, LoopReal, Mode, Number, Sample,
    SampleSink, RECORD_READY,
};
use core::sync::atomic::{AtomicU32, AtomicU8, Ordering};
use heapless::spsc::Consumer;
use heapless::spsc::Producer;
use visco_protocol::{RecordFrame, StepFrame};

/// The deflection input (ADC driver and code → the core's input, [`crate::scale::Scale`]).
pub trait Adc {
    /// The next sample as the core's `step` takes it (metres in f32, nm in fixed point), or
    /// `None` when there is none (counted as starved).
    fn sample(&mut self) -> Option<Number>;
}

/// The actuator output U (DAC driver).
pub trait UOutput {
    /// Writes a signed code relative to mid-scale; returns the DAC word sent.
    fn write(&mut self, code: i32) -> u16;
}

/// The lateral outputs X and Y (the core's DAC codes, signed relative to mid-scale).
pub trait XyOutput {
    /// Writes new lateral setpoints (called only when they change).
    fn write(&mut self, x_code: i32, y_code: i32);
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
    /// Estimator results not back when due (the estimator interrupt overran its N samples;
    /// the result is adopted at the next block close instead).
    pub estimator_late: AtomicU32,
    /// Blocks lost to a full estimator queue (their queued samples are discarded by the task).
    pub blocks_dropped: AtomicU32,
    /// Samples lost to a full sample queue (the estimator interrupt more than
    /// [`SAMPLE_DEPTH`] samples behind). The block they belong to is handed over without
    /// information: the task discards its queued samples, applies its restarts, and θ̂ stays.
    pub samples_dropped: AtomicU32,
}

impl Counters {
    /// All zero.
    pub const fn new() -> Self {
        Self {
            samples: AtomicU32::new(0),
            starved: AtomicU32::new(0),
            telemetry_dropped: AtomicU32::new(0),
            estimator_late: AtomicU32::new(0),
            blocks_dropped: AtomicU32::new(0),
            samples_dropped: AtomicU32::new(0),
        }
    }
}

/// One writer, so a plain load and store (no exclusive-access loop) is enough.
#[inline(always)]
fn bump(c: &AtomicU32) {
    c.store(c.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
}

/// Block headers (and results) the queues between the loop and the estimator interrupt hold:
/// one is in flight by the schedule (`visco_core::schedule`); the rest is slack for an overrun.
pub const ESTIMATOR_DEPTH: usize = 4;

/// Samples the loop → estimator sample queue holds (`heapless::spsc::Queue` of this + 1
/// slots, a power of two, so that its indices wrap with a mask): up to two blocks of
/// the largest N (64) wait by the schedule (the block being handed over and the one the task
/// works on), the rest is slack for an overrun.
pub const SAMPLE_DEPTH: usize = 255;

/// The loop's end of the estimator task: the samples of a running mode (the [`SampleSink`])
/// and block headers out, results back.
pub trait EstimatorLink: SampleSink<Number> {
    /// Hands over a block header (and wakes the task); false when the queue is full.
    fn send(&mut self, b: Block) -> bool;
    /// The next result, if the task has one.
    fn receive(&mut self) -> Option<BlockResult>;
    /// A new core (thread mode, both interrupts masked, the task's queues emptied): nothing
    /// handed over is pending any more.
    fn reset(&mut self) {}
}

/// The firmware's link: three `heapless::spsc` queues and the estimator interrupt pended.
///
/// A full queue loses what did not fit, deterministically, and keeps the task's reading of
/// the sample queue in step with the headers: a sample that does not fit is counted
/// (`samples_dropped`), and the next header then hands over its block without information
/// (its queued samples to be discarded); a header that does not fit is counted
/// (`blocks_dropped`), and its queued samples are discarded with the next header.
pub struct QueueLink {
    /// Loop → estimator, the block headers.
    pub blocks: Producer<'static, Block>,
    /// Loop → estimator, the samples.
    pub samples: Producer<'static, Sample>,
    /// Estimator → loop.
    pub results: Consumer<'static, BlockResult>,
    /// Pends the estimator interrupt (the board's).
    pub pend: fn(),
    /// Where lost samples are counted.
    pub counters: &'static Counters,
    /// Samples that did not fit the queue since the last header.
    lost: u32,
    /// Samples in the queue whose header did not fit.
    carry: u32,
}

impl QueueLink {
    /// The link over the queues' loop ends.
    pub fn new(
        blocks: Producer<'static, Block>,
        samples: Producer<'static, Sample>,
        results: Consumer<'static, BlockResult>,
        pend: fn(),
        counters: &'static Counters,
    ) -> Self {
        Self {
            blocks,
            samples,
            results,
            pend,
            counters,
            lost: 0,
            carry: 0,
        }
    }

    /// The header after losses: samples of its block that did not fit make the whole block
    /// one to discard; samples of lost headers are discarded first.
    #[inline(always)]
    fn amend(&mut self, mut b: Block) -> Block {
        if self.lost != 0 {
            // What of the header's samples (the discarded ones and the block's) is queued.
            b.skip = b.skip.wrapping_add(b.samples).wrapping_sub(self.lost);
            b.samples = 0;
        }
        b.skip = b.skip.wrapping_add(self.carry);
        self.lost = 0;
        self.carry = 0;
        b
    }
}

impl SampleSink<Number> for QueueLink {
    #[inline(always)]
    fn push(&mut self, s: Sample) {
        if self.samples.enqueue(s).is_err() {
            self.lost = self.lost.wrapping_add(1);
            bump(&self.counters.samples_dropped);
        }
    }
}

impl EstimatorLink for QueueLink {
    #[inline(always)]
    fn send(&mut self, b: Block) -> bool {
        let b = if (self.lost | self.carry) != 0 {
            self.amend(b)
        } else {
            b
        };
        let ok = match self.blocks.enqueue(b) {
            Ok(()) => true,
            Err(b) => {
                self.carry = self.carry.wrapping_add(b.skip.wrapping_add(b.samples));
                false
            }
        };
        (self.pend)();
        ok
    }
    #[inline(always)]
    fn receive(&mut self) -> Option<BlockResult> {
        self.results.dequeue()
    }
    fn reset(&mut self) {
        self.lost = 0;
        self.carry = 0;
    }
}

/// The estimator interrupt's state: the task and its ends of the queues.
pub struct EstimatorState {
    /// The estimators.
    pub task: EstimatorTask,
    /// Loop → estimator, the block headers.
    pub blocks: Consumer<'static, Block>,
    /// Loop → estimator, the samples.
    pub samples: Consumer<'static, Sample>,
    /// Estimator → loop.
    pub results: Producer<'static, BlockResult>,
}

impl EstimatorState {
    /// The estimator interrupt's body: [`run_blocks`].
    #[inline(always)]
    pub fn run(&mut self) {
        run_blocks(
            &mut self.task,
            &mut self.blocks,
            &mut self.samples,
            &mut self.results,
        );
    }

    /// Empties the loop → estimator queues (thread mode, both interrupts masked).
    pub fn clear(&mut self) {
        while self.blocks.dequeue().is_some() {}
        while self.samples.dequeue().is_some() {}
    }
}

/// Every waiting block, in order: its samples out of the queue through the task's filters
/// (the ones to discard first, then the block's, the estimating ones into the block sums), the
/// block update, the result queued back. A header is queued after all its samples, so they
/// are there (should one be missing, the block takes those there are).
#[inline(always)]
pub fn run_blocks(
    task: &mut EstimatorTask,
    blocks: &mut Consumer<'_, Block>,
    samples: &mut Consumer<'_, Sample>,
    results: &mut Producer<'_, BlockResult>,
) {
    while let Some(b) = blocks.peek() {
        let r = task.run(b, core::iter::from_fn(|| samples.dequeue()));
        // The value is not read again: this only frees the slot.
        let _ = blocks.dequeue();
        // Cannot be full: at most as many results as blocks, and the queues are alike.
        let _ = results.enqueue(r);
    }
}

/// Items the loop → main telemetry queue holds (`heapless::spsc::Queue` of this + 1 slots).
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

/// Everything the loop interrupt owns. `repr(C)` with the core first: its hot fields stay
/// within immediate-offset reach of the structure's base (see `visco_core::Controller`).
#[repr(C)]
pub struct LoopState<A, U, X, C, E> {
    /// The identification core.
    pub core: C,
    /// Deflection input.
    pub adc: A,
    /// Actuator output.
    pub u_out: U,
    /// Lateral outputs.
    pub xy_out: X,
    /// The estimator task's queues.
    pub estimator: E,
    /// Blocks handed over whose results have not come back.
    in_flight: u32,
    /// Loop → main telemetry.
    pub telemetry: Producer<'static, Item>,
    /// Main → loop commands.
    pub commands: &'static CommandSlot,
    /// Shared counters.
    pub counters: &'static Counters,
    /// Emit a Step item per sample.
    pub per_sample: bool,
    /// The sample counter's value when the source was last set: the index of a sample in
    /// the telemetry is `counters.samples − index_base` (one counter per sample, not two).
    pub index_base: u32,
    last_xy: (i32, i32),
}

impl<A: Adc, U: UOutput, X: XyOutput, C: LoopCore, E: EstimatorLink> LoopState<A, U, X, C, E> {
    /// Assembles the loop state.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        adc: A,
        u_out: U,
        xy_out: X,
        core: C,
        estimator: E,
        telemetry: Producer<'static, Item>,
        commands: &'static CommandSlot,
        counters: &'static Counters,
    ) -> Self {
        Self {
            adc,
            u_out,
            xy_out,
            core,
            estimator,
            in_flight: 0,
            telemetry,
            commands,
            counters,
            per_sample: false,
            index_base: 0,
            // Out of any DAC's range: the first step always writes the lateral outputs.
            last_xy: (i32::MIN, i32::MIN),
        }
    }

    /// One loop sample. Called from the loop interrupt only.
    #[inline(always)]
    pub fn on_sample(&mut self) {
        let core = &mut self.core;
        if let Some(cmd) = self.commands.take() {
            core.apply_command(cmd);
        }
        let Some(d) = self.adc.sample() else {
            bump(&self.counters.starved);
            return;
        };
        if core.block_due() {
            if self.in_flight > 0 {
                // The schedule: the last block's result is adopted now, before this step.
                let mut got = false;
                while let Some(r) = self.estimator.receive() {
                    core.deliver(&r);
                    self.in_flight -= 1;
                    got = true;
                }
                if !got {
                    bump(&self.counters.estimator_late);
                }
            }
            // The block closes at the start of this sample: straight into the queue.
            let estimator = &mut self.estimator;
            match core.close_block(|b| estimator.send(b)) {
                Some(true) => self.in_flight += 1,
                Some(false) => bump(&self.counters.blocks_dropped),
                None => {}
            }
        }
        let out = core.step(d, &mut self.estimator);
        let dac_word = self.u_out.write(out.u_code);
        // Lateral DACs are written only when the setpoint moves (once per pixel in SVE):
        // three SPI writes per sample would not fit 1 MHz.
        let xy = (out.x_code, out.y_code);
        if xy != self.last_xy {
            self.last_xy = xy;
            self.xy_out.write(out.x_code, out.y_code);
        }
        if self.per_sample {
            let estimates = self.core.estimate_array();
            let [u_m, x_m, y_m] = self.core.outputs_m(&out);
            let index = self.index();
            emit(
                &mut self.telemetry,
                self.counters,
                Item::Step(StepFrame {
                    index,
                    d_m: Number::to_metres(d),
                    u_code: out.u_code,
                    dac_word,
                    u_m,
                    x_m,
                    y_m,
                    status: out.status,
                    estimates,
                }),
            );
        }
        if out.status & RECORD_READY != 0 {
            let index = self.index();
            if let Some(r) = self.core.take_record(index) {
                emit(&mut self.telemetry, self.counters, Item::Record(r));
            }
        }
        bump(&self.counters.samples);
    }

    /// The index of the sample being stepped (since the source was last set).
    #[inline(always)]
    pub fn index(&self) -> u32 {
        self.counters
            .samples
            .load(Ordering::Relaxed)
            .wrapping_sub(self.index_base)
    }

    /// A new core (thread mode, with both interrupts masked): nothing is in flight any more
    /// (the caller empties the queues).
    pub fn replace_core(&mut self, core: C) {
        self.core = core;
        self.in_flight = 0;
        while self.estimator.receive().is_some() {}
        self.estimator.reset();
    }

    /// Restarts the sample index at 0 (a new source).
    pub fn reset_index(&mut self) {
        self.index_base = self.counters.samples.load(Ordering::Relaxed);
    }
}

/// Queues a telemetry item, or counts it as dropped when the queue is full.
#[inline(always)]
fn emit(q: &mut Producer<'static, Item>, counters: &Counters, item: Item) {
    if q.enqueue(item).is_err() {
        bump(&counters.telemetry_dropped);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core_glue::{build_core, StagedConfig};
    use heapless::spsc::Queue;
    use std::vec::Vec;

    struct Fed(Vec<Number>);
    impl Adc for Fed {
        fn sample(&mut self) -> Option<Number> {
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
    struct Xy(Vec<(i32, i32)>);
    impl XyOutput for Xy {
        fn write(&mut self, x: i32, y: i32) {
            self.0.push((x, y));
        }
    }

    /// The estimator task run at once (as the host's `Controller::step` does).
    struct Inline(
        EstimatorTask,
        Option<BlockResult>,
        std::collections::VecDeque<Sample>,
    );
    impl SampleSink<Number> for Inline {
        fn push(&mut self, s: Sample) {
            self.2.push_back(s);
        }
    }
    impl EstimatorLink for Inline {
        fn send(&mut self, b: Block) -> bool {
            let q = &mut self.2;
            self.1 = Some(self.0.run(&b, core::iter::from_fn(|| q.pop_front())));
            true
        }
        fn receive(&mut self) -> Option<BlockResult> {
            self.1.take()
        }
    }

    /// A full sample queue and a full header queue lose what does not fit, count it, and keep
    /// the task's reading of the samples in step with the headers.
    #[test]
    fn full_queues_lose_whole_blocks_and_stay_in_step() {
        use visco_core::schedule::Target;
        static COUNTERS: Counters = Counters::new();
        fn leak<T, const N: usize>() -> &'static mut Queue<T, N> {
            std::boxed::Box::leak(std::boxed::Box::new(Queue::new()))
        }
        let (btx, mut brx) = leak::<Block, { ESTIMATOR_DEPTH + 1 }>().split();
        let (stx, mut srx) = leak::<Sample, { SAMPLE_DEPTH + 1 }>().split();
        let (mut rtx, rrx) = leak::<BlockResult, { ESTIMATOR_DEPTH + 1 }>().split();
        let mut link = QueueLink::new(btx, stx, rrx, || {}, &COUNTERS);
        let mut task = build_core(&StagedConfig::new(), None).unwrap().task;
        let theta0 = task.theta(Target::Dive3);
        let header = |skip: u32, samples: u32| Block {
            restart: None,
            restart_watch: false,
            epoch: 0,
            target: Target::Dive3,
            skip,
            samples,
        };
        let v = |x: f64| <Number as visco_core::Real>::from_f64(x);
        let x = Sample {
            z: v(5.0),
            u: v(1.0),
            r: v(2.0),
            flags: visco_core::schedule::SAMPLE_EST,
        };
        // The estimator stalled for 300 samples: 45 do not fit; the block (3 to discard after
        // a restart, 297 its own) is handed over without information.
        for _ in 0..300 {
            link.push(x);
        }
        assert_eq!(COUNTERS.samples_dropped.load(Ordering::Relaxed), 45);
        assert!(link.send(header(3, 297)));
        let b = *brx.peek().unwrap();
        assert_eq!((b.skip, b.samples), (255, 0));
        run_blocks(&mut task, &mut brx, &mut srx, &mut rtx);
        let r = link.receive().unwrap();
        assert_eq!((r.flags, r.theta), (0, theta0));
        assert!(srx.dequeue().is_none());
        // Headers: four fit; the fifth is lost, and its sample is discarded with the next.
        for k in 0..6 {
            link.push(x);
            assert_eq!(link.send(header(0, 1)), k < ESTIMATOR_DEPTH);
        }
        let skips: std::vec::Vec<(u32, u32)> = std::iter::from_fn(|| brx.dequeue())
            .map(|b| (b.skip, b.samples))
            .collect();
        assert_eq!(skips, [(0, 1); ESTIMATOR_DEPTH]);
        link.push(x);
        assert!(link.send(header(0, 1)));
        assert_eq!(brx.peek().map(|b| (b.skip, b.samples)), Some((2, 1)));
        // In step: four samples taken, then the two lost headers' (through the filters) and
        // this block's.
        for _ in 0..ESTIMATOR_DEPTH {
            srx.dequeue();
        }
        let mut alone = task;
        let want = alone.run(&header(2, 1), [x; 3].into_iter());
        run_blocks(&mut task, &mut brx, &mut srx, &mut rtx);
        assert!(srx.dequeue().is_none());
        let got = link.receive().unwrap();
        assert_eq!((got.theta, got.flags), (want.theta, want.flags));
    }

    #[test]
    fn steps_counts_and_reports_drops() {
        static CMD: CommandSlot = CommandSlot::new();
        static COUNTERS: Counters = Counters::new();
        let tel: &'static mut Queue<Item, { TELEMETRY_DEPTH + 1 }> =
            std::boxed::Box::leak(std::boxed::Box::new(Queue::new()));
        let (tp, mut tc) = tel.split();
        let built = build_core(&StagedConfig::new(), None).unwrap();
        // Free cantilever: D = 0; the core moves to the first tap, then approaches.
        let n = 3000;
        let mut st = LoopState::new(
            Fed(std::vec![Number::from_metres(0.0); n]),
            Words::default(),
            Xy::default(),
            built.core,
            Inline(built.task, None, Default::default()),
            tp,
            &CMD,
            &COUNTERS,
        );
        st.per_sample = true;
        CMD.post(CoreCommand::Stop);
        CMD.post(CoreCommand::Start(Mode::Dive)); // the latest intent wins
        for _ in 0..n + 1 {
            st.on_sample();
        }
        assert_eq!(COUNTERS.samples.load(Ordering::Relaxed), n as u32);
        assert_eq!(st.index(), n as u32);
        st.reset_index();
        assert_eq!(st.index(), 0);
        assert_eq!(COUNTERS.starved.load(Ordering::Relaxed), 1);
        // One Step item per sample, 64 fit: the rest is dropped and counted.
        assert_eq!(
            COUNTERS.telemetry_dropped.load(Ordering::Relaxed),
            n as u32 - TELEMETRY_DEPTH as u32
        );
        let mut k = 0;
        while let Some(item) = tc.dequeue() {
            match item {
                Item::Step(s) => assert_eq!(s.index, k),
                Item::Record(_) => panic!("no tap finishes in 3 ms"),
            }
            k += 1;
        }
        assert_eq!(k, TELEMETRY_DEPTH as u32);
        assert_eq!(st.u_out.0.len(), n);
        // The core starts above the first tap: the lateral DACs are written once, then hold.
        assert_eq!(st.xy_out.0.len(), 1);
        assert_eq!(st.core.running_mode(), Some(Mode::Dive));
    }
}
