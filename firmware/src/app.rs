//! Board-independent firmware: the loop interrupt's state, the main loop that talks to the
//! host, and the panic handler.
//!
//! Ownership: the loop state (`LOOP`) belongs to the loop interrupt, the estimator task
//! (`ESTIMATOR`) to the lower-priority estimator interrupt. The main loop touches them only
//! through [`with_loop`] / [`with_both`], which mask the interrupts for the duration (a few
//! hundred cycles, only on configuration commands, never per sample). Data moves through
//! lock-free `heapless::spsc` queues: telemetry loop → main, the blocks of a running mode (header
//! and samples, in buffers passed by reference and handed back) loop → estimator, results estimator → loop, and on QEMU replay samples main → loop; core commands main → loop are a
//! command byte.

use crate::board;
use core::cell::UnsafeCell;
use core::sync::atomic::Ordering;
use heapless::spsc::{Consumer, Queue};
use visco_firmware::core_glue::BlockResult;
use visco_firmware::core_glue::{self, CoreCommand, LoopCore, StagedConfig};
use visco_firmware::loop_body::{
    tone_ends, BlockBuf, CommandSlot, Counters, EstimatorState, Item, QueueLink, SampleBlock,
    Shared, ToneBuf, BLOCK_BUFFERS, BUFFER_SLOTS, ESTIMATOR_DEPTH, TELEMETRY_DEPTH, TONE_CHUNKS,
    TONE_SLOTS,
};
use visco_protocol::{
    ack, frame, param, Command, ConfigRejectedFrame, FrameDecoder, PerSample, SeqTracker,
    StatusFrame, StepBlockFrame, StepDigest, StepFrame, Telemetry, MAX_FEED, MAX_WIRE,
    PROTOCOL_VERSION,
};

/// The loop state, owned by the loop interrupt (see the module comment).
pub struct IsrCell<T>(UnsafeCell<Option<T>>);

// SAFETY: each cell is accessed only by its interrupt (the loop's, the estimator's), or by
// thread mode while that interrupt is masked (`with_loop`, `with_both`), so never from two
// contexts at once.
unsafe impl<T: Send> Sync for IsrCell<T> {}

impl<T> IsrCell<T> {
    const fn new() -> Self {
        Self(UnsafeCell::new(None))
    }
    /// # Safety
    /// Only from the cell's interrupt, or with that interrupt masked.
    // A `&mut` from `&self` is the point: exclusivity comes from the interrupt masking
    // contract above, which the type system cannot see.
    #[allow(clippy::mut_from_ref)]
    #[inline(always)]
    pub unsafe fn get(&self) -> Option<&mut T> {
        // SAFETY: exclusive access per the caller's contract.
        unsafe { (*self.0.get()).as_mut() }
    }
    /// [`Self::get`] from the cell's interrupt, which runs only once the cell is set: no test
    /// of the `Option` (the loop interrupt paid three instructions per sample for it).
    ///
    /// # Safety
    /// Only from the cell's interrupt, and only once [`Self::set`] has run: every board
    /// unmasks the interrupt (`board::unmask_loop`, `board::unmask_estimator`) only after
    /// `app::run` has set its cell, the cells are never emptied, and until the first unmask
    /// the NVIC holds the interrupt (disabled from reset; a pend while masked waits).
    #[allow(clippy::mut_from_ref)]
    #[inline(always)]
    pub unsafe fn get_set(&self) -> &mut T {
        // SAFETY: exclusive access and a set cell, per the caller's contract.
        unsafe { (*self.0.get()).as_mut().unwrap_unchecked() }
    }
    /// # Safety
    /// Only with the cell's interrupt masked.
    unsafe fn set(&self, v: T) {
        // SAFETY: exclusive access per the caller's contract.
        unsafe { *self.0.get() = Some(v) };
    }
}

/// The loop state and what it shares with the main loop, in one static: the loop interrupt
/// addresses the command slot and the counters from the state's own base register (issue 14,
/// round 18: one load of an address less for each, every sample). The state and the shared
/// part are disjoint fields, so the main loop's atomic accesses to the shared part never
/// touch the state the interrupt holds mutably.
#[repr(C)]
pub struct LoopCell {
    /// The loop state, owned by the loop interrupt.
    pub state: IsrCell<board::Loop>,
    /// The command slot and the counters.
    pub shared: Shared,
}

