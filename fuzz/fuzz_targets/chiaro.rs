//! The chiaro importer (`host-sim/src/recording/import/chiaro.rs`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("txt", data);
    let mut warnings = Vec::new();
    let _ = visco::recording::import::chiaro::import(&path, &common::options(), &mut warnings);
});
