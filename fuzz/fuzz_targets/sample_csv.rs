//! A user sample: the element table CSV.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::file_with("csv", data);
    let _ = visco::sample::Sample::from_element_csv(&path);
});