pub static LOOP: LoopCell = LoopCell {
    state: IsrCell::new(),
    shared: Shared::new(),
};
/// The estimator task, owned by the estimator interrupt.
pub static ESTIMATOR: IsrCell<EstimatorState> = IsrCell::new();
static COMMANDS: &CommandSlot = &LOOP.shared.commands;
pub static COUNTERS: &Counters = &LOOP.shared.counters;

/// The loop interrupt body: every board's loop interrupt handler calls this after
/// acknowledging its interrupt source.
#[inline(always)]
pub fn loop_interrupt() {
    #[cfg(feature = "panic-canary")]
    if COUNTERS.samples.load(Ordering::Relaxed) == 0xDEAD_BEEF {
        panic!("canary");
    }
    // SAFETY: called from the loop interrupt only, which runs once `run` has set `LOOP`.
    unsafe { LOOP.state.get_set() }.on_sample(&LOOP.shared);
}

/// The estimator interrupt body (lower priority than the loop's): the blocks the loop
/// handed over, one block update each.
#[inline(always)]
pub fn estimator_interrupt() {
    // SAFETY: called from the estimator interrupt only, which runs once `run` has set
    // `ESTIMATOR`.
    unsafe { ESTIMATOR.get_set() }.run();
}

/// Runs `f` on the loop state and the estimator task with both interrupts masked.
fn with_both<R>(f: impl FnOnce(&mut board::Loop, &mut EstimatorState) -> R) -> Option<R> {
    board::mask_loop();
    board::mask_estimator();
    // SAFETY: both interrupts are masked, and thread mode cannot preempt them.
    let r = match unsafe { (LOOP.state.get(), ESTIMATOR.get()) } {
        (Some(l), Some(e)) => Some(f(l, e)),
        _ => None,
    };
    board::unmask_estimator();
    board::unmask_loop();
    r
}

/// Runs `f` on the loop state with the loop interrupt masked.
pub fn with_loop<R>(f: impl FnOnce(&mut board::Loop) -> R) -> Option<R> {
    board::mask_loop();
    // SAFETY: the loop interrupt is masked, and thread mode cannot preempt it.
    let r = unsafe { LOOP.state.get() }.map(f);
    board::unmask_loop();
    r
}

/// The byte link to the host (UART).
pub trait Link {
    /// A received byte, if one is waiting.
    fn try_read(&mut self) -> Option<u8>;
    /// Sends bytes (blocks the main loop, never the loop interrupt).
    fn write_all(&mut self, bytes: &[u8]);
}

/// The host link's transmit side. Frame sequence numbers are taken here, in send order, so
/// they are strictly increasing on the wire; telemetry the loop could not queue is added to
/// the sequence as a gap of the same size, so the host counts it as lost.
pub struct Tx<L: Link> {
    pub link: L,
    buf: [u8; MAX_WIRE],
    seq: u32,
    dropped_seen: u32,
    /// Per-sample outputs as compact blocks.
    pub blocks: bool,
    block: StepBlockFrame,
    digest: StepDigest,
}

impl<L: Link> Tx<L> {
    fn new(link: L) -> Self {
        Self {
            link,
            buf: [0; MAX_WIRE],
            seq: 0,
            dropped_seen: 0,
            blocks: false,
            block: StepBlockFrame::default(),
            digest: StepDigest::new(),
        }
    }

    pub fn send(&mut self, t: &Telemetry) {
        let dropped = COUNTERS.telemetry_dropped.load(Ordering::Relaxed);
        self.seq = self
            .seq
            .wrapping_add(dropped.wrapping_sub(self.dropped_seen));
        self.dropped_seen = dropped;
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        match frame::encode(seq, t, &mut self.buf) {
            Ok(n) => self.link.write_all(self.buf.get(..n).unwrap_or(&[])),
            // Cannot happen for the fixed-size messages; the gap it leaves reports it.
            Err(_) => defmt::error!("telemetry frame too long"),
        }
    }

    /// Sends everything the loop queued.
    fn drain(&mut self, rx: &mut Consumer<'static, Item>) {
        while let Some(item) = rx.dequeue() {
            match item {
                Item::Step(s) if self.blocks => self.add_to_block(&s),
                Item::Step(s) => self.send(&Telemetry::Step(s)),
                Item::Record(r) => self.send(&Telemetry::Record(r)),
            }
        }
    }

