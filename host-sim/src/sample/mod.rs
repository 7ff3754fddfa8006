//! Samples: a regular lattice of vertical spring–damper elements (the paper's section 2.1).
//!
//! Element `(i, j)` (column `i` along x, row `j` along y) sits at
//! `x = origin_x + i·pitch`, `y = origin_y + j·pitch` with rest height `h`, damping `c` and
//! stiffness `k`. Everything here is SI (m, N·s/m, N/m); the plant converts to its internal
//! units once, when it is built.
//!
//! - [`Sample::cell_phantom`]: the embedded default, a deterministic cell in the paper's ranges.
//! - [`Sample::flat`], [`Sample::from_fn`]: analytic samples for tests and experiments.
//! - [`Sample::load`] and friends ([`io`]): user samples from CSV or 16-bit PNG files.
//! - [`Sample::elements_under_tip`], [`Sample::footprint_mean`], [`Sample::first_contact_z_m`]:
//!   the geometry the experiments need to build their reference maps.

pub mod io;
pub use io::GridSpec;
mod phantom;

use std::fmt;

/// A lattice of spring–damper elements.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    nx: usize,
    ny: usize,
    pitch_m: f64,
    origin_m: [f64; 2],
    h_m: Vec<f64>,
    c_n_s_per_m: Vec<f64>,
    k_n_per_m: Vec<f64>,
}

/// Why a sample could not be built or loaded. File errors name the file and, where it applies,
/// the 1-based line (CSV) or row (PNG) and column.
#[derive(Debug)]
pub enum SampleError {
    /// The lattice or a value is not acceptable.
    Invalid(String),
    /// A file could not be read or written.
    Io {
        path: String,
        source: std::io::Error,
    },
    /// A file was read but its content is wrong.
    Parse {
        path: String,
        line: Option<usize>,
        reason: String,
    },
}

impl fmt::Display for SampleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SampleError::Invalid(reason) => write!(f, "invalid sample: {reason}"),
            SampleError::Io { path, source } => write!(f, "{path}: {source}"),
            SampleError::Parse {
                path,
                line: Some(line),
                reason,
            } => write!(f, "{path}:{line}: {reason}"),
            SampleError::Parse {
                path,
                line: None,
                reason,
            } => write!(f, "{path}: {reason}"),
        }
    }
}

impl std::error::Error for SampleError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SampleError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// One element as seen from a tip position (see [`Sample::elements_under_tip`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElementView {
    /// Linear index `j·nx + i`.
    pub index: usize,
    pub i: usize,
    pub j: usize,
    pub x_m: f64,
    pub y_m: f64,
    /// Lateral distance from the tip axis.
    pub r_m: f64,
    pub h_m: f64,
    pub c_n_s_per_m: f64,
    pub k_n_per_m: f64,
}

/// Plain mean of the element properties over a tip footprint (elements with `r < R`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FootprintMean {
    /// Number of elements in the footprint (the paper's `n` for a submerged tip).
    pub n: usize,
    pub h_m: f64,
    pub c_n_s_per_m: f64,
    pub k_n_per_m: f64,
    /// Mean sag of the sphere over the footprint's elements, `R − √(R² − r_i²)` averaged: the
    /// exact replacement of Appendix A's continuum value R/3 (a submerged tip feels
    /// `F = n·k·(δ − sag)` on a homogeneous bed).
    pub sag_m: f64,
}

impl Sample {
    /// A sample from per-element arrays in row-major order (`index = j·nx + i`).
    ///
    /// Requirements: `nx, ny ≥ 1`, finite positive pitch, finite origin, arrays of `nx·ny`
    /// finite values, `c ≥ 0`, `k ≥ 0` (a negative element would pull the tip into the sample
    /// without bound).
    pub fn new(
        nx: usize,
        ny: usize,
        pitch_m: f64,
        origin_m: [f64; 2],
        h_m: Vec<f64>,
        c_n_s_per_m: Vec<f64>,
        k_n_per_m: Vec<f64>,
    ) -> Result<Self, SampleError> {
        let bad = |s: String| Err(SampleError::Invalid(s));
        if nx == 0 || ny == 0 {
            return bad(format!("lattice {nx} × {ny} has no element"));
        }
        let n = nx
            .checked_mul(ny)
            .ok_or_else(|| SampleError::Invalid(format!("lattice {nx} × {ny} is too large")))?;
        if !(pitch_m.is_finite() && pitch_m > 0.0) {
            return bad(format!("pitch {pitch_m} m must be finite and positive"));
        }
        if !(origin_m[0].is_finite() && origin_m[1].is_finite()) {
            return bad(format!("origin {origin_m:?} m must be finite"));
        }
        for (name, v) in [("h", &h_m), ("c", &c_n_s_per_m), ("k", &k_n_per_m)] {
            if v.len() != n {
                return bad(format!(
                    "{name} has {} values, the {nx} × {ny} lattice needs {n}",
                    v.len()
                ));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return bad(format!(
                    "{name} of element (i={}, j={}) is {}",
                    i % nx,
                    i / nx,
                    v[i]
                ));
            }
        }
        for (name, v) in [("c", &c_n_s_per_m), ("k", &k_n_per_m)] {
            if let Some(i) = v.iter().position(|x| *x < 0.0) {
                return bad(format!(
                    "{name} of element (i={}, j={}) is negative ({})",
                    i % nx,
                    i / nx,
                    v[i]
                ));
            }
        }
        Ok(Sample {
            nx,
            ny,
            pitch_m,
            origin_m,
            h_m,
            c_n_s_per_m,
            k_n_per_m,
        })
    }

