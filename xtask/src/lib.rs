//! `cargo xtask` tasks as a library, so the top-level `cargo xtask test` can call
//! [`firmware_tests`].

pub mod firmware;
pub mod suite;
/// The host end of the firmware link, shared with the `visco` crate (the same source file,
/// included here so xtask does not build the whole host simulator).
#[path = "../../host-sim/src/telemetry.rs"]
#[allow(missing_docs)]
pub mod telemetry;

pub use firmware::firmware_tests;
