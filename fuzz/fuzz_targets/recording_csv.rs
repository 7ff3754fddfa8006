//! The recording CSV reader (header, then every row) on arbitrary bytes: errors, never panics.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;
use visco::recording::{RecordingReader, Row};

fuzz_target!(|data: &[u8]| {
    if let Ok(mut r) = RecordingReader::new(Path::new("fuzz.csv"), data) {
        let mut row = Row::default();
        while let Ok(true) = r.read_row(&mut row) {}
    }
});
