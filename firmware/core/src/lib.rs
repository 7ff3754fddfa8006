#![no_std]
#![forbid(unsafe_code)]
pub mod discretize;
pub mod real;
pub mod units;
pub use real::Real;
