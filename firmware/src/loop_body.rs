//! What the loop interrupt does for one sample, independent of the board:
//! command → ADC → at a block close: the estimator's result adopted and the block (its header
//! and samples) handed to the estimator → `step` (while a mode runs, the sample's Z and U
//! staged for the estimator task, which runs the prefilters and the regressor) → DAC → lateral outputs →
//! telemetry.
//!
//! It never blocks, never allocates and has no panic path: a missing ADC sample is counted
//! and the step skipped; a full telemetry queue is counted, and the main loop turns that
//! count into a gap in the frame sequence numbers, so the host sees the loss too.

use crate::core_glue::{
    Block, BlockResult, ChunkKey, CoreCommand, EstimatorTask, LoopCore, LoopReal, Mode, Number,
    Sample, SampleSink, ToneChunk, ToneSource, RECORD_READY,
};
use core::sync::atomic::{AtomicU32, AtomicU8, Ordering};
use heapless::spsc::Consumer;
use heapless::spsc::Producer;
use heapless::spsc::Queue;
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
    /// Block closes at which an estimator result was still out (the estimator interrupt
    /// overran its N samples; the result is adopted at a later close instead).
    pub estimator_late: AtomicU32,
    /// Blocks lost to a full estimator queue (with their samples).
    pub blocks_dropped: AtomicU32,
    /// Samples that did not fit a block's [`BLOCK_MAX`] (never, by the schedule). The block
    /// they belong to is handed over without information: its samples only feed the filters,
    /// its restarts apply, and θ̂ stays.
    pub samples_dropped: AtomicU32,
    /// Chunks of tones the estimator task had not computed when they began (the start of a
    /// mode, a late task, a chunk the task had no free buffer for): the loop ran its own
    /// oscillators for them, with the same values.
    pub tones_late: AtomicU32,
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
            tones_late: AtomicU32::new(0),
        }
    }
}

/// One writer, so a plain load and store (no exclusive-access loop) is enough.
#[inline(always)]
fn bump(c: &AtomicU32) {
    c.store(c.load(Ordering::Relaxed).wrapping_add(1), Ordering::Relaxed);
}

/// Blocks (and results) the queues between the loop and the estimator interrupt hold: one is
/// in flight by the schedule (`visco_core::schedule`); the rest is slack for an overrun.
pub const ESTIMATOR_DEPTH: usize = 4;

/// Block buffers ([`SampleBlock`]) in circulation: the one the loop stages into and up to
/// [`ESTIMATOR_DEPTH`] handed over.
pub const BLOCK_BUFFERS: usize = ESTIMATOR_DEPTH + 1;

/// Slots of the queues that move block buffers (loop → task full, task → loop free): a power
/// of two (the indices wrap with a mask) holding every buffer, so neither is ever full.
pub const BUFFER_SLOTS: usize = 8;

/// The most samples one block hands over: the largest block (`estimator.decimation` ≤ 64).
/// A block's samples after a restart and those before it to discard are one window of the
/// sample clock, so they fit too.
/// The core's: the host stages as many (`visco_core::schedule::Staged`), so that a block
/// that does not fit is lost alike on both.
pub const BLOCK_MAX: usize = visco_core::schedule::BLOCK_MAX;

/// Chunks of tones in circulation ([`ToneChunk`], issue 14, round 7): the one the loop reads
/// and those the task computed ahead (one or two per block, two blocks ahead at most) or
/// holds free.
pub const TONE_CHUNKS: usize = 6;

/// Slots of the queues that move chunks of tones (task → loop ready, loop → task free): a
/// power of two holding every chunk.
pub const TONE_SLOTS: usize = 8;

/// A chunk of tones, owned by whichever side holds the reference.
pub type ToneBuf<'a> = &'a mut ToneChunk;

// Every chunk fits in either queue (an spsc queue of N slots holds N − 1).
const _: () = assert!(TONE_SLOTS > TONE_CHUNKS);

