//! CRC-32/ISO-HDLC (the CRC of Ethernet, zlib and PNG): reflected polynomial 0xEDB88320,
//! initial value and final XOR 0xFFFFFFFF, check value `crc32(b"123456789") == 0xCBF4_3926`.
//!
//! Why CRC-32 and not CRC-16: a replay carries ~10⁵–10⁶ frames; with CRC-16 a random
//! corruption slips through once in 65 536 frames, which is within reach of one long run.
//! The 1 KiB table is generated at compile time; indexing it with a `u8` cannot panic.

const fn make_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

static TABLE: [u32; 256] = make_table();

/// An incremental CRC-32 computation.
#[derive(Clone, Copy, Debug)]
pub struct Crc32(u32);

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// A fresh computation.
    pub const fn new() -> Self {
        Self(0xFFFF_FFFF)
    }
    /// Feeds bytes.
    #[inline]
    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.0;
        for &b in bytes {
            // `as u8` keeps the index below 256, so the bounds check is provably dead.
            c = TABLE[((c ^ b as u32) as u8) as usize] ^ (c >> 8);
        }
        self.0 = c;
    }
    /// The CRC of everything fed so far.
    #[inline]
    pub fn finish(self) -> u32 {
        self.0 ^ 0xFFFF_FFFF
    }
}

/// The CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut c = Crc32::new();
    c.update(bytes);
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    #[test]
    fn incremental_equals_one_shot() {
        let data: [u8; 100] = core::array::from_fn(|i| (i * 7 + 3) as u8);
        let mut c = Crc32::new();
        c.update(&data[..33]);
        c.update(&data[33..]);
        assert_eq!(c.finish(), crc32(&data));
    }
}
