//! visco host side: simulated AFM, experiments, recordings, identify, diagnose.

pub mod identify;
pub mod plant;
pub mod recording;
pub mod sample;
