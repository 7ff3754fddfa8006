//! The wire format between the visco firmware and the host.
//!
//! - [`msg`]: the messages, [`Command`] (host → firmware: mode, configuration, start/stop,
//!   replay samples, measurements) and [`Telemetry`] (firmware → host: per-sample outputs,
//!   records, counters, measurements).
//! - [`frame`]: `COBS(seq | message | CRC-32) 0x00` framing with a streaming decoder.
//! - [`seq`]: counting lost frames from sequence numbers, tolerant of small reordering.
//!
//! `no_std`, no allocation, no `unsafe`, and no panic path on any input: the firmware links
//! this crate into an image whose panic handler fails the link if it is reachable.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod cobs;
pub mod crc;
pub mod frame;
pub mod msg;
pub mod seq;
pub mod wire;

pub use frame::{FrameDecoder, FrameError, MAX_WIRE};
pub use msg::*;
pub use seq::{SeqEvent, SeqTracker};

#[cfg(test)]
mod tests;