/// The loop's and the task's ends of the chunks of tones, over `chunks` and the two queues
/// (task → loop ready, loop → task free): the loop holds the first chunk, the others start
/// free.
pub fn tone_ends<'a, 'b>(
    chunks: &'b mut [ToneChunk; TONE_CHUNKS],
    ready: &'a mut Queue<ToneBuf<'b>, TONE_SLOTS>,
    free: &'a mut Queue<ToneBuf<'b>, TONE_SLOTS>,
) -> (ToneLink<'a, 'b>, TonePrep<'a, 'b>) {
    let (ready_tx, ready_rx) = ready.split();
    let (mut free_tx, free_rx) = free.split();
    let [held, rest @ ..] = chunks;
    for c in rest {
        // Cannot fail: the queue holds every chunk (asserted above).
        let _ = free_tx.enqueue(c);
    }
    (
        ToneLink::new(held, ready_rx, free_tx),
        TonePrep::new(ready_tx, free_rx),
    )
}

/// The loop's end of the chunks of tones: the chunk it reads, the ready ones (in order) and
/// the free ones back. At a chunk's first sample the excitation asks for the chunk of its
/// key ([`ToneSource::take_tones`]): the ready ones before it (stale: a mode changed its
/// tones, or a chunk the excitation never reached) are handed back free, the one for it
/// taken (and the one read before handed back); none: the loop runs its oscillators for this
/// chunk (counted, `tones_late`).
pub struct ToneLink<'a, 'b> {
    /// The chunk being read.
    cur: ToneBuf<'b>,
    /// Task → loop, chunks computed.
    pub ready: Consumer<'a, ToneBuf<'b>>,
    /// Loop → task, chunks read.
    pub free: Producer<'a, ToneBuf<'b>>,
}

impl<'a, 'b> ToneLink<'a, 'b> {
    /// The loop's end, holding `cur` (its key matches no chunk).
    pub fn new(
        cur: ToneBuf<'b>,
        ready: Consumer<'a, ToneBuf<'b>>,
        free: Producer<'a, ToneBuf<'b>>,
    ) -> Self {
        cur.key.chunk = 0;
        Self { cur, ready, free }
    }

    /// [`ToneSource::take_tones`]: the ready chunk for `key` taken (true), the stale ones
    /// before it handed back free.
    #[inline(always)]
    pub fn take(&mut self, key: &ChunkKey) -> bool {
        while let Some(c) = self.ready.peek() {
            if c.key.chunk.wrapping_sub(key.chunk) as i32 > 0 {
                // Ahead of this chunk: this one was not computed.
                break;
            }
            let hit = c.key == *key;
            let Some(c) = self.ready.dequeue() else { break };
            if hit {
                let read = core::mem::replace(&mut self.cur, c);
                // Cannot be full: the queue holds every chunk.
                let _ = self.free.enqueue(read);
                return true;
            }
            // Stale: handed back.
            let _ = self.free.enqueue(c);
        }
        false
    }

    /// [`ToneSource::tone`]: the value of the chunk being read.
    #[inline(always)]
    pub fn tone(&self, left: u32) -> Number {
        let i = (left & (visco_core::excitation::RESYNC - 1)) as usize;
        // i < RESYNC, the array's length: no bounds test.
        self.cur.values[i]
    }

    /// Hands every ready chunk back (a new core: thread mode, both interrupts masked).
    pub fn reset(&mut self) {
        while let Some(c) = self.ready.dequeue() {
            let _ = self.free.enqueue(c);
        }
        self.cur.key.chunk = 0;
    }
}

/// The task's end of the chunks of tones: free ones in, computed ones out, and the next chunk
/// count it has not computed (a chunk asked for again, while the tones stand still, is not
/// computed twice).
pub struct TonePrep<'a, 'b> {
    /// Task → loop, chunks computed.
    pub ready: Producer<'a, ToneBuf<'b>>,
    /// Loop → task, chunks read.
    pub free: Consumer<'a, ToneBuf<'b>>,
    /// The first chunk count not computed yet.
    pub next: u32,
}

