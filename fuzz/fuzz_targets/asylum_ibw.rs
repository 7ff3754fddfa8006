//! The asylum_ibw importer (`host-sim/src/recording/import/igor.rs`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("ibw", data);
    let mut warnings = Vec::new();
    let _ = visco::recording::import::igor::import(&path, &common::options(), &mut warnings);
});
