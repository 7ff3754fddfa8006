//! AFM Workshop force–distance CSV.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("csv", data);
    let mut warnings = Vec::new();
    let _ = visco::recording::import::workshop::import(&path, &common::options(), &mut warnings);
});
