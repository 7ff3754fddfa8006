//! AD4000-family SAR ADCs (AD4000/AD4004/AD4008 16-bit pseudo-differential, straight binary;
//! AD4001/AD4005 16-bit differential and AD4003/AD4007/AD4011 18-bit differential, two's
//! complement).
//!
//! Wiring assumed: "3-wire CS mode" with CNV driven as the `SpiDevice`'s chip select. The
//! rising edge of CNV at the end of each read starts the next conversion, so
//! [`Ad4000::read_code`] returns the conversion started by the *previous* read: one sample
//! of latency, and the sampling instant is set by when the loop interrupt finishes its
//! read (jitter = the interrupt latency jitter, a few cycles). Turbo mode lets the read
//! overlap the next conversion's quiet time, which is what makes 1 MS/s reachable with a
//! 16-bit read at ≥ 40 MHz SCLK.
//!
//! During reads MOSI sends all ones so that SDI stays high whether it is tied to VIO or
//! wired to MOSI (SDI low at the CNV edge would select a different interface mode).

use embedded_hal::spi::SpiDevice;

/// Register write command (followed by the register value).
pub const CMD_WRITE: u8 = 0x14;
/// Register read command (the register comes back in the next byte).
pub const CMD_READ: u8 = 0x54;
/// Configuration register: output 6 status bits after the conversion result.
pub const CFG_STATUS: u8 = 1 << 4;
/// Configuration register: input span compression.
pub const CFG_SPAN_COMPRESSION: u8 = 1 << 3;
/// Configuration register: high-impedance input mode.
pub const CFG_HIGH_Z: u8 = 1 << 2;
/// Configuration register: turbo mode.
pub const CFG_TURBO: u8 = 1 << 1;

/// Output coding of the part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coding {
    /// Pseudo-differential parts (AD4000/4004/4008): 0 … 2ⁿ−1, mid-scale 2ⁿ⁻¹.
    StraightBinary,
    /// Differential parts (AD4001/4003/…): signed.
    TwosComplement,
}

/// A member of the family: resolution and coding are compile-time constants, so the loop's
/// read has no branch on them.
pub trait Part {
    /// Bits per conversion (16 or 18).
    const BITS: u32;
    /// Output coding.
    const CODING: Coding;
}

/// The parts.
pub mod part {
    use super::{Coding, Part};
    /// AD4000 (and AD4004, AD4008): 16 bits, pseudo-differential, straight binary.
    pub struct Ad4000;
    /// AD4001 (and AD4005): 16 bits, differential, two's complement.
    pub struct Ad4001;
    /// AD4003 (and AD4007, AD4011): 18 bits, differential, two's complement.
    pub struct Ad4003;
    impl Part for Ad4000 {
        const BITS: u32 = 16;
        const CODING: Coding = Coding::StraightBinary;
    }
    impl Part for Ad4001 {
        const BITS: u32 = 16;
        const CODING: Coding = Coding::TwosComplement;
    }
    impl Part for Ad4003 {
        const BITS: u32 = 18;
        const CODING: Coding = Coding::TwosComplement;
    }
}

/// An AD4000-family ADC on an SPI device whose chip select is CNV.
pub struct Ad4000<S, P: Part> {
    spi: S,
    register: u8,
    _part: core::marker::PhantomData<P>,
}

impl<S: SpiDevice<u8>, P: Part> Ad4000<S, P> {
    /// Wraps the device; `register` is the configuration written by [`Self::configure`]
    /// (e.g. [`CFG_TURBO`]). Call [`Self::configure`] and [`Self::prime`] before the loop.
    pub fn new(spi: S, register: u8) -> Self {
        Self {
            spi,
            register,
            _part: core::marker::PhantomData,
        }
    }

    /// Writes the configuration register (needs SDI wired to MOSI).
    pub fn configure(&mut self) -> Result<(), S::Error> {
        self.spi.write(&[CMD_WRITE, self.register])
    }

    /// Reads the configuration register back (needs SDI wired to MOSI).
    pub fn read_register(&mut self) -> Result<u8, S::Error> {
        let mut rx = [0u8; 2];
        self.spi.transfer(&mut rx, &[CMD_READ, 0xFF])?;
        Ok(rx[1])
    }