    /// A homogeneous flat bed: every element has the same `h`, `c`, `k`; the first element at
    /// `origin_m`.
    pub fn flat(
        nx: usize,
        ny: usize,
        pitch_m: f64,
        origin_m: [f64; 2],
        h_m: f64,
        c_n_s_per_m: f64,
        k_n_per_m: f64,
    ) -> Result<Self, SampleError> {
        let n = nx.saturating_mul(ny);
        Sample::new(
            nx,
            ny,
            pitch_m,
            origin_m,
            vec![h_m; n],
            vec![c_n_s_per_m; n],
            vec![k_n_per_m; n],
        )
    }

    /// A sample whose element at `(x, y)` (m) gets `f(x, y) = (h, c, k)`.
    pub fn from_fn(
        nx: usize,
        ny: usize,
        pitch_m: f64,
        origin_m: [f64; 2],
        mut f: impl FnMut(f64, f64) -> (f64, f64, f64),
    ) -> Result<Self, SampleError> {
        let n = nx.saturating_mul(ny);
        let (mut h, mut c, mut k) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        for j in 0..ny {
            for i in 0..nx {
                let (hh, cc, kk) = f(
                    origin_m[0] + i as f64 * pitch_m,
                    origin_m[1] + j as f64 * pitch_m,
                );
                h.push(hh);
                c.push(cc);
                k.push(kk);
            }
        }
        Sample::new(nx, ny, pitch_m, origin_m, h, c, k)
    }

    /// The embedded default cell (see `phantom.rs` for its design): 50 × 50 elements at a
    /// 100 nm pitch, element centres from 50 nm to 4950 nm, covering 0–5 µm in x and y.
    pub fn cell_phantom() -> Self {
        phantom::cell_phantom()
    }

