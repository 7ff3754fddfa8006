//! AFM Workshop maps: a zip of its CSVs (`workshop::import_zip`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("zip", data);
    let mut warnings = Vec::new();
    let _ = visco::recording::import::workshop::import_zip(&path, &common::options(), &mut warnings);
});