impl<'a, 'b> TonePrep<'a, 'b> {
    /// The task's end.
    pub fn new(ready: Producer<'a, ToneBuf<'b>>, free: Consumer<'a, ToneBuf<'b>>) -> Self {
        Self {
            ready,
            free,
            next: 1,
        }
    }

    /// The chunks a block's header asks for, each into a free chunk and queued ready.
    #[inline(always)]
    pub fn run(&mut self, task: &EstimatorTask, header: &Block) {
        task.tones_ahead(&header.tones, |key, p| {
            // Wrapping order: a chunk at or after `next`.
            if (key.chunk.wrapping_sub(self.next) as i32) < 0 {
                return;
            }
            self.next = key.chunk.wrapping_add(1);
            if let Some(c) = self.free.dequeue() {
                c.key = *key;
                EstimatorTask::fill(p, key, &mut c.values);
                // Cannot be full: the queue holds every chunk.
                let _ = self.ready.enqueue(c);
            }
        });
    }
}

/// One block handed over whole, loop → estimator task: its header and its samples (the
/// `skip` to discard first, then the block's own). The buffers circulate by reference (a
/// pointer per queue item, no copy): the loop writes the samples of a block into the one it
/// holds, hands it over at the close and takes a free one back, and the task reads the
/// samples as a slice, so its filters stay in registers across the block, without a queue
/// operation (and its barriers) per sample.
#[derive(Clone, Copy, Debug)]
pub struct SampleBlock {
    /// What the block is for, and how many of `samples` to discard and to use.
    pub header: Block,
    /// Samples staged, `header.skip + header.samples` (at most [`BLOCK_MAX`]).
    pub n: u32,
    /// The samples, in order; those from `n` on are stale.
    pub samples: [Sample; BLOCK_MAX],
}

/// A block header before it is filled: an empty buffer's, and what [`EstimatorLink::send_with`]
/// hands its `fill`.
const EMPTY_HEADER: Block = Block {
    restart: None,
    restart_watch: false,
    epoch: 0,
    target: visco_core::schedule::Target::Dive2,
    skip: 0,
    samples: 0,
    tones: visco_core::schedule::ToneAhead::NONE,
};

impl SampleBlock {
    /// Empty, before the first sample.
    pub const fn new() -> Self {
        Self {
            header: EMPTY_HEADER,
            n: 0,
            samples: [Sample {
                z: <Number as visco_core::Real>::ZERO,
                u: <Number as visco_core::Real>::ZERO,
                r: <Number as visco_core::Real>::ZERO,
                flags: 0,
            }; BLOCK_MAX],
        }
    }

    /// The staged samples.
    #[inline(always)]
    pub fn staged(&mut self) -> &mut [Sample] {
        let n = self.n as usize;
        self.samples.get_mut(..n).unwrap_or(&mut [])
    }
}

impl Default for SampleBlock {
    fn default() -> Self {
        Self::new()
    }
}

/// A block buffer, owned by whichever side holds the reference.
pub type BlockBuf<'a> = &'a mut SampleBlock;

/// The loop's end of the estimator task: the samples of a running mode (the [`SampleSink`])
/// and block headers out, results back.
pub trait EstimatorLink: SampleSink<Number> {
    /// Hands over a block header with the samples since the last one (and wakes the task);
    /// false when the block is lost.
    fn send(&mut self, b: Block) -> bool;
    /// [`Self::send`] with the header written by `fill` (called once, also when the block is
    /// lost) where the link keeps it.
    #[inline(always)]
    fn send_with(&mut self, fill: impl FnOnce(&mut Block)) -> bool {
        let mut b = EMPTY_HEADER;
        fill(&mut b);
        self.send(b)
    }
    /// The next result, if the task has one.
    fn receive(&mut self) -> Option<BlockResult>;
    /// A new core (thread mode, both interrupts masked, the task's queues emptied): nothing
    /// handed over is pending any more.
    fn reset(&mut self) {}
}

