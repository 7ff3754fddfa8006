//! visco host side: simulated AFM, experiments, recordings, identify, diagnose.

pub mod output;
pub mod recording;
