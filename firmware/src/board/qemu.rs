//! The QEMU board: `qemu-system-arm -machine mps2-an500` (Cortex-M7 at a nominal 25 MHz).
//!
//! - Loop interrupt: CMSDK APB TIMER0 (IRQ 8), clocked by the 25 MHz system clock; in replay
//!   ("feed") mode the timer is off and the main loop pends IRQ 8 once per fed sample, so
//!   the very same handler steps exactly once per sample.
//! - ADC: the AD4000 driver over a virtual SPI bus whose "conversion result" is a replay
//!   sample sent by the host (or, in timer mode, a synthetic triangle wave).
//! - DACs: the AD5541 driver over virtual SPI buses (U, X, Y); the U word is reported back
//!   to the host in the Step frames.
//! - Host link: CMSDK UART0 (QEMU `-serial`), polled from the main loop. QEMU moves UART
//!   bytes as fast as the emulation runs (no baud-rate pacing).
//! - Log: defmt over semihosting (QEMU's stdout with `-semihosting-config target=native`).
//! - Measurement: SysTick on the core clock (QEMU: the 25 MHz system clock), read around
//!   many loop interrupts; see `bench` and `calibrate`.

use crate::app::{self, Link};
use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::Ordering;
use cortex_m::peripheral::{syst::SystClkSource, NVIC};
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{ErrorType as PinErrorType, OutputPin};
use embedded_hal::spi::{ErrorType as SpiErrorType, SpiBus};
use heapless::spsc::{Consumer, Producer, Queue};
use visco_firmware::core_glue::{
    ActiveCore, BlockResult, CoreCommand, LoopCore, LoopReal, Mode, Number, Sample,
};
use visco_firmware::drivers::ad4000::{self, part, Ad4000, CFG_TURBO};
use visco_firmware::drivers::ad5541::Ad5541;
use visco_firmware::loop_body::{
    self, BlockBuf, Counters, EstimatorLink, Item, LoopState, QueueLink, SampleBlock, ToneBuf,
    ToneLink,
};
use visco_firmware::scale::Scale;
use visco_firmware::spi_device::CsDevice;
use visco_protocol::{
    ack, board, BenchFrame, BenchMode, CalibrationFrame, FeedBlock, FeedSamples, Source, MAX_FEED,
};

#[path = "semihosting_log.rs"]
mod semihosting_log;

pub const NAME: &str = "qemu-mps2-an500";
pub const BOARD_ID: u8 = board::QEMU_MPS2_AN500;

// CMSDK APB peripherals of the AN385/AN386/AN500 map.
const TIMER0_BASE: usize = 0x4000_0000;
const TIMER1_BASE: usize = 0x4000_1000;
const UART0: usize = 0x4000_4000;
const TIMER_CTRL: usize = 0x00;
const TIMER_VALUE: usize = 0x04;
const TIMER_RELOAD: usize = 0x08;
const TIMER_INTCLEAR: usize = 0x0C;
const TIMER_CTRL_EN: u32 = 1 << 0;
const TIMER_CTRL_IRQEN: u32 = 1 << 3;
const UART_DATA: usize = 0x00;
const UART_STATE: usize = 0x04;
const UART_CTRL: usize = 0x08;
const UART_BAUDDIV: usize = 0x10;
const UART_INTCLEAR: usize = 0x0C;
const UART_STATE_TXFULL: u32 = 1 << 0;
const UART_STATE_RXFULL: u32 = 1 << 1;
const UART_CTRL_TX_EN: u32 = 1 << 0;
const UART_CTRL_RX_EN: u32 = 1 << 1;
const UART_CTRL_RX_INT_EN: u32 = 1 << 3;
const UART_INT_RX: u32 = 1 << 1;
/// SysTick current value register.
const SYST_CVR: usize = 0xE000_E018;

#[inline(always)]
fn reg(base: usize, off: usize) -> *mut u32 {
    (base + off) as *mut u32
}

/// The loop interrupt's IRQ number.
#[derive(Clone, Copy)]
struct LoopIrq;
// SAFETY: 8 is TIMER0's IRQ on mps2-an500 and below the 32 IRQs QEMU's model has.
unsafe impl cortex_m::interrupt::InterruptNumber for LoopIrq {
    fn number(self) -> u16 {
        8
    }
}

/// The estimator interrupt's IRQ number: 10, a timer of the board's FPGA that this image
/// leaves off, pended by software only.
#[derive(Clone, Copy)]
struct EstimatorIrq;
// SAFETY: 10 is below the 32 IRQs QEMU's model has; nothing else raises it here.
unsafe impl cortex_m::interrupt::InterruptNumber for EstimatorIrq {
    fn number(self) -> u16 {
        10
    }
}

