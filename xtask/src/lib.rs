//! `cargo xtask` tasks as a library, so the top-level `cargo xtask test` can call
//! [`firmware_tests`].

pub mod digest;
pub mod firmware;
pub mod firmware_report;
pub mod fuzz;
pub mod suite;
/// The host end of the firmware link (`visco::telemetry`).
pub use visco::telemetry;

pub use firmware::firmware_tests;
