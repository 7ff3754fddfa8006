//! The STM32H743 board (NUCLEO-H743ZI pin-out), built in CI, flashed with probe-rs
//! (`probe-rs run --chip STM32H743ZITx`, see firmware/README.md). Not run in CI: no
//! hardware there; the QEMU board runs the same loop code.
//!
//! - Clocks: HSI 64 MHz → PLL1 (M 4, N 50, P 2, Q 8): 400 MHz core (VOS1), 200 MHz AXI,
//!   100 MHz APB, 100 MHz SPI kernel clock (PLL1 Q), 200 MHz TIM2.
//! - ADC (AD4000-family, 3-wire turbo, CNV as chip select): SPI1 at 50 MHz, PA5 SCK, PA6
//!   MISO, PA7 MOSI (→ SDI), PA4 CNV.
//! - DACs (AD5541 for U, X, Y): SPI2 at 50 MHz, PB13 SCK, PB15 MOSI, chip selects PB12 (U),
//!   PC6 (X), PC7 (Y).
//! - Loop interrupt: TIM2 update at the configured period (200 MHz ticks); its handler and
//!   the drivers it inlines run from ITCM, the state is in DTCM.
//! - Host link: USART3 (PD8 TX, PD9 RX: the ST-LINK virtual COM port), 921 600 Bd.
//! - Log: defmt over RTT.

use crate::app::{self, Link};
use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};
use cortex_m::peripheral::NVIC;
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{ErrorType as PinErrorType, OutputPin};
use embedded_hal::spi::{ErrorType as SpiErrorType, SpiBus};
use heapless::spsc::Producer;
use stm32h7::stm32h743 as pac;
use visco_firmware::core_glue::{ActiveCore, Number};
use visco_firmware::drivers::ad4000::{part, Ad4000, CFG_TURBO};
use visco_firmware::drivers::ad5541::Ad5541;
use visco_firmware::loop_body::{self, Item, LoopState, QueueLink};
use visco_firmware::scale::Scale;
use visco_firmware::spi_device::CsDevice;
use visco_protocol::{ack, board, BenchFrame, BenchMode, CalibrationFrame, FeedBlock, Source};

#[cfg(not(feature = "panic-never"))]
use defmt_rtt as _;

/// With `panic-never`, defmt-rtt (which panics on re-entrant logging) is replaced by a
/// logger that drops everything, so the link check covers all of the firmware's own code.
#[cfg(feature = "panic-never")]
mod null_logger {
    #[defmt::global_logger]
    struct Null;
    // SAFETY: does nothing.
    unsafe impl defmt::Logger for Null {
        fn acquire() {}
        unsafe fn flush() {}
        unsafe fn release() {}
        unsafe fn write(_: &[u8]) {}
    }
}

pub const NAME: &str = "stm32h743";
pub const BOARD_ID: u8 = board::STM32H743;

// ---------------------------------------------------------------- clocks and power