// ---- Vector table (cortex-m-rt `device` feature): 32 external interrupts. ----

#[repr(C)]
pub union Vector {
    handler: unsafe extern "C" fn(),
    reserved: usize,
}

unsafe extern "C" {
    fn UART0_TX();
    fn TIMER1();
}

#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [Vector; 32] = {
    const R: Vector = Vector { reserved: 0 };
    let mut v = [R; 32];
    v[0] = Vector { handler: UART0_RX };
    v[1] = Vector { handler: UART0_TX };
    v[8] = Vector { handler: TIMER0 };
    v[9] = Vector { handler: TIMER1 };
    v[10] = Vector { handler: ESTIMATOR };
    v
};

/// The estimator interrupt (below the loop's priority): the block updates.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ESTIMATOR() {
    app::estimator_interrupt();
}

/// Pends the estimator interrupt (from the loop interrupt, when it hands over a block).
#[inline(always)]
pub fn pend_estimator() {
    NVIC::pend(EstimatorIrq);
}

pub fn mask_estimator() {
    NVIC::mask(EstimatorIrq);
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

pub fn unmask_estimator() {
    // SAFETY: the estimator state is initialised before the first unmask (app::run), and
    // the interrupt only runs it.
    unsafe { NVIC::unmask(EstimatorIrq) };
}

/// UART0 receive interrupt: only wakes the main loop from `wfi` (it reads the byte).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn UART0_RX() {
    // SAFETY: UART0 interrupt-clear register.
    unsafe { write_volatile(reg(UART0, UART_INTCLEAR), UART_INT_RX) };
}

/// The UART's IRQ number.
#[derive(Clone, Copy)]
struct UartIrq;
// SAFETY: 0 is UART0 RX on mps2-an500.
unsafe impl cortex_m::interrupt::InterruptNumber for UartIrq {
    fn number(self) -> u16 {
        0
    }
}

/// The loop interrupt: acknowledge the timer, then one sample.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn TIMER0() {
    // SAFETY: TIMER0's interrupt-clear register; writing 1 clears a timer interrupt and is
    // harmless when the interrupt was pended by software (replay).
    unsafe { write_volatile(reg(TIMER0_BASE, TIMER_INTCLEAR), 1) };
    app::loop_interrupt();
}

// ---- Virtual SPI converters. ----

