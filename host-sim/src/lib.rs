pub mod plant;
pub mod sample;
