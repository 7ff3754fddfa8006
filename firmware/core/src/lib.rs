//! # visco-core
//!
//! The identification core of visco: the method of Ragazzon, Gravdahl & Vagia, "Viscoelastic
//! properties of cells: modeling and identification by atomic force microscopy" (Mechatronics),
//! sample by sample, for a Cortex-M7 next to an AFM and for the host simulation alike.
//!
//! * `#![no_std]`, no heap, no `unsafe`, no board and no file format: numbers in, numbers out.
//! * Generic over the number type ([`Real`]): `f32` runs on the microcontroller, `f64` is the
//!   reference the f32 results are tested against.
//! * One per-sample entry point, [`Controller::step`]: the measured deflection D in, the next
//!   base position U (on the DAC grid), the lateral setpoints and a status word out; a finished
//!   DIVE tap or SVE pixel is collected with [`Controller::take_record`].
//!
//! The walk of one sample, module by module:
//!
//! | step | module | paper |
//! | --- | --- | --- |
//! | D → Z = U − D, prefilters 1/Λ | [`prefilter`] | (18) |
//! | w and φ | [`regressor`] | (13), (16) |
//! | θ̂ update, projection | [`estimator`] | (20)–(25) |
//! | contact height (DIVE) | [`contact`] | 4.3.1 |
//! | depth I-controller (SVE) | [`depth`] | (27)–(28) |
//! | two-tone excitation | [`excitation`] | (29) |
//! | sequencers, U, X, Y | [`controller`] | 3.1, 3.2, 5.1 |
//! | bad input, force limit, lost surface, divergence | [`guard`] | — |
//! | per-element scaling (outside the loop) | [`geometry`] | (30)–(32), App. A |
//!
//! The public API is SI; inside, lengths are nm, forces nN and time µs ([`units`]).
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Small fixed-size matrices read best with explicit index loops; the bounds are const.
#![allow(clippy::needless_range_loop)]
// `!(x > 0.0)` is true for NaN as well, which is the point wherever it is written.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

#[cfg(test)]
extern crate std;

pub mod config;
pub mod contact;
pub mod controller;
pub mod depth;
pub mod discretize;
pub mod estimator;
pub mod excitation;
pub mod fixed;
pub mod geometry;
pub mod guard;
pub mod observer;
pub mod prefilter;
pub mod real;
pub mod regressor;
pub mod schedule;
pub mod units;

pub use config::{Cantilever, Config, ConfigError, DiveRegressor, FaultConfig, SveRegressor};
pub use controller::{
    status, Command, Controller, Mode, Phase, PixelRecord, Record, StepOut, TapRecord,
};
pub use estimator::EstimatorKind;
pub use real::Real;