fn init_clocks(dp: &pac::Peripherals) {
    let pwr = &dp.PWR;
    let rcc = &dp.RCC;
    let flash = &dp.FLASH;
    // SAFETY (all `bits` writes below): values from RM0433 for the named fields.
    unsafe {
        // Supply from the LDO (NUCLEO default), locked once after reset.
        pwr.cr3().modify(|r, w| w.bits((r.bits() & !0b111) | 0b010));
        while pwr.csr1().read().bits() & (1 << 13) == 0 {} // ACTVOSRDY
                                                           // Voltage scale 1 (400 MHz).
        pwr.d3cr()
            .modify(|r, w| w.bits((r.bits() & !(0b11 << 14)) | (0b11 << 14)));
        while pwr.d3cr().read().bits() & (1 << 13) == 0 {} // VOSRDY
                                                           // Flash: 2 wait states, programming delay 2, for a 200 MHz AXI clock at VOS1.
        flash.acr().write(|w| w.bits(2 | (2 << 4)));
        while flash.acr().read().bits() & 0xF != 2 {}
        // PLL1 from HSI: 64 / 4 = 16 MHz (range 8-16 MHz), × 50 = 800 MHz VCO (wide),
        // P / 2 = 400 MHz, Q / 8 = 100 MHz.
        rcc.pllckselr()
            .modify(|r, w| w.bits((r.bits() & !((0x3F << 4) | 0b11)) | (4 << 4)));
        rcc.pllcfgr().modify(|r, w| {
            w.bits((r.bits() & !0b1111 & !(0b111 << 16)) | (0b11 << 2) | (1 << 16) | (1 << 17))
        });
        rcc.pll1divr()
            .write(|w| w.bits((50 - 1) | ((2 - 1) << 9) | ((8 - 1) << 16) | ((2 - 1) << 24)));
        rcc.cr().modify(|r, w| w.bits(r.bits() | (1 << 24))); // PLL1ON
        while rcc.cr().read().bits() & (1 << 25) == 0 {} // PLL1RDY
                                                         // Bus prescalers: core /1, AXI/AHB /2, all APBs /2.
        rcc.d1cfgr().write(|w| w.bits(0b1000 | (0b100 << 4)));
        rcc.d2cfgr().write(|w| w.bits((0b100 << 4) | (0b100 << 8)));
        rcc.d3cfgr().write(|w| w.bits(0b100 << 4));
        // System clock switch to PLL1.
        rcc.cfgr()
            .modify(|r, w| w.bits((r.bits() & !0b111) | 0b011));
        while (rcc.cfgr().read().bits() >> 3) & 0b111 != 0b011 {}
        // Peripheral clocks: GPIOA-D, SPI1, SPI2, TIM2, USART3.
        rcc.ahb4enr().modify(|r, w| w.bits(r.bits() | 0b1111));
        rcc.apb2enr().modify(|r, w| w.bits(r.bits() | (1 << 12)));
        rcc.apb1lenr()
            .modify(|r, w| w.bits(r.bits() | 1 | (1 << 14) | (1 << 18)));
    }
    cortex_m::asm::dsb();
}

// ---------------------------------------------------------------- GPIO

/// A push-pull output.
pub struct Pin {
    bsrr: *mut u32,
    bit: u32,
}
// SAFETY: BSRR writes are atomic set/reset operations.
unsafe impl Send for Pin {}

impl Pin {
    /// Makes pin `n` of the port at `base` a very-high-speed push-pull output, high.
    fn output(base: usize, n: u32) -> Self {
        let p = Pin {
            bsrr: (base + 0x18) as *mut u32,
            bit: n,
        };
        // SAFETY: GPIO registers of an enabled port: MODER (0x00), OSPEEDR (0x08).
        unsafe {
            write_volatile(p.bsrr, 1 << n);
            modify(base, 0x08, 0b11 << (2 * n), 0b11 << (2 * n));
            modify(base, 0x00, 0b11 << (2 * n), 0b01 << (2 * n));
        }
        p
    }
}

/// Alternate function `af` for pin `n` of the port at `base`, very high speed.
fn alternate(base: usize, n: u32, af: u32) {
    let (afr, shift) = if n < 8 {
        (0x20, 4 * n)
    } else {
        (0x24, 4 * (n - 8))
    };
    // SAFETY: GPIO registers of an enabled port.
    unsafe {
        modify(base, afr, 0xF << shift, af << shift);
        modify(base, 0x08, 0b11 << (2 * n), 0b11 << (2 * n));
        modify(base, 0x00, 0b11 << (2 * n), 0b10 << (2 * n));
    }
}

/// # Safety
/// `base + off` must be a peripheral register.
unsafe fn modify(base: usize, off: usize, mask: u32, value: u32) {
    let r = (base + off) as *mut u32;
    // SAFETY: per the caller.
    unsafe { write_volatile(r, (read_volatile(r) & !mask) | value) };
}

