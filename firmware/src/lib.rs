//! The board-independent part of the visco firmware: the loop body, the boundary to the
//! core, converter drivers over embedded-hal 1.0 and code ↔ metres conversion (the queues between
//! contexts are `heapless::spsc`). It builds and tests on the host (`cargo test -p visco-firmware`);
//! the binary (`src/main.rs`) adds the boards, the interrupt and the host link.
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod core_config;
pub mod core_glue;
pub mod core_number;
pub mod drivers;
pub mod loop_body;
pub mod scale;
pub mod spi_device;

#[cfg(test)]
mod testspi;
