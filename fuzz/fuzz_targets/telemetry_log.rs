//! The firmware telemetry log decoder (COBS frames, CRC, postcard) on arbitrary bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let (_frames, stats) = visco::telemetry::decode_log(data);
    let _ = stats.is_clean();
});