impl PinErrorType for Pin {
    type Error = Infallible;
}
impl OutputPin for Pin {
    #[inline(always)]
    fn set_low(&mut self) -> Result<(), Infallible> {
        // SAFETY: BSRR reset bit of this pin.
        unsafe { write_volatile(self.bsrr, 1 << (self.bit + 16)) };
        Ok(())
    }
    #[inline(always)]
    fn set_high(&mut self) -> Result<(), Infallible> {
        // SAFETY: BSRR set bit of this pin.
        unsafe { write_volatile(self.bsrr, 1 << self.bit) };
        Ok(())
    }
}

const GPIOA: usize = 0x5802_0000;
const GPIOB: usize = 0x5802_0400;
const GPIOC: usize = 0x5802_0800;
const GPIOD: usize = 0x5802_0C00;

// ---------------------------------------------------------------- SPI (STM32H7 SPI v2)

/// A blocking full-duplex 8-bit master on an STM32H7 SPI, as an embedded-hal 1.0 `SpiBus`.
/// Runs in "endless" mode (TSIZE = 0, started once): each byte written to TXDR clocks one
/// byte in; chip selects are GPIOs handled by `ExclusiveDevice`.
pub struct H7Spi {
    base: usize,
}
// SAFETY: owns its peripheral.
unsafe impl Send for H7Spi {}

const SPI_CR1: usize = 0x00;
const SPI_CFG1: usize = 0x08;
const SPI_CFG2: usize = 0x0C;
const SPI_SR: usize = 0x14;
const SPI_TXDR: usize = 0x20;
const SPI_RXDR: usize = 0x30;
const SR_RXP: u32 = 1 << 0;
const SR_TXP: u32 = 1 << 1;
const SR_TXC: u32 = 1 << 12;

impl H7Spi {
    /// Master, mode 0, 8-bit frames, kernel clock / 2 (50 MHz from 100 MHz).
    fn new(base: usize) -> Self {
        // SAFETY: SPI registers of an enabled, disabled-state peripheral.
        unsafe {
            write_volatile((base + SPI_CFG1) as *mut u32, 7); // DSIZE 8 bits, MBR /2
            write_volatile(
                (base + SPI_CFG2) as *mut u32,
                (1 << 31) | (1 << 26) | (1 << 22), // AFCNTR, SSM, MASTER
            );
            write_volatile((base + SPI_CR1) as *mut u32, 1 << 12); // SSI
            write_volatile((base + SPI_CR1) as *mut u32, (1 << 12) | 1); // SPE
            write_volatile((base + SPI_CR1) as *mut u32, (1 << 12) | (1 << 9) | 1);
            // CSTART
        }
        H7Spi { base }
    }
    #[inline(always)]
    fn sr(&self) -> u32 {
        // SAFETY: SPI status register.
        unsafe { read_volatile((self.base + SPI_SR) as *const u32) }
    }
    #[inline(always)]
    fn xfer(&mut self, out: u8) -> u8 {
        while self.sr() & SR_TXP == 0 {}
        // SAFETY: 8-bit access to TXDR/RXDR moves exactly one frame.
        unsafe { write_volatile((self.base + SPI_TXDR) as *mut u8, out) };
        while self.sr() & SR_RXP == 0 {}
        // SAFETY: as above.
        unsafe { read_volatile((self.base + SPI_RXDR) as *const u8) }
    }
}

impl SpiErrorType for H7Spi {
    type Error = Infallible;
}