    fn add_to_block(&mut self, s: &StepFrame) {
        let len = self.block.len as u32;
        if len > 0 && s.index != self.block.first_index.wrapping_add(len) {
            self.flush_block(); // a dropped sample: start a new block
        }
        if self.block.len == 0 {
            self.block.first_index = s.index;
            self.digest = StepDigest::new();
        }
        let i = self.block.len as usize;
        if let (Some(c), Some(st)) = (self.block.u_codes.get_mut(i), self.block.status.get_mut(i)) {
            *c = s.u_code.clamp(-32768, 32767) as i16;
            *st = s.status as u16;
            self.digest.add(s);
            self.block.len += 1;
        }
        if self.block.len as usize >= MAX_FEED {
            self.flush_block();
        }
    }

    /// Sends the partial block, if any.
    fn flush_block(&mut self) {
        if self.block.len > 0 {
            self.block.digest = self.digest.finish();
            let b = self.block;
            self.send(&Telemetry::StepBlock(b));
            self.block.len = 0;
        }
    }
}

/// Board-level configuration staged by `SetParam`: the ADC's metres per code (`None`:
/// derived from the core's full scale).
struct BoardScales {
    adc: Option<f64>,
}

pub fn run() -> ! {
    let mut b = board::init();
    defmt::info!(
        "visco firmware: board {=str}, core {=u8}, protocol {=u16}",
        board::NAME,
        core_glue::CORE_ID,
        PROTOCOL_VERSION
    );
    // heapless's queue of N slots holds N − 1 items.
    let Some(tel) = cortex_m::singleton!(: Queue<Item, { TELEMETRY_DEPTH + 1 }> = Queue::new())
    else {
        board::fatal(4)
    };
    let (tel_tx, mut tel_rx) = tel.split();
    let mut scales = BoardScales { adc: None };
    let mut staged = StagedConfig::new();
    // The default configuration (`Config::paper` at 1 MHz), so that the loop can run at once.
    let (core, task, adc) = match core_glue::build_core(&staged, scales.adc) {
        Ok(b) => (b.core, b.task, b.adc),
        Err(_) => board::fatal(5),
    };
    // The estimator's queues: block buffers loop → estimator full and back free, results
    // back. The buffers circulate by reference; one stages, the others start free.
    let (Some(bufs), Some(blocks), Some(free), Some(results)) = (
        cortex_m::singleton!(: [SampleBlock; BLOCK_BUFFERS] = [SampleBlock::new(); BLOCK_BUFFERS]),
        cortex_m::singleton!(: Queue<BlockBuf<'static>, BUFFER_SLOTS> = Queue::new()),
        cortex_m::singleton!(: Queue<BlockBuf<'static>, BUFFER_SLOTS> = Queue::new()),
        cortex_m::singleton!(: Queue<BlockResult, { ESTIMATOR_DEPTH + 1 }> = Queue::new()),
    ) else {
        board::fatal(11)
    };
    let (block_tx, block_rx) = blocks.split();
    let (mut free_tx, free_rx) = free.split();
    let (result_tx, result_rx) = results.split();
    let [stage, rest @ ..] = bufs;
    for b in rest {
        let _ = free_tx.enqueue(b);
    }
    // The chunks of tones: computed ahead by the task, read by the loop (one it holds, the
    // others start free).
    let (Some(chunks), Some(ready), Some(tfree)) = (
        cortex_m::singleton!(: [core_glue::ToneChunk; TONE_CHUNKS] =
            [core_glue::ToneChunk::new(<core_glue::Number as visco_core::Real>::ZERO); TONE_CHUNKS]),
        cortex_m::singleton!(: Queue<ToneBuf<'static>, TONE_SLOTS> = Queue::new()),
        cortex_m::singleton!(: Queue<ToneBuf<'static>, TONE_SLOTS> = Queue::new()),
    ) else {
        board::fatal(11)
    };
    let (tone_link, tone_prep) = tone_ends(chunks, ready, tfree);
    let link = QueueLink::new(
        stage,
        block_tx,
        free_rx,
        result_rx,
        board::pend_estimator,
        COUNTERS,
        tone_link,
    );
    let state = board::make_loop(&mut b, adc, core, link, tel_tx);
    board::mask_estimator();
    // SAFETY: the estimator interrupt is masked.
    unsafe {
        ESTIMATOR.set(EstimatorState {
            task,
            blocks: block_rx,
            free: free_tx,
            results: result_tx,
            tones: tone_prep,
        })
    };
    board::unmask_estimator();
    board::mask_loop();
    // SAFETY: the loop interrupt is masked.
    unsafe { LOOP.state.set(state) };
    board::unmask_loop();

    let mut tx = Tx::new(board::take_link(&mut b));
    tx.send(&Telemetry::Hello {
        protocol: PROTOCOL_VERSION,
        board: board::BOARD_ID,
        core: core_glue::CORE_ID,
    });

    let mut rx = FrameDecoder::new();
    let mut rx_seq = SeqTracker::starting_at(0);
    let mut rx_bad: u32 = 0;
    let mut status_every: u32 = 0;
    let mut next_status: u32 = 0;
    loop {
        tx.drain(&mut tel_rx);
        if !board::samples_pending(&b) {
            // The sample stream paused (end of a replay, or a slow host): send what we have.
            tx.flush_block();
        }
        board::poll(&mut b, TELEMETRY_DEPTH - tel_rx.len());

        if status_every != 0 {
            let samples = COUNTERS.samples.load(Ordering::Relaxed);
            if samples.wrapping_sub(next_status) as i32 >= 0 {
                next_status = samples.wrapping_add(status_every);
                let s = status(rx_bad, &rx_seq);
                tx.send(&Telemetry::Status(s));
            }
        }

        // Host bytes, as long as a whole replay block would still fit.
        let mut received = false;
        while board::can_accept_command(&b) {
            let Some(byte) = tx.link.try_read() else {
                break;
            };
            received = true;
            let Some(res) = rx.push::<Command>(byte) else {
                continue;
            };
            let (seq, cmd) = match res {
                Ok(x) => x,
                Err(_) => {
                    rx_bad = rx_bad.wrapping_add(1);
                    continue;
                }
            };
            rx_seq.observe(seq);
            // Whatever the loop queued before this command goes out first, so the host sees
            // telemetry and acks in the order they happened.
            if !matches!(cmd, Command::Feed(_)) {
                tx.drain(&mut tel_rx);
                tx.flush_block();
            }
            let code = match cmd {
                Command::Ping { .. } => ack::OK,
                Command::SetParam { id, value } => set_param(&mut scales, &mut staged, id, value),
                Command::ApplyConfig => match apply_config(&scales, &staged) {
                    Ok(()) => ack::OK,
                    Err(Some(e)) => {
                        tx.send(&Telemetry::ConfigRejected(ConfigRejectedFrame::new(
                            e.field, e.value, e.reason,
                        )));
                        ack::INVALID
                    }
                    Err(None) => ack::BUSY,
                },
                Command::Start(mode) => push_cmd(CoreCommand::Start(mode)),
                Command::Stop => push_cmd(CoreCommand::Stop),
                Command::SetSource(src) => board::set_source(&mut b, src),
                Command::Feed(block) => {
                    let code = board::feed(&mut b, &block);
                    if code == ack::OK {
                        // Replay blocks are not acknowledged one by one: the Step frames are
                        // the answer, and an ack per block would cost link bandwidth.
                        continue;
                    }
                    code
                }
                Command::SetTelemetry {
                    per_sample,
                    status_every: every,
                } => {
                    status_every = every;
                    next_status = COUNTERS.samples.load(Ordering::Relaxed);
                    tx.blocks = per_sample == PerSample::Blocks;
                    with_loop(|l| l.per_sample = per_sample != PerSample::Off);
                    ack::OK
                }
                Command::RequestStatus => {
                    let s = status(rx_bad, &rx_seq);
                    tx.send(&Telemetry::Status(s));
                    ack::OK
                }
                Command::Bench {
                    mode,
                    steps,
                    period_ticks,
                } => match board::bench(&mut b, mode, steps, period_ticks) {
                    Some(frame) => {
                        tx.drain(&mut tel_rx);
                        tx.send(&Telemetry::Bench(frame));
                        ack::OK
                    }
                    None => ack::UNSUPPORTED,
                },
                Command::Calibrate { iterations } => match board::calibrate(iterations) {
                    Some(frame) => {
                        tx.send(&Telemetry::Calibration(frame));
                        ack::OK
                    }
                    None => ack::UNSUPPORTED,
                },
                Command::Exit { code } => {
                    tx.drain(&mut tel_rx);
                    let s = status(rx_bad, &rx_seq);
                    tx.send(&Telemetry::Status(s));
                    tx.send(&Telemetry::Ack {
                        cmd_seq: seq,
                        code: ack::OK,
                    });
                    defmt::info!("exit {=u8} after {=u32} samples", code, s.samples);
                    board::exit(code)
                }
            };
            tx.send(&Telemetry::Ack { cmd_seq: seq, code });
        }
        if !received && tel_rx.is_empty() {
            // Nothing to do until an interrupt: a host byte, a loop sample, a timer. Under
            // QEMU this also leaves the emulator's I/O thread alone instead of polling the
            // UART, which is what makes the link fast.
            board::idle(&b);
        }
    }
}

fn push_cmd(c: CoreCommand) -> u8 {
    COMMANDS.post(c);
    ack::OK
}

fn set_param(scales: &mut BoardScales, staged: &mut StagedConfig, id: u16, value: f64) -> u8 {
    if id == param::ADC_METRES_PER_CODE {
        return if value.is_finite() && value != 0.0 {
            scales.adc = Some(value);
            ack::OK
        } else {
            ack::INVALID
        };
    }
    if staged.stage(id, value) {
        ack::OK
    } else {
        ack::INVALID
    }
}

/// Builds the core from the staged configuration and swaps it in. `Err(None)`: the core is
/// running (stop it first); `Err(Some(_))`: the configuration was refused, with the field.
fn apply_config(
    scales: &BoardScales,
    staged: &StagedConfig,
) -> Result<(), Option<core_glue::ConfigError>> {
    // A Start/Stop the loop has not taken yet (no samples are coming) takes effect now.
    let running = with_loop(|l| {
        if let Some(cmd) = COMMANDS.take() {
            l.core.apply_command(cmd);
        }
        l.core.running_mode().is_some()
    });
    if running != Some(false) {
        return Err(None);
    }
    // Built here, in thread mode; the loop only receives the finished core.
    match core_glue::build_core(staged, scales.adc) {
        Ok(b) => {
            let (core, task, adc) = (b.core, b.task, b.adc);
            with_both(move |l, e| {
                // Samples, blocks and results of the old core are dropped with it.
                e.clear();
                e.task = task;
                l.replace_core(core);
                board::set_scales(l, adc);
            });
            Ok(())
        }
        Err(e) => {
            defmt::warn!("configuration refused: {=str}", e.field);
            Err(Some(e))
        }
    }
}

fn status(rx_bad: u32, rx_seq: &SeqTracker) -> StatusFrame {
    let (state, estimates) = with_loop(|l| {
        (
            match l.core.running_mode() {
                None => 0,
                Some(core_glue::Mode::Dive) => 1,
                Some(core_glue::Mode::Sve) => 2,
            },
            l.core.estimate_array(),
        )
    })
    .unwrap_or((0, [0.0; 3]));
    StatusFrame {
        samples: COUNTERS.samples.load(Ordering::Relaxed),
        starved: COUNTERS.starved.load(Ordering::Relaxed),
        telemetry_dropped: COUNTERS.telemetry_dropped.load(Ordering::Relaxed),
        rx_bad_frames: rx_bad,
        rx_lost_frames: rx_seq.lost().min(u32::MAX as u64) as u32,
        state,
        estimates,
        estimator_late: COUNTERS.estimator_late.load(Ordering::Relaxed),
        blocks_dropped: COUNTERS.blocks_dropped.load(Ordering::Relaxed),
        samples_dropped: COUNTERS.samples_dropped.load(Ordering::Relaxed),
        tones_late: COUNTERS.tones_late.load(Ordering::Relaxed),
    }
}

#[cfg(not(feature = "panic-never"))]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic");
    board::fatal(3)
}

/// With `panic-never`, any panic path that survives optimisation references this undefined
/// symbol and the link fails, naming it: the proof that the image cannot panic.
#[cfg(feature = "panic-never")]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    unsafe extern "Rust" {
        fn visco_firmware_has_a_reachable_panic_path() -> !;
    }
    // SAFETY: never executed; the symbol does not exist, so a reachable call fails the link.
    unsafe { visco_firmware_has_a_reachable_panic_path() }
}
