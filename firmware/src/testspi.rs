//! A recording `SpiDevice` for host tests of the drivers.

use embedded_hal::spi::{ErrorType, Operation, SpiDevice};
use std::vec::Vec;

/// Answers reads from a script and records every byte written.
pub struct MockSpi {
    answers: Vec<u8>,
    next: usize,
    pub sent: Vec<u8>,
}

impl MockSpi {
    pub fn answering(bytes: &[u8]) -> Self {
        Self {
            answers: bytes.to_vec(),
            next: 0,
            sent: Vec::new(),
        }
    }
    fn answer(&mut self) -> u8 {
        let b = self.answers.get(self.next).copied().unwrap_or(0);
        self.next += 1;
        b
    }
}

impl ErrorType for MockSpi {
    type Error = core::convert::Infallible;
}

impl SpiDevice<u8> for MockSpi {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), Self::Error> {
        for op in ops {
            match op {
                Operation::Read(r) => {
                    for b in r.iter_mut() {
                        self.sent.push(0);
                        *b = self.answer();
                    }
                }
                Operation::Write(w) => {
                    for &b in w.iter() {
                        self.sent.push(b);
                        self.answer();
                    }
                }
                Operation::Transfer(r, w) => {
                    for (i, b) in r.iter_mut().enumerate() {
                        self.sent.push(w.get(i).copied().unwrap_or(0));
                        *b = self.answer();
                    }
                }
                Operation::TransferInPlace(rw) => {
                    for b in rw.iter_mut() {
                        self.sent.push(*b);
                        *b = self.answer();
                    }
                }
                Operation::DelayNs(_) => {}
            }
        }
        Ok(())
    }
}