    /// One read whose result is discarded: starts the first conversion of the loop.
    pub fn prime(&mut self) -> Result<(), S::Error> {
        self.read_code().map(|_| ())
    }

    /// The last conversion as a signed code relative to mid-scale (this read's CNV edge
    /// starts the next conversion).
    #[inline(always)]
    pub fn read_code(&mut self) -> Result<i32, S::Error> {
        if P::BITS > 16 {
            let mut rx = [0u8; 3];
            self.spi.transfer(&mut rx, &[0xFF; 3])?;
            let raw = ((rx[0] as u32) << 10) | ((rx[1] as u32) << 2) | ((rx[2] as u32) >> 6);
            Ok(decode(raw, 18, P::CODING))
        } else {
            let mut rx = [0u8; 2];
            self.spi.transfer(&mut rx, &[0xFF; 2])?;
            Ok(decode(u16::from_be_bytes(rx) as u32, 16, P::CODING))
        }
    }

    /// The SPI device (e.g. for a board's virtual converter).
    #[inline(always)]
    pub fn device_mut(&mut self) -> &mut S {
        &mut self.spi
    }

    /// The SPI device back.
    pub fn release(self) -> S {
        self.spi
    }
}

/// A raw `bits`-bit result to a signed code relative to mid-scale.
#[inline(always)]
pub fn decode(raw: u32, bits: u32, coding: Coding) -> i32 {
    let shift = 32 - bits;
    match coding {
        Coding::StraightBinary => (raw as i32).wrapping_sub(1 << (bits - 1)),
        Coding::TwosComplement => ((raw << shift) as i32) >> shift,
    }
}

/// The inverse of [`decode`] (used by the virtual ADC and by tests).
#[inline(always)]
pub fn encode(code: i32, bits: u32, coding: Coding) -> u32 {
    let mask = (1u32 << bits) - 1;
    match coding {
        Coding::StraightBinary => (code.wrapping_add(1 << (bits - 1)) as u32) & mask,
        Coding::TwosComplement => (code as u32) & mask,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testspi::MockSpi;

    #[test]
    fn codings() {
        assert_eq!(decode(0x8000, 16, Coding::StraightBinary), 0);
        assert_eq!(decode(0x0000, 16, Coding::StraightBinary), -32768);
        assert_eq!(decode(0xFFFF, 16, Coding::StraightBinary), 32767);
        assert_eq!(decode(0xFFFF, 16, Coding::TwosComplement), -1);
        assert_eq!(decode(0x20000, 18, Coding::TwosComplement), -131072);
        for c in [-131072, -1, 0, 1, 131071] {
            for coding in [Coding::StraightBinary, Coding::TwosComplement] {
                assert_eq!(decode(encode(c, 18, coding), 18, coding), c);
            }
        }
    }

    #[test]
    fn reads_16_and_18_bits_over_spi() {
        let mut adc: Ad4000<_, part::Ad4000> =
            Ad4000::new(MockSpi::answering(&[0x7F, 0xFE]), CFG_TURBO);
        assert_eq!(adc.read_code().unwrap(), 0x7FFE - 0x8000);
        let spi = adc.release();
        assert_eq!(spi.sent, [0xFF, 0xFF]);

        // 18 bits MSB first, left-aligned in 3 bytes: 0x2_0001 → -131071.
        let raw: u32 = 0x2_0001 << 6;
        let bytes = [(raw >> 16) as u8, (raw >> 8) as u8, raw as u8];
        let mut adc: Ad4000<_, part::Ad4003> = Ad4000::new(MockSpi::answering(&bytes), CFG_TURBO);
        assert_eq!(adc.read_code().unwrap(), -131071);
    }

    #[test]
    fn register_access() {
        let mut adc: Ad4000<_, part::Ad4001> =
            Ad4000::new(MockSpi::answering(&[0, 0, 0x00, 0xE3]), CFG_TURBO);
        adc.configure().unwrap();
        assert_eq!(adc.read_register().unwrap(), 0xE3);
        assert_eq!(adc.release().sent, [CMD_WRITE, CFG_TURBO, CMD_READ, 0xFF]);
    }
}