impl SpiBus<u8> for H7Spi {
    #[inline(always)]
    fn read(&mut self, words: &mut [u8]) -> Result<(), Infallible> {
        for w in words {
            *w = self.xfer(0xFF);
        }
        Ok(())
    }
    #[inline(always)]
    fn write(&mut self, words: &[u8]) -> Result<(), Infallible> {
        for &w in words {
            self.xfer(w);
        }
        Ok(())
    }
    #[inline(always)]
    fn transfer(&mut self, read: &mut [u8], write: &[u8]) -> Result<(), Infallible> {
        let n = read.len().max(write.len());
        for i in 0..n {
            let b = self.xfer(write.get(i).copied().unwrap_or(0xFF));
            if let Some(r) = read.get_mut(i) {
                *r = b;
            }
        }
        Ok(())
    }
    #[inline(always)]
    fn transfer_in_place(&mut self, words: &mut [u8]) -> Result<(), Infallible> {
        for w in words {
            *w = self.xfer(*w);
        }
        Ok(())
    }
    #[inline(always)]
    fn flush(&mut self) -> Result<(), Infallible> {
        while self.sr() & SR_TXC == 0 {}
        Ok(())
    }
}

/// Busy-wait delay on the 400 MHz core clock.
pub struct CycleDelay;
impl DelayNs for CycleDelay {
    #[inline(always)]
    fn delay_ns(&mut self, ns: u32) {
        cortex_m::asm::delay(ns.saturating_mul(2) / 5);
    }
}

/// SPI2 is shared by the three DACs; a device owns its bus, so each DAC gets a handle to the
/// same peripheral. Sound because only the loop interrupt uses them, one transaction at a
/// time (configuration happens before the interrupt is enabled).
type AdcDev = CsDevice<H7Spi, Pin, CycleDelay>;
type DacDev = CsDevice<H7Spi, Pin, CycleDelay>;

fn device(bus: H7Spi, cs: Pin) -> CsDevice<H7Spi, Pin, CycleDelay> {
    match CsDevice::new(bus, cs, CycleDelay) {
        Ok(d) => d,
        Err(e) => match e {},
    }
}

pub struct H7Adc {
    dev: Ad4000<AdcDev, part::Ad4000>,
    scale: Scale,
}
impl loop_body::Adc for H7Adc {
    #[inline(always)]
    fn sample(&mut self) -> Option<Number> {
        match self.dev.read_code() {
            Ok(c) => Some(self.scale.to_input(c)),
            Err(e) => match e {},
        }
    }
}

pub struct H7U {
    dac: Ad5541<DacDev>,
}
impl loop_body::UOutput for H7U {
    #[inline(always)]
    fn write(&mut self, code: i32) -> u16 {
        match self.dac.write_code(code) {
            Ok(w) => w,
            Err(e) => match e {},
        }
    }
}

pub struct H7Xy {
    x: Ad5541<DacDev>,
    y: Ad5541<DacDev>,
}
impl loop_body::XyOutput for H7Xy {
    fn write(&mut self, x_code: i32, y_code: i32) {
        let (Ok(_) | Err(_)) = self.x.write_code(x_code);
        let (Ok(_) | Err(_)) = self.y.write_code(y_code);
    }
}

pub type Loop = LoopState<H7Adc, H7U, H7Xy, ActiveCore, QueueLink<'static, 'static>>;

// ---------------------------------------------------------------- loop interrupt (TIM2)

const TIM2_BASE: usize = 0x4000_0000;

/// The loop interrupt, in ITCM: acknowledge the timer, then one sample.
#[unsafe(no_mangle)]
#[unsafe(link_section = ".itcm.TIM2")]
pub unsafe extern "C" fn TIM2() {
    // SAFETY: TIM2 status register; writing 0 to UIF clears it (rc_w0).
    unsafe { write_volatile((TIM2_BASE + 0x10) as *mut u32, 0) };
    app::loop_interrupt();
}

/// The estimator interrupt, in ITCM, below the loop's priority: TIM3's vector (the timer
/// stays off; the loop pends it by software when it hands over a block).
#[unsafe(no_mangle)]
#[unsafe(link_section = ".itcm.TIM3")]
pub unsafe extern "C" fn TIM3() {
    app::estimator_interrupt();
}

/// Pends the estimator interrupt.
#[inline(always)]
pub fn pend_estimator() {
    NVIC::pend(pac::Interrupt::TIM3);
}