/// An SPI bus whose MISO shifts out the virtual ADC's conversion result (left-aligned in
/// 32 bits), MSB first, once per transfer call: the ADC's output shift register.
pub struct VirtualAdcBus {
    conversion: u32,
}
impl SpiErrorType for VirtualAdcBus {
    type Error = Infallible;
}
impl VirtualAdcBus {
    #[inline(always)]
    fn shift_out(&self, words: &mut [u8]) {
        let mut v = self.conversion;
        for w in words {
            *w = (v >> 24) as u8;
            v <<= 8;
        }
    }
}
impl SpiBus<u8> for VirtualAdcBus {
    fn read(&mut self, words: &mut [u8]) -> Result<(), Infallible> {
        self.shift_out(words);
        Ok(())
    }
    fn write(&mut self, _: &[u8]) -> Result<(), Infallible> {
        Ok(())
    }
    #[inline(always)]
    fn transfer(&mut self, read: &mut [u8], _: &[u8]) -> Result<(), Infallible> {
        self.shift_out(read);
        Ok(())
    }
    fn transfer_in_place(&mut self, words: &mut [u8]) -> Result<(), Infallible> {
        self.shift_out(words);
        Ok(())
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// An SPI bus that accepts writes (the DACs' outputs are reported through telemetry).
pub struct VirtualDacBus;
impl SpiErrorType for VirtualDacBus {
    type Error = Infallible;
}
impl SpiBus<u8> for VirtualDacBus {
    fn read(&mut self, words: &mut [u8]) -> Result<(), Infallible> {
        words.fill(0);
        Ok(())
    }
    #[inline(always)]
    fn write(&mut self, _: &[u8]) -> Result<(), Infallible> {
        Ok(())
    }
    fn transfer(&mut self, read: &mut [u8], _: &[u8]) -> Result<(), Infallible> {
        read.fill(0);
        Ok(())
    }
    fn transfer_in_place(&mut self, _: &mut [u8]) -> Result<(), Infallible> {
        Ok(())
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// A chip-select line that goes nowhere.
pub struct VirtualPin;
impl PinErrorType for VirtualPin {
    type Error = Infallible;
}
impl OutputPin for VirtualPin {
    #[inline(always)]
    fn set_low(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
    #[inline(always)]
    fn set_high(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// Delays are meaningless for the virtual converters.
pub struct NoWait;
impl DelayNs for NoWait {
    #[inline(always)]
    fn delay_ns(&mut self, _: u32) {}
}

type AdcDev = CsDevice<VirtualAdcBus, VirtualPin, NoWait>;
type DacDev = CsDevice<VirtualDacBus, VirtualPin, NoWait>;

/// One replay sample.
#[derive(Clone, Copy, Debug)]
pub enum FeedSample {
    /// An ADC code (signed, relative to mid-scale).
    Code(i16),
    /// Deflection in metres, bypassing the ADC.
    Metres(f32),
}

const FEED_DEPTH: usize = 256;

/// Where the virtual ADC's conversions come from.
#[derive(Clone, Copy, PartialEq, Eq)]
enum AdcSource {
    Synthetic,
    Feed,
    /// The bench table, one code per sample, then starved.
    Table,
}

/// Codes of the bench table (a realistic input for [`BenchMode::Continue`]): 32 KiB.
pub const TABLE_LEN: usize = 16384;

pub struct QemuAdc {
    dev: Ad4000<AdcDev, part::Ad4000>,
    scale: Scale,
    source: AdcSource,
    phase: u32,
    feed: Consumer<'static, FeedSample>,
    table: &'static mut [i16; TABLE_LEN],
    /// Codes loaded into the table.
    table_len: usize,
    /// Next code read from the table.
    table_pos: usize,
}

impl loop_body::Adc for QemuAdc {
    #[inline(always)]
    fn sample(&mut self) -> Option<Number> {
        let code = match self.source {
            AdcSource::Synthetic => {
                // A triangle-ish wave of ±8192 codes: deterministic and cheap.
                self.phase = self.phase.wrapping_add(7);
                (self.phase & 0x3FFF) as i32 - 8192
            }
            AdcSource::Feed => match self.feed.dequeue()? {
                FeedSample::Code(c) => c as i32,
                FeedSample::Metres(m) => return Some(Number::from_metres(m)),
            },
            AdcSource::Table => {
                let i = self.table_pos;
                if i >= self.table_len {
                    return None;
                }
                self.table_pos = i + 1;
                // table_len ≤ TABLE_LEN: the mask changes nothing and needs no bounds test.
                self.table[i & (TABLE_LEN - 1)] as i32
            }
        };
        // The "conversion" lands in the ADC's output register, then the driver reads it over
        // SPI exactly as on the board.
        let raw = ad4000::encode(code, 16, ad4000::Coding::StraightBinary);
        self.dev.device_mut().bus_mut().conversion = raw << 16;
        match self.dev.read_code() {
            Ok(c) => Some(self.scale.to_input(c)),
            Err(e) => match e {},
        }
    }
}

pub struct QemuU {
    dac: Ad5541<DacDev>,
}
impl loop_body::UOutput for QemuU {
    #[inline(always)]
    fn write(&mut self, code: i32) -> u16 {
        match self.dac.write_code(code) {
            Ok(w) => w,
            Err(e) => match e {},
        }
    }
}

pub struct QemuXy {
    x: Ad5541<DacDev>,
    y: Ad5541<DacDev>,
}
impl loop_body::XyOutput for QemuXy {
    fn write(&mut self, x_code: i32, y_code: i32) {
        let (Ok(_) | Err(_)) = self.x.write_code(x_code);
        let (Ok(_) | Err(_)) = self.y.write_code(y_code);
    }
}

pub type Loop = LoopState<QemuAdc, QemuU, QemuXy, ActiveCore, QueueLink<'static, 'static>>;

// ---- UART0 host link. ----

pub struct Uart;
impl Uart {
    fn init() -> Self {
        // SAFETY: UART0 registers; BAUDDIV ≥ 16 is required by the CMSDK UART model, and the
        // rate is irrelevant under QEMU (no pacing).
        unsafe {
            write_volatile(reg(UART0, UART_BAUDDIV), 16);
            write_volatile(
                reg(UART0, UART_CTRL),
                UART_CTRL_TX_EN | UART_CTRL_RX_EN | UART_CTRL_RX_INT_EN,
            );
        }
        Uart
    }
}
impl Link for Uart {
    #[inline]
    fn try_read(&mut self) -> Option<u8> {
        // SAFETY: UART0 registers.
        unsafe {
            if read_volatile(reg(UART0, UART_STATE)) & UART_STATE_RXFULL != 0 {
                Some(read_volatile(reg(UART0, UART_DATA)) as u8)
            } else {
                None
            }
        }
    }
    fn write_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            // SAFETY: UART0 registers.
            unsafe {
                while read_volatile(reg(UART0, UART_STATE)) & UART_STATE_TXFULL != 0 {}
                write_volatile(reg(UART0, UART_DATA), b as u32);
            }
        }
    }
}

// ---- The board. ----

pub struct Board {
    link: Option<Uart>,
    feed_tx: Producer<'static, FeedSample>,
    feed_rx: Option<Consumer<'static, FeedSample>>,
    feeding: bool,
    loading_table: bool,
    next_feed_index: u32,
}

pub fn init() -> Board {
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        fatal(6)
    };
    // SysTick free-running on the core clock, no interrupt: the instruction-count clock.
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();
    // TIMER1 free-running (32 bits, 25 MHz) to detect a SysTick wrap in long windows.
    // SAFETY: TIMER1 registers; no interrupt enabled.
    unsafe {
        write_volatile(reg(TIMER1_BASE, TIMER_RELOAD), u32::MAX);
        write_volatile(reg(TIMER1_BASE, TIMER_VALUE), u32::MAX);
        write_volatile(reg(TIMER1_BASE, TIMER_CTRL), TIMER_CTRL_EN);
    }
    // heapless's queue of N slots holds N − 1 items.
    let Some(feed) = cortex_m::singleton!(: Queue<FeedSample, { FEED_DEPTH + 1 }> = Queue::new())
    else {
        fatal(7)
    };
    let (feed_tx, feed_rx) = feed.split();
    let link = Uart::init();
    // The loop interrupt preempts everything; the UART interrupt only wakes the main loop.
    // SAFETY: priorities are set before either interrupt is unmasked.
    unsafe {
        cp.NVIC.set_priority(LoopIrq, 0x00);
        cp.NVIC.set_priority(EstimatorIrq, 0x40);
        cp.NVIC.set_priority(UartIrq, 0x80);
        NVIC::unmask(UartIrq);
    }
    Board {
        link: Some(link),
        feed_tx,
        feed_rx: Some(feed_rx),
        feeding: false,
        loading_table: false,
        next_feed_index: 0,
    }
}

fn device<B: SpiBus<u8>>(bus: B) -> CsDevice<B, VirtualPin, NoWait> {
    match CsDevice::new(bus, VirtualPin, NoWait) {
        Ok(d) => d,
        Err(e) => match e {},
    }
}

pub fn make_loop(
    b: &mut Board,
    adc_scale: Scale,
    core: ActiveCore,
    link: QueueLink<'static, 'static>,
    tel: Producer<'static, Item>,
) -> Loop {
    let Some(feed) = b.feed_rx.take() else {
        fatal(8)
    };
    let Some(table) = cortex_m::singleton!(: [i16; TABLE_LEN] = [0; TABLE_LEN]) else {
        fatal(10)
    };
    let mut adc = Ad4000::new(device(VirtualAdcBus { conversion: 0 }), CFG_TURBO);
    let (Ok(()) | Err(_)) = adc.configure();
    let (Ok(()) | Err(_)) = adc.prime();
    LoopState::new(
        QemuAdc {
            dev: adc,
            scale: adc_scale,
            source: AdcSource::Synthetic,
            phase: 0,
            feed,
            table,
            table_len: 0,
            table_pos: 0,
        },
        QemuU {
            dac: Ad5541::new(device(VirtualDacBus)),
        },
        QemuXy {
            x: Ad5541::new(device(VirtualDacBus)),
            y: Ad5541::new(device(VirtualDacBus)),
        },
        core,
        link,
        tel,
    )
}

/// Free slots of the replay queue.
fn feed_free(q: &Producer<'static, FeedSample>) -> usize {
    q.capacity() - q.len()
}

pub fn take_link(b: &mut Board) -> Uart {
    match b.link.take() {
        Some(l) => l,
        None => fatal(9),
    }
}

pub fn set_scales(l: &mut Loop, adc: Scale) {
    l.adc.scale = adc;
}

pub fn mask_loop() {
    NVIC::mask(LoopIrq);
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

pub fn unmask_loop() {
    // SAFETY: the loop state is initialised before the first unmask (app::run).
    unsafe { NVIC::unmask(LoopIrq) };
}

fn timer_stop() {
    // SAFETY: TIMER0 registers.
    unsafe {
        write_volatile(reg(TIMER0_BASE, TIMER_CTRL), 0);
        write_volatile(reg(TIMER0_BASE, TIMER_INTCLEAR), 1);
    }
    NVIC::unpend(LoopIrq);
}

fn timer_start(period_ticks: u32) {
    // SAFETY: TIMER0 registers. The timer counts RELOAD … 0: a period of RELOAD + 1 ticks.
    unsafe {
        write_volatile(
            reg(TIMER0_BASE, TIMER_RELOAD),
            period_ticks.saturating_sub(1),
        );
        write_volatile(
            reg(TIMER0_BASE, TIMER_VALUE),
            period_ticks.saturating_sub(1),
        );
        write_volatile(
            reg(TIMER0_BASE, TIMER_CTRL),
            TIMER_CTRL_EN | TIMER_CTRL_IRQEN,
        );
    }
}

/// Main loop housekeeping: in replay mode, one loop interrupt per fed sample, as long as the
/// telemetry queue has room for its Step frame and a possible Record frame.
pub fn poll(b: &mut Board, telemetry_free: usize) {
    if b.feeding && telemetry_free >= 2 && feed_free(&b.feed_tx) < FEED_DEPTH {
        NVIC::pend(LoopIrq);
    }
}

/// True while replay samples wait for the loop.
pub fn samples_pending(b: &Board) -> bool {
    b.feeding && feed_free(&b.feed_tx) < FEED_DEPTH
}

/// Sleeps until an interrupt, unless work is already waiting (checked with interrupts off,
/// so a wake-up between the check and `wfi` is not lost: a pending interrupt ends `wfi`).
pub fn idle(b: &Board) {
    cortex_m::interrupt::free(|_| {
        // SAFETY: UART0 state register.
        let rx = unsafe { read_volatile(reg(UART0, UART_STATE)) } & UART_STATE_RXFULL != 0;
        if !rx && !samples_pending(b) {
            cortex_m::asm::wfi();
        }
    });
}

/// Host bytes are taken only while a whole replay block still fits the replay queue, so a
/// decoded block never has to be refused; QEMU then holds the bytes (flow control).
pub fn can_accept_command(b: &Board) -> bool {
    feed_free(&b.feed_tx) >= MAX_FEED
}

pub fn set_source(b: &mut Board, src: Source) -> u8 {
    timer_stop();
    match src {
        Source::Table => {
            b.feeding = false;
            b.loading_table = true;
            b.next_feed_index = 0;
            app::with_loop(|l| {
                l.adc.table_len = 0;
                l.adc.table_pos = 0;
            });
        }
        Source::Timer { period_ticks } => {
            b.feeding = false;
            b.loading_table = false;
            app::with_loop(|l| {
                l.adc.source = AdcSource::Synthetic;
                l.reset_index(app::COUNTERS);
            });
            if period_ticks != 0 {
                timer_start(period_ticks);
            }
        }
        Source::Feed => {
            b.feeding = true;
            b.loading_table = false;
            b.next_feed_index = 0;
            app::with_loop(|l| {
                // Samples of an earlier replay still queued are discarded.
                while l.adc.feed.dequeue().is_some() {}
                l.adc.source = AdcSource::Feed;
                l.reset_index(app::COUNTERS);
            });
        }
    }
    ack::OK
}

pub fn feed(b: &mut Board, block: &FeedBlock) -> u8 {
    if !b.feeding && !b.loading_table {
        return ack::BUSY;
    }
    if block.first_index != b.next_feed_index {
        return ack::FEED_GAP;
    }
    if b.loading_table {
        return load_table(b, block);
    }
    let n = (block.len as usize).min(MAX_FEED);
    let mut pushed = 0u32;
    match &block.samples {
        FeedSamples::Codes(c) => {
            for &v in c.iter().take(n) {
                if b.feed_tx.enqueue(FeedSample::Code(v)).is_ok() {
                    pushed += 1;
                }
            }
        }
        FeedSamples::Metres(m) => {
            for &v in m.iter().take(n) {
                if b.feed_tx.enqueue(FeedSample::Metres(v)).is_ok() {
                    pushed += 1;
                }
            }
        }
    }
    b.next_feed_index = b.next_feed_index.wrapping_add(pushed);
    if pushed as usize == n {
        ack::OK
    } else {
        // Unreachable with the receive gating above; reported rather than hidden.
        ack::FEED_GAP
    }
}

/// Appends a block of codes to the bench table.
fn load_table(b: &mut Board, block: &FeedBlock) -> u8 {
    let FeedSamples::Codes(codes) = &block.samples else {
        return ack::INVALID; // the table holds ADC codes
    };
    let n = (block.len as usize).min(MAX_FEED);
    let first = block.first_index as usize;
    let stored = app::with_loop(|l| {
        let Some(dst) = l.adc.table.get_mut(first..first.saturating_add(n)) else {
            return false;
        };
        for (d, s) in dst.iter_mut().zip(codes.iter()) {
            *d = *s;
        }
        l.adc.table_len = first + n;
        true
    });
    if stored == Some(true) {
        b.next_feed_index = b.next_feed_index.wrapping_add(n as u32);
        ack::OK
    } else {
        ack::INVALID // beyond TABLE_LEN
    }
}

fn timer1_now() -> u32 {
    // SAFETY: TIMER1 value register.
    unsafe { read_volatile(reg(TIMER1_BASE, TIMER_VALUE)) }
}

/// Instructions per loop interrupt, measured as the SysTick time of `steps` timer-driven
/// loop interrupts minus the counted idle loop that runs between them.
///
/// Under `-icount shift=N` QEMU's virtual clock advances 2^N ns per executed instruction
/// (exception entry/exit are not instructions and take no virtual time), and SysTick counts
/// that virtual clock at 25 MHz, so `instructions = ticks × 40 / 2^N`: the host does this
/// conversion, after checking it with [`calibrate`].
///
/// Window: from the first SysTick read to the second, thread mode executes `movs` (1), the
/// idle loop (4 instructions per iteration: `ldr`, `adds`, `cmp`, `bmi`) and the second `ldr`
/// (1); everything else is the loop interrupts.
///
/// [`BenchMode::Continue`] keeps the core where a replay left it and reads the bench table
/// as the ADC input (the estimating phases of a recording); before the interrupts run, the
/// same `steps` calls of `step` alone are timed on a copy of the core in thread mode, and
/// the same loop without the call, so the host can split the interrupt into `step` and the
/// rest.
pub fn bench(b: &mut Board, mode: BenchMode, steps: u32, period_ticks: u32) -> Option<BenchFrame> {
    if steps == 0 || period_ticks < 2 {
        return None;
    }
    timer_stop();
    b.feeding = false;
    b.loading_table = false;
    let (mut step_ticks, mut loop_ticks, mut est_ticks, mut est_blocks) = (0, 0, 0, 0);
    let configured = app::with_loop(|l| {
        l.per_sample = false;
        let c = &mut l.core;
        match mode {
            BenchMode::Stopped => {
                l.adc.source = AdcSource::Synthetic;
                LoopCore::apply_command(c, CoreCommand::Stop);
            }
            BenchMode::Start(m) => {
                l.adc.source = AdcSource::Synthetic;
                LoopCore::apply_command(c, CoreCommand::Start(m));
            }
            BenchMode::Continue { time_step } => {
                if steps as usize > l.adc.table_len {
                    return false;
                }
                l.adc.source = AdcSource::Table;
                l.adc.table_pos = 0;
                if time_step {
                    let table = l.adc.table.get(..steps as usize).unwrap_or(&[]);
                    (step_ticks, loop_ticks, est_ticks, est_blocks) =
                        time_step_alone(c, table, l.adc.scale);
                }
            }
        }
        true
    });
    if configured != Some(true) {
        return None;
    }
    let counter = app::COUNTERS.samples.as_ptr();
    let target = app::COUNTERS
        .samples
        .load(Ordering::Relaxed)
        .wrapping_add(steps);
    let (t0, t1, idle): (u32, u32, u32);
    let w0 = timer1_now();
    timer_start(period_ticks);
    // SAFETY: reads SysTick and the sample counter; the loop interrupt writes the counter
    // (a plain aligned word) concurrently, which is the point.
    unsafe {
        core::arch::asm!(
            "ldr {t0}, [{cvr}]",
            "movs {it}, #0",
            "2:",
            "ldr {tmp}, [{cnt}]",
            "adds {it}, {it}, #1",
            "cmp {tmp}, {target}",
            "bmi 2b",
            "ldr {t1}, [{cvr}]",
            cvr = in(reg) SYST_CVR,
            cnt = in(reg) counter,
            target = in(reg) target,
            tmp = out(reg) _,
            it = out(reg) idle,
            t0 = out(reg) t0,
            t1 = out(reg) t1,
            options(nostack, readonly),
        );
    }
    timer_stop();
    let w1 = timer1_now();
    app::with_loop(|l| {
        if matches!(mode, BenchMode::Continue { .. }) {
            // The core stays where the recording took it; the host may continue the replay.
            l.adc.source = AdcSource::Synthetic;
        } else {
            l.core.apply_command(CoreCommand::Stop);
        }
    });
    let ticks = t0.wrapping_sub(t1) & 0x00FF_FFFF;
    // SysTick is 24 bits: a window of 2^24 ticks or more would wrap unseen.
    let wrapped = w0.wrapping_sub(w1) >= 0x00FF_0000;
    Some(BenchFrame {
        mode: match mode {
            BenchMode::Stopped => 0,
            BenchMode::Start(Mode::Dive) => 1,
            BenchMode::Start(Mode::Sve) => 2,
            BenchMode::Continue { .. } => 3,
        },
        steps,
        ticks: if wrapped { 0 } else { ticks },
        idle_iterations: idle,
        idle_insns_per_iteration: 4,
        fixed_insns: 2,
        step_ticks,
        loop_ticks,
        estimator_ticks: est_ticks,
        estimator_blocks: est_blocks,
    })
}

fn systick_now() -> u32 {
    // SAFETY: SysTick current value register.
    unsafe { read_volatile(SYST_CVR as *const u32) }
}

/// SysTick ticks of `step` over `table` on a copy of `core` (the interrupt's ADC conversion
/// in front of each call), of the same loop without the call, and of the estimator task's
/// work over the same input — each block's samples read in its queue slot into the block sums,
/// and the block updates — (with the number of blocks); interrupts masked.
fn time_step_alone(core: &ActiveCore, table: &[i16], scale: Scale) -> (u32, u32, u32, u32) {
    let mut copy = core.clone();
    let mut copy2 = core.clone();
    cortex_m::interrupt::free(|_| {
        // SAFETY: every interrupt is masked, the estimator's too.
        let Some(mut task) = (unsafe { app::ESTIMATOR.get() }).map(|e| e.task) else {
            return (0, 0, 0, 0);
        };
        // The step reads the chunks of tones the task computes ahead, as in the interrupt:
        // they are computed at each close here (`TonePrep::run`, timed apart and taken out).
        let mut chunks1 =
            [visco_firmware::core_glue::ToneChunk::new(<Number as visco_core::Real>::ZERO);
                loop_body::TONE_CHUNKS];
        let mut ready1: Queue<ToneBuf, { loop_body::TONE_SLOTS }> = Queue::new();
        let mut tfree1: Queue<ToneBuf, { loop_body::TONE_SLOTS }> = Queue::new();
        let (link1, mut prep1) = loop_body::tone_ends(&mut chunks1, &mut ready1, &mut tfree1);
        let mut tones1 = BenchTones(link1);
        let mut apart = 0u32;
        let t0 = systick_now();
        for &c in table {
            let d = scale.to_input(c as i32);
            // Through an opaque reference, as the interrupt sees its core: no state or
            // parameter is kept in registers from one call to the next. `LoopCore::step`,
            // the interrupt's entry (for Q32 the inherent `step` is the SI one), with the
            // loop's side of the block hand-over (the result check, the block taken). Only
            // what the interrupt uses of the output is kept: the DAC codes and the status
            // word (its SI values are telemetry, computed only in replay; for Q31.32 they are
            // three 128-bit products the interrupt never pays).
            let core = core::hint::black_box(&mut copy);
            if LoopCore::block_due(core) {
                LoopCore::close_block(core, |b| {
                    core::hint::black_box(&b);
                    let t3 = systick_now();
                    prep1.run(&task, &b);
                    apart = apart.wrapping_add(t3.wrapping_sub(systick_now()) & 0x00FF_FFFF);
                });
            }
            let o = LoopCore::step(core, core::hint::black_box(d), &mut tones1);
            core::hint::black_box((o.u_code, o.x_code, o.y_code, o.status));
        }
        let t1 = systick_now();
        for &c in table {
            let d = scale.to_input(c as i32);
            core::hint::black_box(core::hint::black_box(d));
        }
        let t2 = systick_now();
        // The estimator task's share, timed where it runs: `step` again on another copy,
        // its samples and block headers through queues like the firmware's, the result
        // adopted at each block close, and at every close the estimator interrupt's body
        // (`loop_body::run_blocks`: the block's samples, read in its queue slot, into the block sums,
        // the block update, the result queued) on a copy of the task between two SysTick
        // reads (their own cost, one load each, is part of the figure). Timing the task
        // itself, rather than the difference of two loops of `step` that the compiler lays
        // out differently (±10 per sample), puts the hand-over (samples and header queued)
        // on the loop's side, where the firmware runs it.
        // The chunks of tones, as the firmware's (declared first: the
        // queues of block buffers below hold references of the same lifetime).
        let mut chunks =
            [visco_firmware::core_glue::ToneChunk::new(<Number as visco_core::Real>::ZERO);
                loop_body::TONE_CHUNKS];
        let mut bufs = [SampleBlock::new(); loop_body::BLOCK_BUFFERS];
        let mut ready: Queue<ToneBuf, { loop_body::TONE_SLOTS }> = Queue::new();
        let mut tfree: Queue<ToneBuf, { loop_body::TONE_SLOTS }> = Queue::new();
        let mut full: Queue<BlockBuf, { loop_body::BUFFER_SLOTS }> = Queue::new();
        let mut free: Queue<BlockBuf, { loop_body::BUFFER_SLOTS }> = Queue::new();
        let mut results: Queue<BlockResult, { loop_body::ESTIMATOR_DEPTH + 1 }> = Queue::new();
        let (b_tx, mut b_rx) = full.split();
        let (mut f_tx, f_rx) = free.split();
        let (mut r_tx, r_rx) = results.split();
        let [stage, rest @ ..] = &mut bufs;
        for b in rest {
            let _ = f_tx.enqueue(b);
        }
        let (tone_link, mut prep) = loop_body::tone_ends(&mut chunks, &mut ready, &mut tfree);
        let counters = Counters::new();
        let mut link = QueueLink::new(stage, b_tx, f_rx, r_rx, || {}, &counters, tone_link);
        let mut blocks = 0u32;
        let mut est = 0u32;
        for &c in table {
            let d = scale.to_input(c as i32);
            let core = core::hint::black_box(&mut copy2);
            if LoopCore::block_due(core) {
                while let Some(r) = link.receive() {
                    LoopCore::deliver(core, &r);
                }
                if LoopCore::close_block(core, |b| link.send(b)) == Some(true) {
                    let t3 = systick_now();
                    loop_body::run_blocks(
                        core::hint::black_box(&mut task),
                        &mut b_rx,
                        &mut f_tx,
                        &mut r_tx,
                        &mut prep,
                    );
                    est = est.wrapping_add(t3.wrapping_sub(systick_now()) & 0x00FF_FFFF);
                    blocks += 1;
                }
            }
            let o = LoopCore::step(core, core::hint::black_box(d), &mut link);
            core::hint::black_box((o.u_code, o.x_code, o.y_code, o.status));
        }
        let step = (t0.wrapping_sub(t1) & 0x00FF_FFFF).wrapping_sub(apart);
        (step, t1.wrapping_sub(t2) & 0x00FF_FFFF, est, blocks)
    })
}

/// The step's sink in [`time_step_alone`]'s first loop: samples dropped, chunks of tones read
/// as the firmware's link reads them.
struct BenchTones<'a, 'b>(ToneLink<'a, 'b>);
impl visco_firmware::core_glue::ToneSource<Number> for BenchTones<'_, '_> {
    #[inline(always)]
    fn take_tones(&mut self, key: &visco_firmware::core_glue::ChunkKey) -> bool {
        self.0.take(key)
    }
    #[inline(always)]
    fn tone(&self, left: u32) -> Number {
        self.0.tone(left)
    }
}
impl visco_firmware::core_glue::SampleSink<Number> for BenchTones<'_, '_> {
    #[inline(always)]
    fn push(&mut self, x: Sample) {
        core::hint::black_box(x);
    }
}

/// SysTick ticks for a loop of exactly `2 × iterations + 1` instructions (the `subs`/`bne`
/// pairs and the closing SysTick read), with interrupts off.
pub fn calibrate(iterations: u32) -> Option<CalibrationFrame> {
    let n = iterations.max(1);
    let w0 = timer1_now();
    let (t0, t1) = cortex_m::interrupt::free(|_| {
        let (t0, t1): (u32, u32);
        // SAFETY: reads SysTick; a counted register loop.
        unsafe {
            core::arch::asm!(
                "ldr {t0}, [{cvr}]",
                "2:",
                "subs {n}, {n}, #1",
                "bne 2b",
                "ldr {t1}, [{cvr}]",
                cvr = in(reg) SYST_CVR,
                n = inout(reg) n => _,
                t0 = out(reg) t0,
                t1 = out(reg) t1,
                options(nostack, readonly),
            );
        }
        (t0, t1)
    });
    let w1 = timer1_now();
    let wrapped = w0.wrapping_sub(w1) >= 0x00FF_0000;
    Some(CalibrationFrame {
        iterations: n,
        instructions: n.wrapping_mul(2).wrapping_add(1),
        ticks: if wrapped {
            0
        } else {
            t0.wrapping_sub(t1) & 0x00FF_FFFF
        },
    })
}

pub fn exit(code: u8) -> ! {
    cortex_m_semihosting::debug::exit(if code == 0 {
        cortex_m_semihosting::debug::EXIT_SUCCESS
    } else {
        cortex_m_semihosting::debug::EXIT_FAILURE
    });
    #[allow(clippy::empty_loop)]
    loop {}
}

/// Unrecoverable start-up errors and faults: log, then end QEMU with a failure status so a
/// test never hangs on a dead image.
pub fn fatal(code: u8) -> ! {
    defmt::error!("fatal {=u8}", code);
    exit(code.max(1))
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_ef: &cortex_m_rt::ExceptionFrame) -> ! {
    fatal(2)
}
