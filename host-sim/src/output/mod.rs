//! The output layer: what a lab looks at and loads elsewhere.
//!
//! - [`map::Map`]: values on a regular grid over a physical area (SI, NaN = no data), with
//!   statistics, binning of scattered samples, resampling and differences.
//! - [`gsf`]: Gwyddion Simple Field files (`.gsf`), written and read.
//! - [`csv`]: maps as commented CSV grids, written and read.
//! - [`figure`]: PNG figures like the paper's Figs. 4–9 (maps with a shared colour bar, line
//!   plots in stacked panels, data with a power-law fit), drawn by a small built-in
//!   rasteriser with an embedded font, so they look the same on a machine without fonts.
//! - [`progress::Progress`]: a progress bar on a terminal, periodic lines in a log.
//!
//! Every writer replaces its file atomically (temporary file + rename), so a failure leaves
//! no partial file, and every error names the file ([`OutputError`]).

pub mod atomic;
pub mod csv;
pub mod error;
pub mod figure;
pub mod gsf;
pub mod map;
pub mod progress;

pub use error::{write_atomic, OutputError, Result};
pub use map::{Binned, Grid, Map, Stats};