/// The firmware's link: the block buffer being staged, two `heapless::spsc` queues of block
/// buffers (full ones to the task, free ones back), the results queue and the estimator
/// interrupt pended.
///
/// The samples of a block are written into the staged buffer (no queue operation per sample);
/// at the close the buffer is handed over and a free one taken. Losses are deterministic and
/// lose whole blocks: a sample that does not fit the buffer (more than [`BLOCK_MAX`] since the
/// last header, which the schedule never hands over) is counted (`samples_dropped`) and its
/// block is handed over without information (`samples = 0`: its staged samples only feed the
/// filters, its restarts apply, θ̂ stays); a block closed while no buffer is free (the task
/// [`ESTIMATOR_DEPTH`] blocks behind) is lost with its samples (the caller counts it,
/// `blocks_dropped`), and its buffer stages the next.
pub struct QueueLink<'a, 'b> {
    /// The block being staged: the samples since the last header.
    stage: BlockBuf<'b>,
    /// Loop → estimator, full buffers.
    pub blocks: Producer<'a, BlockBuf<'b>>,
    /// Estimator → loop, free buffers.
    pub free: Consumer<'a, BlockBuf<'b>>,
    /// Estimator → loop, results.
    pub results: Consumer<'a, BlockResult>,
    /// Pends the estimator interrupt (the board's).
    pub pend: fn(),
    /// Where lost samples are counted.
    pub counters: &'a Counters,
    /// Samples that did not fit the staged buffer since the last header.
    lost: u32,
    /// The chunks of tones from the task.
    pub tones: ToneLink<'a, 'b>,
}

impl<'a, 'b> QueueLink<'a, 'b> {
    /// The link over the queues' loop ends, staging into `stage` (the other buffers wait in
    /// the free queue).
    pub fn new(
        stage: BlockBuf<'b>,
        blocks: Producer<'a, BlockBuf<'b>>,
        free: Consumer<'a, BlockBuf<'b>>,
        results: Consumer<'a, BlockResult>,
        pend: fn(),
        counters: &'a Counters,
        tones: ToneLink<'a, 'b>,
    ) -> Self {
        stage.n = 0;
        Self {
            stage,
            blocks,
            free,
            results,
            pend,
            counters,
            lost: 0,
            tones,
        }
    }
}

impl SampleSink<Number> for QueueLink<'_, '_> {
    #[inline(always)]
    fn push(&mut self, s: Sample) {
        let b = &mut *self.stage;
        let n = b.n;
        match b.samples.get_mut(n as usize) {
            Some(slot) => {
                *slot = s;
                b.n = n + 1;
            }
            None => {
                self.lost = self.lost.wrapping_add(1);
                bump(&self.counters.samples_dropped);
            }
        }
    }
}

impl ToneSource<Number> for QueueLink<'_, '_> {
    /// Once per chunk (`RESYNC` samples), at its first sample.
    #[inline(always)]
    fn take_tones(&mut self, key: &ChunkKey) -> bool {
        if self.tones.take(key) {
            return true;
        }
        bump(&self.counters.tones_late);
        false
    }
    #[inline(always)]
    fn tone(&self, left: u32) -> Number {
        self.tones.tone(left)
    }
}