pub fn mask_estimator() {
    NVIC::mask(pac::Interrupt::TIM3);
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

pub fn unmask_estimator() {
    // SAFETY: the estimator state is initialised before the first unmask (app::run).
    unsafe { NVIC::unmask(pac::Interrupt::TIM3) };
}

pub fn mask_loop() {
    NVIC::mask(pac::Interrupt::TIM2);
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

pub fn unmask_loop() {
    // SAFETY: the loop state is initialised before the first unmask (app::run).
    unsafe { NVIC::unmask(pac::Interrupt::TIM2) };
}

fn timer_stop() {
    // SAFETY: TIM2 CR1 and SR.
    unsafe {
        write_volatile(TIM2_BASE as *mut u32, 0);
        write_volatile((TIM2_BASE + 0x10) as *mut u32, 0);
    }
    NVIC::unpend(pac::Interrupt::TIM2);
}

fn timer_start(period_ticks: u32) {
    // SAFETY: TIM2 registers: PSC 0, ARR, DIER.UIE, EGR.UG, CR1.CEN.
    unsafe {
        write_volatile((TIM2_BASE + 0x28) as *mut u32, 0);
        write_volatile(
            (TIM2_BASE + 0x2C) as *mut u32,
            period_ticks.saturating_sub(1),
        );
        write_volatile((TIM2_BASE + 0x14) as *mut u32, 1);
        write_volatile((TIM2_BASE + 0x10) as *mut u32, 0);
        write_volatile((TIM2_BASE + 0x0C) as *mut u32, 1);
        write_volatile(TIM2_BASE as *mut u32, 1);
    }
}

// ---------------------------------------------------------------- USART3 host link

const USART3: usize = 0x4000_4800;

pub struct Uart;
impl Uart {
    fn init() -> Self {
        alternate(GPIOD, 8, 7);
        alternate(GPIOD, 9, 7);
        // SAFETY: USART3 registers: BRR for 921 600 Bd from 100 MHz, CR1 FIFO, TE, RE, UE.
        unsafe {
            write_volatile((USART3 + 0x0C) as *mut u32, 109);
            write_volatile(
                USART3 as *mut u32, // CR1
                (1 << 29) | (1 << 3) | (1 << 2) | 1,
            );
        }
        Uart
    }
}
impl Link for Uart {
    #[inline]
    fn try_read(&mut self) -> Option<u8> {
        // SAFETY: USART3 ISR, ICR (clear overrun), RDR.
        unsafe {
            let isr = read_volatile((USART3 + 0x1C) as *const u32);
            if isr & (1 << 3) != 0 {
                // An overrun loses bytes; the frame CRC/sequence numbers report it.
                write_volatile((USART3 + 0x20) as *mut u32, 1 << 3);
            }
            if isr & (1 << 5) != 0 {
                Some(read_volatile((USART3 + 0x24) as *const u32) as u8)
            } else {
                None
            }
        }
    }
    fn write_all(&mut self, bytes: &[u8]) {
        for &b in bytes {
            // SAFETY: USART3 ISR and TDR.
            unsafe {
                while read_volatile((USART3 + 0x1C) as *const u32) & (1 << 7) == 0 {}
                write_volatile((USART3 + 0x28) as *mut u32, b as u32);
            }
        }
    }
}

// ---------------------------------------------------------------- the board

pub struct Board {
    link: Option<Uart>,
}

/// Copies the `.itcm` section from flash to ITCM (before anything there runs).
fn load_itcm() {
    unsafe extern "C" {
        static mut __sitcm: u32;
        static mut __eitcm: u32;
        static __siitcm: u32;
    }
    // SAFETY: linker-provided bounds of the ITCM section and its load image; word aligned
    // (ALIGN(8) in memory.x); nothing executes from ITCM yet.
    unsafe {
        let mut dst = &raw mut __sitcm;
        let end = &raw mut __eitcm;
        let mut src = &raw const __siitcm;
        while dst < end {
            dst.write_volatile(src.read());
            dst = dst.add(1);
            src = src.add(1);
        }
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}

pub fn init() -> Board {
    load_itcm();
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        fatal(6)
    };
    let Some(dp) = pac::Peripherals::take() else {
        fatal(6)
    };
    init_clocks(&dp);
    cp.SCB.enable_icache();
    // SysTick free-running on the core clock, for timing measurements.
    cp.SYST
        .set_clock_source(cortex_m::peripheral::syst::SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();
    // SAFETY: priority set before the interrupt is unmasked.
    unsafe {
        cp.NVIC.set_priority(pac::Interrupt::TIM2, 0);
        cp.NVIC.set_priority(pac::Interrupt::TIM3, 0x40);
    }
    Board {
        link: Some(Uart::init()),
    }
}

pub fn make_loop(
    _b: &mut Board,
    adc_scale: Scale,
    core: ActiveCore,
    link: QueueLink<'static, 'static>,
    tel: Producer<'static, Item>,
) -> Loop {
    for n in [5, 6, 7] {
        alternate(GPIOA, n, 5); // SPI1 SCK, MISO, MOSI
    }
    alternate(GPIOB, 13, 5); // SPI2 SCK
    alternate(GPIOB, 15, 5); // SPI2 MOSI
    let cnv = Pin::output(GPIOA, 4);
    let mut adc = Ad4000::new(device(H7Spi::new(0x4001_3000), cnv), CFG_TURBO);
    let (Ok(()) | Err(_)) = adc.configure();
    let (Ok(()) | Err(_)) = adc.prime();
    let spi2 = || H7Spi { base: 0x4000_3800 };
    let u_bus = H7Spi::new(0x4000_3800);
    LoopState::new(
        H7Adc {
            dev: adc,
            scale: adc_scale,
        },
        H7U {
            dac: Ad5541::new(device(u_bus, Pin::output(GPIOB, 12))),
        },
        H7Xy {
            x: Ad5541::new(device(spi2(), Pin::output(GPIOC, 6))),
            y: Ad5541::new(device(spi2(), Pin::output(GPIOC, 7))),
        },
        core,
        link,
        tel,
    )
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

pub fn poll(_b: &mut Board, _telemetry_free: usize) {}

pub fn samples_pending(_b: &Board) -> bool {
    false
}

pub fn can_accept_command(_b: &Board) -> bool {
    true
}

pub fn idle(_b: &Board) {
    // The USART has no interrupt enabled here, so no `wfi`: the main loop keeps polling it.
}

/// `Timer { period_ticks }` counts TIM2's 200 MHz kernel clock (APB1 100 MHz with a /2
/// prescaler: timers run at twice the APB clock): 200 ticks = 1 MHz.
pub fn set_source(_b: &mut Board, src: Source) -> u8 {
    timer_stop();
    match src {
        Source::Timer { period_ticks } => {
            app::with_loop(|l| l.reset_index(app::COUNTERS));
            if period_ticks != 0 {
                timer_start(period_ticks);
            }
            ack::OK
        }
        Source::Feed | Source::Table => ack::UNSUPPORTED,
    }
}

pub fn feed(_b: &mut Board, _block: &FeedBlock) -> u8 {
    ack::UNSUPPORTED
}

pub fn bench(
    _b: &mut Board,
    _mode: BenchMode,
    _steps: u32,
    _period_ticks: u32,
) -> Option<BenchFrame> {
    None
}

pub fn calibrate(_iterations: u32) -> Option<CalibrationFrame> {
    None
}

pub fn exit(_code: u8) -> ! {
    // No host to return to: park the core.
    loop {
        cortex_m::asm::wfi();
    }
}

pub fn fatal(code: u8) -> ! {
    defmt::error!("fatal {=u8}", code);
    // Outputs hold their last value; a debugger (probe-rs) shows the log and the halt.
    loop {
        cortex_m::asm::wfi();
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_ef: &cortex_m_rt::ExceptionFrame) -> ! {
    fatal(2)
}
