//! AD5541 (and AD5541A) 16-bit voltage-output DAC: one 16-bit word, MSB first, offset binary
//! (0x8000 = mid-scale); the output updates on the rising edge of CS (AD5541A: on LDAC,
//! which may be tied low for the same behaviour).

use embedded_hal::spi::SpiDevice;

/// An AD5541 on an SPI device.
pub struct Ad5541<S> {
    spi: S,
}

/// The DAC word for a signed code relative to mid-scale, saturated to the 16-bit range
/// (the core already clamps; saturating again makes the driver safe on its own).
#[inline(always)]
pub fn word_for(code: i32) -> u16 {
    (code.clamp(-32768, 32767) + 32768) as u16
}

impl<S: SpiDevice<u8>> Ad5541<S> {
    /// Wraps the device.
    pub fn new(spi: S) -> Self {
        Self { spi }
    }

    /// Writes a signed code relative to mid-scale; returns the word sent.
    #[inline(always)]
    pub fn write_code(&mut self, code: i32) -> Result<u16, S::Error> {
        let w = word_for(code);
        self.spi.write(&w.to_be_bytes())?;
        Ok(w)
    }

    /// The SPI device back.
    pub fn release(self) -> S {
        self.spi
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testspi::MockSpi;

    #[test]
    fn offset_binary_and_saturation() {
        assert_eq!(word_for(0), 0x8000);
        assert_eq!(word_for(-32768), 0);
        assert_eq!(word_for(32767), 0xFFFF);
        assert_eq!(word_for(i32::MAX), 0xFFFF);
        assert_eq!(word_for(i32::MIN), 0);
        let mut dac = Ad5541::new(MockSpi::answering(&[]));
        assert_eq!(dac.write_code(-2).unwrap(), 0x7FFE);
        assert_eq!(dac.release().sent, [0x7F, 0xFE]);
    }
}