    /// Columns (elements along x).
    pub fn nx(&self) -> usize {
        self.nx
    }
    /// Rows (elements along y).
    pub fn ny(&self) -> usize {
        self.ny
    }
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.h_m.len()
    }
    /// Never true: a sample has at least one element.
    pub fn is_empty(&self) -> bool {
        self.h_m.is_empty()
    }
    /// Distance between neighbouring elements.
    pub fn pitch_m(&self) -> f64 {
        self.pitch_m
    }
    /// Position of element (0, 0).
    pub fn origin_m(&self) -> [f64; 2] {
        self.origin_m
    }
    /// The area the lattice represents: each element owns a pitch × pitch cell centred on it,
    /// so `[x_min, x_max, y_min, y_max]` extends half a pitch beyond the outer elements.
    pub fn extent_m(&self) -> [f64; 4] {
        let p = self.pitch_m;
        [
            self.origin_m[0] - 0.5 * p,
            self.origin_m[0] + (self.nx as f64 - 0.5) * p,
            self.origin_m[1] - 0.5 * p,
            self.origin_m[1] + (self.ny as f64 - 0.5) * p,
        ]
    }
    /// Rest heights, row-major.
    pub fn h_m(&self) -> &[f64] {
        &self.h_m
    }
    /// Damping coefficients, row-major.
    pub fn c_n_s_per_m(&self) -> &[f64] {
        &self.c_n_s_per_m
    }
    /// Spring constants, row-major.
    pub fn k_n_per_m(&self) -> &[f64] {
        &self.k_n_per_m
    }
    /// Linear index of element `(i, j)`.
    pub fn index(&self, i: usize, j: usize) -> usize {
        j * self.nx + i
    }
    /// Lateral position of element `(i, j)`.
    pub fn element_xy_m(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.origin_m[0] + i as f64 * self.pitch_m,
            self.origin_m[1] + j as f64 * self.pitch_m,
        ]
    }

    /// Range of lattice columns (or rows) whose coordinate lies within `[lo, hi]`; empty when
    /// none does.
    fn index_range(origin: f64, pitch: f64, n: usize, lo: f64, hi: f64) -> std::ops::Range<usize> {
        let a = ((lo - origin) / pitch).ceil().max(0.0);
        let b = ((hi - origin) / pitch).floor();
        if !(a.is_finite() && b.is_finite()) || b < a || b < 0.0 {
            return 0..0;
        }
        let a = a as usize;
        let b = (b as usize).min(n - 1);
        if a > b {
            0..0
        } else {
            a..b + 1
        }
    }

    /// Visit every element whose lateral distance from `(x, y)` is below `radius_m`, in row-major
    /// order. Allocation-free; the plant uses it to gather its candidate elements.
    pub fn for_each_within(
        &self,
        x_m: f64,
        y_m: f64,
        radius_m: f64,
        mut f: impl FnMut(ElementView),
    ) {
        let r2max = radius_m * radius_m;
        let is = Self::index_range(
            self.origin_m[0],
            self.pitch_m,
            self.nx,
            x_m - radius_m,
            x_m + radius_m,
        );
        let js = Self::index_range(
            self.origin_m[1],
            self.pitch_m,
            self.ny,
            y_m - radius_m,
            y_m + radius_m,
        );
        for j in js {
            let ey = self.origin_m[1] + j as f64 * self.pitch_m;
            for i in is.clone() {
                let ex = self.origin_m[0] + i as f64 * self.pitch_m;
                let r2 = (ex - x_m) * (ex - x_m) + (ey - y_m) * (ey - y_m);
                if r2 < r2max {
                    let index = j * self.nx + i;
                    f(ElementView {
                        index,
                        i,
                        j,
                        x_m: ex,
                        y_m: ey,
                        r_m: r2.sqrt(),
                        h_m: self.h_m[index],
                        c_n_s_per_m: self.c_n_s_per_m[index],
                        k_n_per_m: self.k_n_per_m[index],
                    });
                }
            }
        }
    }

    /// The elements under a spherical tip of radius `tip_radius_m` whose axis is at `(x, y)`:
    /// those with lateral distance `r < R` (the second condition of the active set (7)).
    pub fn elements_under_tip(&self, x_m: f64, y_m: f64, tip_radius_m: f64) -> Vec<ElementView> {
        let mut v = Vec::new();
        self.for_each_within(x_m, y_m, tip_radius_m, |e| v.push(e));
        v
    }

    /// Plain (unweighted) mean of `h`, `c`, `k` over the elements under the tip; `None` when the
    /// footprint holds no element (tip off the lattice). This is what a fully submerged tip
    /// averages (DIVE: `k_c = k/n`, `c_c = c/n`); SVE's partial contact weights the centre more,
    /// which the experiments may want to model separately.
    pub fn footprint_mean(&self, x_m: f64, y_m: f64, tip_radius_m: f64) -> Option<FootprintMean> {
        let (mut n, mut h, mut c, mut k, mut sag) = (0usize, 0.0, 0.0, 0.0, 0.0);
        let r = tip_radius_m;
        self.for_each_within(x_m, y_m, r, |e| {
            n += 1;
            h += e.h_m;
            c += e.c_n_s_per_m;
            k += e.k_n_per_m;
            sag += r - (r * r - e.r_m * e.r_m).max(0.0).sqrt();
        });
        (n > 0).then(|| {
            let inv = 1.0 / n as f64;
            FootprintMean {
                n,
                h_m: h * inv,
                c_n_s_per_m: c * inv,
                k_n_per_m: k * inv,
                sag_m: sag * inv,
            }
        })
    }

    /// The tip-apex height at which a sphere of radius `R` at `(x, y)` first touches an element
    /// (the largest engagement height `h_i − R + √(R² − r_i²)`), or `None` off the lattice.
    /// This is the "surface" a contact detector sees: on a slope it is above the local `h`.
    pub fn first_contact_z_m(&self, x_m: f64, y_m: f64, tip_radius_m: f64) -> Option<f64> {
        let r = tip_radius_m;
        let mut best: Option<f64> = None;
        self.for_each_within(x_m, y_m, r, |e| {
            let t = e.h_m - r + (r * r - e.r_m * e.r_m).max(0.0).sqrt();
            best = Some(best.map_or(t, |b: f64| b.max(t)));
        });
        best
    }

    /// Largest rest height.
    pub fn h_max_m(&self) -> f64 {
        self.h_m.iter().copied().fold(f64::NEG_INFINITY, f64::max)
    }

    /// Largest height difference between neighbouring elements divided by the pitch, at each
    /// element (the maximum over its 4 neighbours): the slope the experiments use to tell steep
    /// topography (where Appendix B expects the largest errors) from the rest.
    pub fn slope_map(&self) -> Vec<f64> {
        let (nx, ny) = (self.nx, self.ny);
        let mut out = vec![0.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let h = self.h_m[j * nx + i];
                let mut s: f64 = 0.0;
                if i > 0 {
                    s = s.max((h - self.h_m[j * nx + i - 1]).abs());
                }
                if i + 1 < nx {
                    s = s.max((h - self.h_m[j * nx + i + 1]).abs());
                }
                if j > 0 {
                    s = s.max((h - self.h_m[(j - 1) * nx + i]).abs());
                }
                if j + 1 < ny {
                    s = s.max((h - self.h_m[(j + 1) * nx + i]).abs());
                }
                out[j * nx + i] = s / self.pitch_m;
            }
        }
        out
    }
}
