//! An embedded-hal 1.0 `SpiDevice` from a `SpiBus` and a chip-select `OutputPin`.
//!
//! Why not `embedded_hal_bus::spi::ExclusiveDevice`: its transaction is a separate function
//! that keeps a panic path for `Operation::DelayNs` with `NoDelay`, and on the STM32H743 it
//! stays out of line, in flash, while the loop interrupt runs from ITCM. This one is
//! `#[inline(always)]`, has no panic path, and delays with the board's `DelayNs`.

use embedded_hal::delay::DelayNs;
use embedded_hal::digital::OutputPin;
use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiBus, SpiDevice};

/// A device on its own chip select.
pub struct CsDevice<B, P, D> {
    bus: B,
    cs: P,
    delay: D,
}

/// A bus or chip-select failure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CsError<BE, PE> {
    /// The bus failed.
    Bus(BE),
    /// The chip-select pin failed.
    Cs(PE),
}

impl<BE: embedded_hal::spi::Error, PE: core::fmt::Debug> embedded_hal::spi::Error
    for CsError<BE, PE>
{
    fn kind(&self) -> ErrorKind {
        match self {
            CsError::Bus(e) => e.kind(),
            CsError::Cs(_) => ErrorKind::ChipSelectFault,
        }
    }
}

impl<B: SpiBus<u8>, P: OutputPin, D: DelayNs> CsDevice<B, P, D> {
    /// Takes the bus and pin; the chip select is driven high (inactive).
    pub fn new(bus: B, mut cs: P, delay: D) -> Result<Self, P::Error> {
        cs.set_high()?;
        Ok(Self { bus, cs, delay })
    }

    /// The bus (outside a transaction).
    #[inline(always)]
    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }
}

impl<B: SpiBus<u8>, P: OutputPin, D> ErrorType for CsDevice<B, P, D> {
    type Error = CsError<B::Error, P::Error>;
}

impl<B: SpiBus<u8>, P: OutputPin, D: DelayNs> SpiDevice<u8> for CsDevice<B, P, D> {
    #[inline(always)]
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), Self::Error> {
        self.cs.set_low().map_err(CsError::Cs)?;
        let mut res = Ok(());
        for op in ops.iter_mut() {
            res = match op {
                Operation::Read(r) => self.bus.read(r),
                Operation::Write(w) => self.bus.write(w),
                Operation::Transfer(r, w) => self.bus.transfer(r, w),
                Operation::TransferInPlace(rw) => self.bus.transfer_in_place(rw),
                Operation::DelayNs(ns) => {
                    // The bus must be idle before a delay counts.
                    let f = self.bus.flush();
                    self.delay.delay_ns(*ns);
                    f
                }
            };
            if res.is_err() {
                break;
            }
        }
        // Flush before raising CS (for the AD4000 the rising edge starts a conversion; for
        // the AD5541 it updates the output), even after an error.
        let flushed = self.bus.flush();
        let raised = self.cs.set_high();
        res.map_err(CsError::Bus)?;
        flushed.map_err(CsError::Bus)?;
        raised.map_err(CsError::Cs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::convert::Infallible;
    use std::vec::Vec;

    #[derive(Default)]
    struct Log(Vec<&'static str>);
    struct Bus<'a>(&'a core::cell::RefCell<Log>);
    struct Pin<'a>(&'a core::cell::RefCell<Log>);
    struct Delay<'a>(&'a core::cell::RefCell<Log>);
    impl ErrorType for Bus<'_> {
        type Error = Infallible;
    }
    impl SpiBus<u8> for Bus<'_> {
        fn read(&mut self, w: &mut [u8]) -> Result<(), Infallible> {
            w.fill(0xA5);
            self.0.borrow_mut().0.push("read");
            Ok(())
        }
        fn write(&mut self, _: &[u8]) -> Result<(), Infallible> {
            self.0.borrow_mut().0.push("write");
            Ok(())
        }
        fn transfer(&mut self, r: &mut [u8], _: &[u8]) -> Result<(), Infallible> {
            r.fill(0x5A);
            self.0.borrow_mut().0.push("transfer");
            Ok(())
        }
        fn transfer_in_place(&mut self, _: &mut [u8]) -> Result<(), Infallible> {
            self.0.borrow_mut().0.push("in_place");
            Ok(())
        }
        fn flush(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().0.push("flush");
            Ok(())
        }
    }
    impl embedded_hal::digital::ErrorType for Pin<'_> {
        type Error = Infallible;
    }
    impl OutputPin for Pin<'_> {
        fn set_low(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().0.push("cs_low");
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().0.push("cs_high");
            Ok(())
        }
    }
    impl DelayNs for Delay<'_> {
        fn delay_ns(&mut self, _: u32) {
            self.0.borrow_mut().0.push("delay");
        }
    }

    #[test]
    fn chip_select_frames_the_transaction_after_flush() {
        let log = core::cell::RefCell::new(Log::default());
        let mut d = CsDevice::new(Bus(&log), Pin(&log), Delay(&log)).unwrap();
        let mut buf = [0u8; 2];
        d.transaction(&mut [
            Operation::Write(&[1]),
            Operation::DelayNs(100),
            Operation::Read(&mut buf),
        ])
        .unwrap();
        assert_eq!(buf, [0xA5, 0xA5]);
        assert_eq!(
            log.borrow().0,
            ["cs_high", "cs_low", "write", "flush", "delay", "read", "flush", "cs_high"]
        );
    }
}
