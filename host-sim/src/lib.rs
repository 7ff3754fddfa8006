//! visco host side: simulated AFM, experiments, recordings, identify, diagnose.

pub mod experiment;
pub mod output;
pub mod plant;
pub mod recording;
pub mod sample;
