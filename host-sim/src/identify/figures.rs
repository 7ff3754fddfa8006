//! The fit's figures: recorded against simulated deflection, and the residual, through the
//! output layer's line plots ([`crate::output::figure::lines`]).
//!
//! Long recordings are drawn as envelopes (the highest and lowest value in each of ~2000
//! buckets), which shows the excitation's swing without aliasing it; a detail figure shows
//! one span at the full rate.

use std::path::Path;

use super::error::Result;
use super::files::Staged;
use crate::output::figure::{self, LinePanel, LinePlot, Quantity, Series, PALETTE};

/// Highest and lowest recorded, simulated and residual D per bucket of rows.
#[derive(Debug, Clone)]
pub struct Envelope {
    rows_per_bucket: u64,
    n: u64,
    t: Vec<f64>,
    lo: Vec<[f64; 3]>,
    hi: Vec<[f64; 3]>,
}

impl Envelope {
    /// For a recording of `rows` rows, ~2000 buckets.
    pub fn new(rows: u64) -> Self {
        Self::with_max_points(rows, 2000)
    }

    /// For a recording of `rows` rows, at most `max` points per series (every row when
    /// `rows ≤ max`).
    pub fn with_max_points(rows: u64, max: u64) -> Self {
        Envelope {
            rows_per_bucket: rows.div_ceil(max.max(1)).max(1),
            n: 0,
            t: Vec::new(),
            lo: Vec::new(),
            hi: Vec::new(),
        }
    }

    /// One row: time, recorded D, simulated D.
    pub fn push(&mut self, t: f64, rec: f64, sim: f64) {
        let v = [rec, sim, rec - sim];
        if self.n % self.rows_per_bucket == 0 {
            self.t.push(t);
            self.lo.push(v);
            self.hi.push(v);
        } else if let (Some(lo), Some(hi)) = (self.lo.last_mut(), self.hi.last_mut()) {
            for q in 0..3 {
                lo[q] = lo[q].min(v[q]);
                hi[q] = hi[q].max(v[q]);
            }
        }
        self.n += 1;
    }

    fn series(&self, q: usize, hi: bool) -> Vec<(f64, f64)> {
        let src = if hi { &self.hi } else { &self.lo };
        self.t.iter().zip(src).map(|(t, v)| (*t, v[q])).collect()
    }

    /// Whether a bucket holds more than one row (then the figure shows envelopes).
    pub fn is_enveloped(&self) -> bool {
        self.rows_per_bucket > 1
    }
}

/// Stages the overview figure of the fit.
pub fn stage_overview(staged: &mut Staged, path: &Path, title: &str, env: &Envelope) -> Result<()> {
    let (rec_c, sim_c, res_c) = (PALETTE[0], PALETTE[1], PALETTE[2]);
    let panels = if env.is_enveloped() {
        vec![
            LinePanel {
                y: Quantity::new("D", "m"),
                series: vec![
                    Series::line(
                        "recorded (highest and lowest per bucket)",
                        env.series(0, true),
                    )
                    .with_color(rec_c),
                    Series::line("", env.series(0, false)).with_color(rec_c),
                    Series::dashed("simulated", env.series(1, true)).with_color(sim_c),
                    Series::dashed("", env.series(1, false)).with_color(sim_c),
                ],
                ..Default::default()
            },
            LinePanel {
                y: Quantity::new("recorded − simulated", "m"),
                series: vec![
                    Series::line("highest", env.series(2, true)).with_color(res_c),
                    Series::line("lowest", env.series(2, false)).with_color(res_c),
                ],
                ..Default::default()
            },
        ]
    } else {
        vec![
            LinePanel {
                y: Quantity::new("D", "m"),
                series: vec![
                    Series::line("recorded", env.series(0, true)).with_color(rec_c),
                    Series::dashed("simulated", env.series(1, true)).with_color(sim_c),
                ],
                ..Default::default()
            },
            LinePanel {
                y: Quantity::new("recorded − simulated", "m"),
                series: vec![Series::line("", env.series(2, true)).with_color(res_c)],
                ..Default::default()
            },
        ]
    };
    let plot = LinePlot {
        title: Some(plain(title)),
        x: Quantity::new("t", "s"),
        panels,
        ..Default::default()
    };
    staged.render(path, |tmp| figure::lines(tmp, &plot))
}

/// Stages a detail figure from full-rate rows `(t, recorded, simulated)`.
pub fn stage_detail(
    staged: &mut Staged,
    path: &Path,
    title: &str,
    rows: &[(f64, f64, f64)],
) -> Result<()> {
    let mut env = Envelope::with_max_points(rows.len() as u64, 50_000);
    for &(t, r, s) in rows {
        env.push(t, r, s);
    }
    stage_overview(staged, path, title, &env)
}

/// Text for a figure: the figures turn `_x` into a subscript, which a file name such as
/// `cell_07.csv` does not mean.
pub fn plain(text: &str) -> String {
    text.replace('_', "-")
}
