//! Frames: `COBS( seq:u32 | message | crc32(seq|message) ) 0x00`.
//!
//! The sequence number is per direction and per sender, incremented for every frame the
//! sender *meant* to send, so a frame that is dropped anywhere (a full queue in the
//! firmware, a lost or corrupted byte on the link) leaves a gap that [`crate::SeqTracker`]
//! counts. The CRC covers the sequence number too, so a corrupted sequence number is a CRC
//! failure, not a phantom gap.

use crate::cobs::{self, CobsError};
use crate::crc::crc32;
use crate::msg::{Command, DecodeError, Telemetry};
use crate::wire::{Short, Writer};

/// The longest message (kind byte and fields) a frame carries.
pub const MAX_MESSAGE: usize = 240;
/// The longest frame before COBS: sequence number, message, CRC.
pub const MAX_RAW: usize = 4 + MAX_MESSAGE + 4;
/// The longest frame on the wire, delimiter included.
pub const MAX_WIRE: usize = cobs::max_encoded_len(MAX_RAW) + 1;

/// Why a received frame was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// Invalid COBS (a lost byte usually shows up here or as a CRC failure).
    Cobs(CobsError),
    /// Shorter than a sequence number and a CRC.
    TooShort,
    /// Longer than [`MAX_WIRE`] before a delimiter arrived.
    TooLong,
    /// The CRC does not match.
    Crc,
    /// The CRC matched but the message did not decode (version mismatch?).
    Decode(DecodeError),
}

/// A message type that travels in frames.
pub trait Message: Sized {
    /// Writes the message.
    fn encode_to(&self, w: &mut Writer<'_>) -> Result<(), Short>;
    /// Reads the message.
    fn decode_from(bytes: &[u8]) -> Result<Self, DecodeError>;
}

impl Message for Command {
    fn encode_to(&self, w: &mut Writer<'_>) -> Result<(), Short> {
        self.encode(w)
    }
    fn decode_from(bytes: &[u8]) -> Result<Self, DecodeError> {
        Command::decode(bytes)
    }
}

impl Message for Telemetry {
    fn encode_to(&self, w: &mut Writer<'_>) -> Result<(), Short> {
        self.encode(w)
    }
    fn decode_from(bytes: &[u8]) -> Result<Self, DecodeError> {
        Telemetry::decode(bytes)
    }
}

/// Encodes `msg` with sequence number `seq` into `out` (at least [`MAX_WIRE`] bytes is
/// always enough), delimiter included; returns the number of bytes to send.
pub fn encode<M: Message>(seq: u32, msg: &M, out: &mut [u8]) -> Result<usize, Short> {
    let mut raw = [0u8; MAX_RAW];
    let n = {
        let mut w = Writer::new(&mut raw[..4 + MAX_MESSAGE]);
        w.u32(seq)?;
        msg.encode_to(&mut w)?;
        w.len()
    };
    let crc = crc32(raw.get(..n).ok_or(Short)?);
    let total = {
        let tail = raw.get_mut(n..).ok_or(Short)?;
        let mut w = Writer::new(tail);
        w.u32(crc)?;
        n + 4
    };
    let used = cobs::encode(raw.get(..total).ok_or(Short)?, out).map_err(|_| Short)?;
    *out.get_mut(used).ok_or(Short)? = 0;
    Ok(used + 1)
}

/// Reassembles frames from a byte stream, one byte at a time (no allocation).
pub struct FrameDecoder {
    buf: [u8; MAX_WIRE],
    len: usize,
    overflow: bool,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_WIRE],
            len: 0,
            overflow: false,
        }
    }

    /// Feeds one byte. At a delimiter returns the frame: its sequence number and message, or
    /// why it was rejected. Empty frames (two delimiters in a row, used to resynchronise) are
    /// skipped without a result.
    pub fn push<M: Message>(&mut self, byte: u8) -> Option<Result<(u32, M), FrameError>> {
        if byte != 0 {
            match self.buf.get_mut(self.len) {
                Some(slot) => {
                    *slot = byte;
                    self.len += 1;
                }
                None => self.overflow = true,
            }
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.overflow, false) {
            return Some(Err(FrameError::TooLong));
        }
        if len == 0 {
            return None;
        }
        Some(decode_frame(self.buf.get(..len).unwrap_or(&[])))
    }
}

/// Decodes one frame's COBS bytes (without the delimiter).
pub fn decode_frame<M: Message>(wire: &[u8]) -> Result<(u32, M), FrameError> {
    let mut raw = [0u8; MAX_RAW];
    let n = cobs::decode(wire, &mut raw).map_err(FrameError::Cobs)?;
    let raw = raw.get(..n).ok_or(FrameError::TooShort)?;
    if n < 8 {
        return Err(FrameError::TooShort);
    }
    let (body, crc_bytes) = raw.split_at(n - 4);
    let mut c = [0u8; 4];
    for (d, &s) in c.iter_mut().zip(crc_bytes) {
        *d = s;
    }
    if crc32(body) != u32::from_le_bytes(c) {
        return Err(FrameError::Crc);
    }
    let (seq_bytes, msg) = body.split_at(4);
    let mut s = [0u8; 4];
    for (d, &b) in s.iter_mut().zip(seq_bytes) {
        *d = b;
    }
    let m = M::decode_from(msg).map_err(FrameError::Decode)?;
    Ok((u32::from_le_bytes(s), m))
}
