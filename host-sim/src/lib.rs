//! visco host side: simulated AFM, experiments, recordings, identify, diagnose.
// `!(x > 0.0)` is true for NaN as well, which is the point wherever it is written.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod diagnose;
pub mod experiment;
pub mod identify;
pub mod numerics;
pub mod output;
pub mod plant;
pub mod recording;
pub mod replay;
pub mod report;
pub mod sample;
pub mod telemetry;
