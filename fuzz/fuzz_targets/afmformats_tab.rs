//! The afmformats_tab importer (`host-sim/src/recording/import/afmformats_tab.rs`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("tab", data);
    let mut warnings = Vec::new();
    let _ = visco::recording::import::afmformats_tab::import(&path, &common::options(), &mut warnings);
});
