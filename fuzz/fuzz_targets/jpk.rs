//! JPK archives (zip, header and segment properties, binary channels): single curves and maps.
#![no_main]
use libfuzzer_sys::fuzz_target;
use visco::recording::import::{jpk::JpkArchive, Format};

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    for (ext, format) in [("jpk-force", Format::JpkForce), ("jpk-force-map", Format::JpkForceMap)] {
        let path = common::file_with(ext, data);
        if let Ok(mut a) = JpkArchive::open(&path, format, &common::options()) {
            let mut warnings = Vec::new();
            for c in a.curves() {
                let _ = a.read_curve(c, &mut warnings);
            }
        }
    }
});
