//! Drivers for the converters, written against embedded-hal 1.0 `SpiDevice`, so they run
//! unchanged on the STM32H743's SPI peripherals and on the QEMU board's virtual SPI bus.

pub mod ad4000;
pub mod ad5541;
