//! Little-endian field writer and reader over byte slices. Each call returns a `Result`
//! instead of indexing, so short buffers and short frames are errors, never panics.

/// The buffer is too short for the value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Short;

/// Writes fields one after the other.
pub struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    /// A writer at the start of `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    /// Bytes written so far.
    pub fn len(&self) -> usize {
        self.pos
    }
    /// True when nothing was written.
    pub fn is_empty(&self) -> bool {
        self.pos == 0
    }
    /// Raw bytes.
    pub fn bytes(&mut self, b: &[u8]) -> Result<(), Short> {
        let end = self.pos.checked_add(b.len()).ok_or(Short)?;
        let dst = self.buf.get_mut(self.pos..end).ok_or(Short)?;
        for (d, &s) in dst.iter_mut().zip(b) {
            *d = s;
        }
        self.pos = end;
        Ok(())
    }
    /// One byte.
    pub fn u8(&mut self, v: u8) -> Result<(), Short> {
        self.bytes(&[v])
    }
    /// `u16`, little endian.
    pub fn u16(&mut self, v: u16) -> Result<(), Short> {
        self.bytes(&v.to_le_bytes())
    }
    /// `u32`, little endian.
    pub fn u32(&mut self, v: u32) -> Result<(), Short> {
        self.bytes(&v.to_le_bytes())
    }
    /// `i32`, little endian.
    pub fn i32(&mut self, v: i32) -> Result<(), Short> {
        self.bytes(&v.to_le_bytes())
    }
    /// `f32` as its IEEE bits, so NaN payloads and signed zeros survive exactly.
    pub fn f32(&mut self, v: f32) -> Result<(), Short> {
        self.u32(v.to_bits())
    }
    /// `f64` as its IEEE bits.
    pub fn f64(&mut self, v: f64) -> Result<(), Short> {
        self.bytes(&v.to_bits().to_le_bytes())
    }
}

/// Reads fields one after the other.
pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// A reader at the start of `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }
    fn take<const N: usize>(&mut self) -> Result<[u8; N], Short> {
        let end = self.pos.checked_add(N).ok_or(Short)?;
        let src = self.buf.get(self.pos..end).ok_or(Short)?;
        let mut out = [0u8; N];
        for (d, &s) in out.iter_mut().zip(src) {
            *d = s;
        }
        self.pos = end;
        Ok(out)
    }
    /// One byte.
    pub fn u8(&mut self) -> Result<u8, Short> {
        Ok(self.take::<1>()?[0])
    }
    /// `u16`, little endian.
    pub fn u16(&mut self) -> Result<u16, Short> {
        Ok(u16::from_le_bytes(self.take()?))
    }
    /// `i16`, little endian.
    pub fn i16(&mut self) -> Result<i16, Short> {
        Ok(i16::from_le_bytes(self.take()?))
    }
    /// `u32`, little endian.
    pub fn u32(&mut self) -> Result<u32, Short> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    /// `i32`, little endian.
    pub fn i32(&mut self) -> Result<i32, Short> {
        Ok(i32::from_le_bytes(self.take()?))
    }
    /// `f32` from its IEEE bits.
    pub fn f32(&mut self) -> Result<f32, Short> {
        Ok(f32::from_bits(self.u32()?))
    }
    /// `f64` from its IEEE bits.
    pub fn f64(&mut self) -> Result<f64, Short> {
        Ok(f64::from_bits(u64::from_le_bytes(self.take()?)))
    }
}
