//! NT-MDT Nova text export (decimal commas).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("txt", data);
    let mut warnings = Vec::new();
    let _ = visco::recording::import::ntmdt::import(&path, &common::options(), &mut warnings);
});