impl EstimatorLink for QueueLink<'_, '_> {
    #[inline(always)]
    fn send(&mut self, b: Block) -> bool {
        let lost = core::mem::take(&mut self.lost);
        let Some(next) = self.free.dequeue() else {
            // No free buffer: the block is lost whole, its buffer stages the next.
            self.stage.n = 0;
            return false;
        };
        next.n = 0;
        let full = core::mem::replace(&mut self.stage, next);
        full.header = b;
        if lost != 0 {
            // Not all of the block's samples are staged: the staged ones only feed the
            // filters.
            full.header.skip = full.n;
            full.header.samples = 0;
        }
        // Cannot be full: the queue holds every buffer. Were it full, the buffer would be
        // dropped (out of circulation) and the block counted as lost.
        let ok = self.blocks.enqueue(full).is_ok();
        (self.pend)();
        ok
    }
    /// The header written straight into the buffer handed over (issue 14, round 19).
    #[inline(always)]
    fn send_with(&mut self, fill: impl FnOnce(&mut Block)) -> bool {
        let lost = core::mem::take(&mut self.lost);
        let Some(next) = self.free.dequeue() else {
            // No free buffer: the block is lost whole (its header taken all the same), its
            // buffer stages the next.
            let mut b = self.stage.header;
            fill(&mut b);
            self.stage.n = 0;
            return false;
        };
        next.n = 0;
        let full = core::mem::replace(&mut self.stage, next);
        fill(&mut full.header);
        if lost != 0 {
            // As in `send`.
            full.header.skip = full.n;
            full.header.samples = 0;
        }
        let ok = self.blocks.enqueue(full).is_ok();
        (self.pend)();
        ok
    }
    #[inline(always)]
    fn receive(&mut self) -> Option<BlockResult> {
        self.results.dequeue()
    }
    fn reset(&mut self) {
        self.stage.n = 0;
        self.lost = 0;
        // Chunks of the old core's tones: handed back.
        self.tones.reset();
    }
}

/// The estimator interrupt's state: the task and its ends of the queues.
pub struct EstimatorState {
    /// The estimators.
    pub task: EstimatorTask,
    /// Loop → estimator, full buffers.
    pub blocks: Consumer<'static, BlockBuf<'static>>,
    /// Estimator → loop, free buffers.
    pub free: Producer<'static, BlockBuf<'static>>,
    /// Estimator → loop, results.
    pub results: Producer<'static, BlockResult>,
    /// The chunks of tones computed ahead.
    pub tones: TonePrep<'static, 'static>,
}

impl EstimatorState {
    /// The estimator interrupt's body: [`run_blocks`].
    #[inline(always)]
    pub fn run(&mut self) {
        run_blocks(
            &mut self.task,
            &mut self.blocks,
            &mut self.free,
            &mut self.results,
            &mut self.tones,
        );
    }

    /// Hands every waiting buffer back unread (thread mode, both interrupts masked).
    pub fn clear(&mut self) {
        while let Some(b) = self.blocks.dequeue() {
            let _ = self.free.enqueue(b);
        }
        // A new core's chunks count from 1 again.
        self.tones.next = 1;
    }
}

