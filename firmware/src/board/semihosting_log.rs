//! defmt global logger over semihosting (QEMU's stdout with `target=native`), written here
//! instead of using `defmt-semihosting` because that crate panics on re-entrant logging,
//! and the QEMU image must link with the `panic-never` handler (`cargo xtask panic-check`).
//! A nested log call (only possible from a fault handler while thread mode logs) is dropped
//! instead.
//!
//! Logging stops interrupts for the duration of one frame (a semihosting trap), so it is
//! used from the main loop on commands only, never per sample and never in the loop
//! interrupt.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU8, Ordering};
use cortex_m_semihosting::hio::{self, HostStream};

#[defmt::global_logger]
struct Logger;

struct State {
    encoder: defmt::Encoder,
    out: Option<HostStream>,
    primask_was_active: bool,
}

struct Shared(UnsafeCell<State>);
// SAFETY: only touched between `acquire` and `release`, with interrupts disabled, by the
// outermost holder (DEPTH == 1) on a single core.
unsafe impl Sync for Shared {}

static STATE: Shared = Shared(UnsafeCell::new(State {
    encoder: defmt::Encoder::new(),
    out: None,
    primask_was_active: false,
}));
static DEPTH: AtomicU8 = AtomicU8::new(0);

fn emit(bytes: &[u8]) {
    // SAFETY: called by the encoder inside acquire/release at DEPTH == 1.
    let st = unsafe { &mut *STATE.0.get() };
    if st.out.is_none() {
        st.out = hio::hstdout().ok();
    }
    if let Some(out) = st.out.as_mut() {
        // A failed host write loses log output only; nothing to do about it here.
        let _ = out.write_all(bytes);
    }
}

// SAFETY: acquire/release pair up per defmt's contract; the encoder is used only by the
// outermost holder with interrupts disabled.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        let active = cortex_m::register::primask::read().is_active();
        cortex_m::interrupt::disable();
        let depth = DEPTH.load(Ordering::Relaxed);
        DEPTH.store(depth.saturating_add(1), Ordering::Relaxed);
        if depth == 0 {
            // SAFETY: outermost holder, interrupts disabled.
            let st = unsafe { &mut *STATE.0.get() };
            st.primask_was_active = active;
            st.encoder.start_frame(emit);
        }
    }

    unsafe fn flush() {}

    unsafe fn release() {
        let depth = DEPTH.load(Ordering::Relaxed);
        if depth == 1 {
            // SAFETY: outermost holder, interrupts disabled.
            let st = unsafe { &mut *STATE.0.get() };
            st.encoder.end_frame(emit);
            let enable = st.primask_was_active;
            DEPTH.store(0, Ordering::Relaxed);
            if enable {
                // SAFETY: restores the interrupt state found in `acquire`.
                unsafe { cortex_m::interrupt::enable() };
            }
        } else {
            DEPTH.store(depth.saturating_sub(1), Ordering::Relaxed);
        }
    }

    unsafe fn write(bytes: &[u8]) {
        if DEPTH.load(Ordering::Relaxed) == 1 {
            // SAFETY: outermost holder, interrupts disabled.
            let st = unsafe { &mut *STATE.0.get() };
            st.encoder.write(bytes, emit);
        }
    }
}