/// Every waiting block, in order: its samples, in its buffer, through the task's filters (the
/// ones to discard first, then the block's, the estimating ones into the block sums:
/// `EstimatorTask::run_in_place`, which overwrites them), the block update, the result queued
/// back, the buffer handed back free; then the chunks of tones the block asks for
/// ([`TonePrep::run`]).
#[inline(always)]
pub fn run_blocks<'b>(
    task: &mut EstimatorTask,
    blocks: &mut Consumer<'_, BlockBuf<'b>>,
    free: &mut Producer<'_, BlockBuf<'b>>,
    results: &mut Producer<'_, BlockResult>,
    tones: &mut TonePrep<'_, '_>,
) {
    while let Some(b) = blocks.dequeue() {
        let header = b.header;
        let r = task.run_in_place(&header, b.staged());
        // Neither can be full: the free queue holds every buffer, and there are at most as
        // many results as blocks, the queues alike.
        let _ = free.enqueue(b);
        let _ = results.enqueue(r);
        tones.run(task, &header);
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

/// What the loop interrupt shares with the main loop: the command slot (main → loop) and the
/// counters (loop → main). Passed to [`LoopState::on_sample`] by the caller, not held by
/// reference: the firmware keeps it in the same static as the loop state (`app::LOOP`), so
/// that the loop addresses both from one base register (issue 14, round 18: through
/// references held in the state, the command byte and the sample counter each took a load of
/// their address first, every sample).
#[derive(Debug, Default)]
pub struct Shared {
    /// Main → loop commands.
    pub commands: CommandSlot,
    /// Shared counters.
    pub counters: Counters,
}

impl Shared {
    /// Empty, all zero.
    pub const fn new() -> Self {
        Self {
            commands: CommandSlot::new(),
            counters: Counters::new(),
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
    ) -> Self {
        Self {
            adc,
            u_out,
            xy_out,
            core,
            estimator,
            in_flight: 0,
            telemetry,
            per_sample: false,
            index_base: 0,
            // Out of any DAC's range: the first step always writes the lateral outputs.
            last_xy: (i32::MIN, i32::MIN),
        }
    }

    /// One loop sample, with the command slot and the counters shared with the main loop.
    /// Called from the loop interrupt only.
    #[inline(always)]
    pub fn on_sample(&mut self, shared: &Shared) {
        let counters = &shared.counters;
        let core = &mut self.core;
        if let Some(cmd) = shared.commands.take() {
            core.apply_command(cmd);
        }
        let Some(d) = self.adc.sample() else {
            bump(&counters.starved);
            return;
        };
        if !core.block_continues() {
            self.close_block(counters);
        }
        let out = self.core.step(d, &mut self.estimator);
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
            let index = self.index(counters);
            emit(
                &mut self.telemetry,
                counters,
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
            let index = self.index(counters);
            if let Some(r) = self.core.take_record(index) {
                emit(&mut self.telemetry, counters, Item::Record(r));
            }
        }
        bump(&counters.samples);
    }

    /// A block close: the last block's result adopted, the block handed over. Out of line
    /// (issue 14, round 19): once per block, and inlined it put a jump around itself and its
    /// registers' spills on every sample's path.
    #[cold]
    #[inline(never)]
    fn close_block(&mut self, counters: &Counters) {
        let core = &mut self.core;
        // `block_continues` was false: the clock's test is known.
        if !core.block_closes() {
            return;
        }
        if self.in_flight > 0 {
            // The schedule: the last block's result is adopted now, before this step.
            while let Some(r) = self.estimator.receive() {
                core.deliver(&r);
                self.in_flight -= 1;
            }
            // One still out is late (a steady lag of a block counts at every close).
            if self.in_flight > 0 {
                bump(&counters.estimator_late);
            }
        }
        // The block closes at the start of this sample: straight into the queue, its header
        // written in the buffer handed over.
        let n = core.block_samples();
        if n == 0 {
            return;
        }
        if self.estimator.send_with(|h| *h = core.header(n)) {
            self.in_flight += 1;
        } else {
            bump(&counters.blocks_dropped);
        }
    }

    /// The index of the sample being stepped (since the source was last set).
    #[inline(always)]
    pub fn index(&self, counters: &Counters) -> u32 {
        counters
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
    pub fn reset_index(&mut self, counters: &Counters) {
        self.index_base = counters.samples.load(Ordering::Relaxed);
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
    impl ToneSource<Number> for Inline {}
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

    /// A block with more samples than [`BLOCK_MAX`] and a block closed while the task holds
    /// every buffer lose whole blocks, deterministically, and are counted; the task's filters see
    /// exactly the samples of the blocks it was handed.
    #[test]
    fn full_queues_lose_whole_blocks_and_stay_in_step() {
        use visco_core::schedule::Target;
        static COUNTERS: Counters = Counters::new();
        fn leak<T, const N: usize>() -> &'static mut Queue<T, N> {
            std::boxed::Box::leak(std::boxed::Box::new(Queue::new()))
        }
        let (btx, mut brx) = leak::<BlockBuf<'static>, BUFFER_SLOTS>().split();
        let (mut ftx, frx) = leak::<BlockBuf<'static>, BUFFER_SLOTS>().split();
        let (mut rtx, rrx) = leak::<BlockResult, { ESTIMATOR_DEPTH + 1 }>().split();
        let bufs: &'static mut [SampleBlock; BLOCK_BUFFERS] =
            std::boxed::Box::leak(std::boxed::Box::new([SampleBlock::new(); BLOCK_BUFFERS]));
        let [stage, rest @ ..] = bufs;
        for b in rest {
            assert!(ftx.enqueue(b).is_ok());
        }
        let chunks: &'static mut [ToneChunk; TONE_CHUNKS] = std::boxed::Box::leak(
            std::boxed::Box::new([ToneChunk::new(<Number as visco_core::Real>::ZERO); TONE_CHUNKS]),
        );
        let (tone_link, mut prep) = tone_ends(
            chunks,
            leak::<ToneBuf<'static>, TONE_SLOTS>(),
            leak::<ToneBuf<'static>, TONE_SLOTS>(),
        );
        let mut link = QueueLink::new(stage, btx, frx, rrx, || {}, &COUNTERS, tone_link);
        let mut task = build_core(&StagedConfig::new(), None).unwrap().task;
        // What the task should have seen: the same task fed only the blocks handed over.
        let mut alone = task;
        let theta0 = task.theta(Target::Dive3);
        let header = |skip: u32, samples: u32| Block {
            restart: None,
            restart_watch: false,
            epoch: 0,
            target: Target::Dive3,
            skip,
            samples,
            tones: Default::default(),
        };
        let v = |x: f64| <Number as visco_core::Real>::from_f64(x);
        // Samples that differ, so that a sample fed twice, lost or out of order shows in θ̂.
        let x = |k: u32| Sample {
            z: v(5.0 + 0.01 * f64::from(k % 17)),
            u: v(1.0 + 0.02 * f64::from(k % 5)),
            r: v(2.0),
            flags: visco_core::schedule::SAMPLE_EST,
        };
        // 70 samples since the last header: 6 do not fit; the block (3 to discard after a
        // restart, 67 its own) is handed over without information, its 64 staged samples
        // through the filters only.
        for k in 0..70 {
            link.push(x(k));
        }
        assert_eq!(COUNTERS.samples_dropped.load(Ordering::Relaxed), 6);
        assert!(link.send(header(3, 67)));
        let b = brx.peek().unwrap();
        assert_eq!((b.header.skip, b.header.samples, b.n), (64, 0, 64));
        run_blocks(&mut task, &mut brx, &mut ftx, &mut rtx, &mut prep);
        let r = link.receive().unwrap();
        assert_eq!((r.flags, r.theta, r.updated), (0, theta0, false));
        alone.run(&header(64, 0), (0..64).map(x));
        // The task stalls: four blocks are handed over, the fifth finds no free buffer and is
        // lost with its samples.
        let mut k = 100;
        for j in 0..ESTIMATOR_DEPTH + 1 {
            for _ in 0..32 {
                link.push(x(k));
                k += 1;
            }
            assert_eq!(link.send(header(0, 32)), j < ESTIMATOR_DEPTH);
            if j < ESTIMATOR_DEPTH {
                alone.run(&header(0, 32), (k - 32..k).map(x));
            }
        }
        run_blocks(&mut task, &mut brx, &mut ftx, &mut rtx, &mut prep);
        for _ in 0..ESTIMATOR_DEPTH {
            assert!(link.receive().unwrap().updated);
        }
        assert!(link.receive().is_none());
        // The next block goes through, its samples alone (none of the lost block's).
        for _ in 0..32 {
            link.push(x(k));
            k += 1;
        }
        assert!(link.send(header(0, 32)));
        run_blocks(&mut task, &mut brx, &mut ftx, &mut rtx, &mut prep);
        let want = alone.run(&header(0, 32), (k - 32..k).map(x));
        let got = link.receive().unwrap();
        assert!(got.updated);
        assert_ne!(got.theta, theta0);
        assert_eq!((got.theta, got.flags), (want.theta, want.flags));
        assert!(brx.peek().is_none());
    }

    /// A loop state on a free cantilever (D = 0 for `n` samples) with the default core, its
    /// estimator task behind the link `link` makes of it, and the telemetry's consumer.
    #[allow(clippy::type_complexity)]
    fn free_lever<E: EstimatorLink>(
        n: usize,
        link: impl FnOnce(EstimatorTask) -> E,
    ) -> (
        LoopState<Fed, Words, Xy, crate::core_glue::ActiveCore, E>,
        heapless::spsc::Consumer<'static, Item>,
    ) {
        let tel: &'static mut Queue<Item, { TELEMETRY_DEPTH + 1 }> =
            std::boxed::Box::leak(std::boxed::Box::new(Queue::new()));
        let (tp, tc) = tel.split();
        let built = build_core(&StagedConfig::new(), None).unwrap();
        let st = LoopState::new(
            Fed(std::vec![Number::from_metres(0.0); n]),
            Words::default(),
            Xy::default(),
            built.core,
            link(built.task),
            tp,
        );
        (st, tc)
    }

    #[test]
    fn steps_counts_and_reports_drops() {
        static SHARED: Shared = Shared::new();
        let (cmd, counters) = (&SHARED.commands, &SHARED.counters);
        // Free cantilever: D = 0; the core moves to the first tap, then approaches.
        let n = 3000;
        let (mut st, mut tc) = free_lever(n, |task| Inline(task, None, Default::default()));
        st.per_sample = true;
        cmd.post(CoreCommand::Stop);
        cmd.post(CoreCommand::Start(Mode::Dive)); // the latest intent wins
        for _ in 0..n + 1 {
            st.on_sample(&SHARED);
        }
        assert_eq!(counters.samples.load(Ordering::Relaxed), n as u32);
        assert_eq!(st.index(counters), n as u32);
        st.reset_index(counters);
        assert_eq!(st.index(counters), 0);
        assert_eq!(counters.starved.load(Ordering::Relaxed), 1);
        // One Step item per sample, 64 fit: the rest is dropped and counted.
        assert_eq!(
            counters.telemetry_dropped.load(Ordering::Relaxed),
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
        // The task ran at once: no block close found a result still out.
        assert_eq!(counters.estimator_late.load(Ordering::Relaxed), 0);
    }

    /// The task a block late (each result released by the next hand-over): every close but
    /// the first finds a result still out, and counts it; the blocks are not lost.
    #[test]
    fn a_late_estimator_is_counted_at_every_close() {
        static SHARED: Shared = Shared::new();
        let (cmd, counters) = (&SHARED.commands, &SHARED.counters);
        struct Lagging {
            inner: Inline,
            held: Option<BlockResult>,
            out: Option<BlockResult>,
            sent: u32,
        }
        impl ToneSource<Number> for Lagging {}
        impl SampleSink<Number> for Lagging {
            fn push(&mut self, s: Sample) {
                self.inner.push(s);
            }
        }
        impl EstimatorLink for Lagging {
            fn send(&mut self, b: Block) -> bool {
                self.sent += 1;
                self.out = self.held.take();
                let ok = self.inner.send(b);
                self.held = self.inner.receive();
                ok
            }
            fn receive(&mut self) -> Option<BlockResult> {
                self.out.take()
            }
        }
        let n = 3000;
        let (mut st, _tc) = free_lever(n, |task| Lagging {
            inner: Inline(task, None, Default::default()),
            held: None,
            out: None,
            sent: 0,
        });
        cmd.post(CoreCommand::Start(Mode::Dive));
        for _ in 0..n {
            st.on_sample(&SHARED);
        }
        let sent = st.estimator.sent;
        assert!(sent > 50, "{sent} blocks");
        assert_eq!(counters.estimator_late.load(Ordering::Relaxed), sent - 1);
        assert_eq!(counters.blocks_dropped.load(Ordering::Relaxed), 0);
    }
}
