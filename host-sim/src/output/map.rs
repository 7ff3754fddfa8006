//! [`Map`]: a regular grid of values over a physical area, the unit every writer and figure
//! of the output layer takes.
//!
//! # Conventions
//! - Pixel `(i, j)` (column `i` along x, row `j` along y) covers
//!   `[x0 + i·dx, x0 + (i+1)·dx] × [y0 + j·dy, y0 + (j+1)·dy]`; its value stands for the
//!   pixel's centre `(x0 + (i+½)·dx, y0 + (j+½)·dy)`. So `(x0, y0)` is the lower-left
//!   *corner* of the area and the area is `nx·dx × ny·dy` (Gwyddion's `XOffset`/`XReal`
//!   convention). [`Grid::covering`] builds a grid whose pixel centres fall on given sample
//!   positions.
//! - Storage is row-major, row `j = 0` (smallest y) first: `data[j·nx + i]`.
//! - Values and extents are SI (metres, N·s/m, N/m); percent maps use the unit `%`.
//! - `NaN` means "no data" and is ignored by every statistic.

/// The geometry of a regular grid: `nx × ny` pixels of `dx × dy` metres, lower-left corner at
/// `(x0, y0)`. See the module docs for the conventions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Pixels along x (columns).
    pub nx: usize,
    /// Pixels along y (rows).
    pub ny: usize,
    /// x of the area's left edge, m.
    pub x0: f64,
    /// y of the area's bottom edge, m.
    pub y0: f64,
    /// Pixel width, m (> 0).
    pub dx: f64,
    /// Pixel height, m (> 0).
    pub dy: f64,
}

impl Grid {
    /// `nx × ny` pixels tiling the rectangle `[x_min, x_max] × [y_min, y_max]` (edges).
    pub fn over(nx: usize, ny: usize, x_min: f64, x_max: f64, y_min: f64, y_max: f64) -> Self {
        Grid {
            nx,
            ny,
            x0: x_min,
            y0: y_min,
            dx: (x_max - x_min) / nx as f64,
            dy: (y_max - y_min) / ny as f64,
        }
    }

    /// `nx × ny` pixels whose *centres* are the sample positions `x_first + i·dx` and
    /// `y_first + j·dy` (e.g. the simulator's elements, or the taps of a DIVE raster).
    pub fn covering(nx: usize, ny: usize, x_first: f64, y_first: f64, dx: f64, dy: f64) -> Self {
        Grid {
            nx,
            ny,
            x0: x_first - 0.5 * dx,
            y0: y_first - 0.5 * dy,
            dx,
            dy,
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// True when the grid has no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Width of the area, m.
    pub fn width(&self) -> f64 {
        self.nx as f64 * self.dx
    }

    /// Height of the area, m.
    pub fn height(&self) -> f64 {
        self.ny as f64 * self.dy
    }

    /// x of the right edge, m.
    pub fn x1(&self) -> f64 {
        self.x0 + self.width()
    }

    /// y of the top edge, m.
    pub fn y1(&self) -> f64 {
        self.y0 + self.height()
    }

    /// Centre of pixel `(i, j)`, m.
    pub fn centre(&self, i: usize, j: usize) -> (f64, f64) {
        (
            self.x0 + (i as f64 + 0.5) * self.dx,
            self.y0 + (j as f64 + 0.5) * self.dy,
        )
    }

    /// The pixel containing `(x, y)`; `None` outside the area (or for NaN). A point on the
    /// right or top edge belongs to the last column or row.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let fi = (x - self.x0) / self.dx;
        let fj = (y - self.y0) / self.dy;
        if !(fi >= 0.0 && fj >= 0.0 && fi <= self.nx as f64 && fj <= self.ny as f64) {
            return None;
        }
        let i = (fi as usize).min(self.nx.checked_sub(1)?);
        let j = (fj as usize).min(self.ny.checked_sub(1)?);
        Some((i, j))
    }

    /// True when both grids have the same pixel count and extents to within 1e-9 of a pixel.
    pub fn same_as(&self, other: &Grid) -> bool {
        let close = |a: f64, b: f64, d: f64| (a - b).abs() <= 1e-9 * d.abs();
        self.nx == other.nx
            && self.ny == other.ny
            && close(self.x0, other.x0, self.dx)
            && close(self.y0, other.y0, self.dy)
            && close(self.dx, other.dx, self.dx)
            && close(self.dy, other.dy, self.dy)
    }

    fn check(&self) -> Result<(), String> {
        if self.nx == 0 || self.ny == 0 {
            return Err(format!("empty grid ({} × {})", self.nx, self.ny));
        }
        for (name, v) in [("x0", self.x0), ("y0", self.y0)] {
            if !v.is_finite() {
                return Err(format!("{name} = {v} is not finite"));
            }
        }
        for (name, v) in [("dx", self.dx), ("dy", self.dy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} = {v} is not a positive finite length"));
            }
        }
        Ok(())
    }
}

/// A named map of one quantity on a [`Grid`]: values (SI, NaN = no data), a name ("h",
/// "c (DIVE)") and an SI unit ("m", "N·s/m", "N/m", "%").
#[derive(Debug, Clone, PartialEq)]
pub struct Map {
    /// Geometry.
    pub grid: Grid,
    /// What the values are, shown in titles and file headers.
    pub name: String,
    /// SI unit of the values, in the usual symbols (`m`, `N·s/m`, `N/m`, `%`, or empty).
    pub unit: String,
    /// Row-major values, row `j = 0` (smallest y) first: `data[j·nx + i]`.
    pub data: Vec<f64>,
}

/// The result of [`Map::bin`]: the mean of the samples that fell in each pixel (NaN where
/// none did) and how many did.
#[derive(Debug, Clone, PartialEq)]
pub struct Binned {
    /// Mean value per pixel, NaN for empty pixels.
    pub map: Map,
    /// Samples per pixel, same layout as `map.data`.
    pub count: Vec<u32>,
}

/// Summary statistics over the non-NaN values of a map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stats {
    /// Number of non-NaN values.
    pub count: usize,
    /// Smallest value (NaN when `count == 0`).
    pub min: f64,
    /// Largest value (NaN when `count == 0`).
    pub max: f64,
    /// Mean (NaN when `count == 0`).
    pub mean: f64,
    /// Root mean square of the values (NaN when `count == 0`).
    pub rms: f64,
    /// Largest absolute value (NaN when `count == 0`).
    pub max_abs: f64,
}

impl Map {
    /// A map of NaN ("no data yet").
    ///
    /// # Panics
    /// On an empty grid or a non-positive or non-finite pixel size: those are programming
    /// errors, not data.
    pub fn new(grid: Grid, name: impl Into<String>, unit: impl Into<String>) -> Self {
        if let Err(e) = grid.check() {
            panic!("Map::new: {e}");
        }
        Map {
            grid,
            name: name.into(),
            unit: unit.into(),
            data: vec![f64::NAN; grid.len()],
        }
    }

    /// A map from row-major values (row `j = 0` first).
    ///
    /// # Panics
    /// If `data.len() != nx·ny` or the grid is invalid (see [`Map::new`]).
    pub fn from_vec(
        grid: Grid,
        name: impl Into<String>,
        unit: impl Into<String>,
        data: Vec<f64>,
    ) -> Self {
        let mut m = Map::new(grid, name, unit);
        assert_eq!(
            data.len(),
            grid.len(),
            "Map::from_vec: {} values for a {} × {} grid",
            data.len(),
            grid.nx,
            grid.ny
        );
        m.data = data;
        m
    }

    /// A map whose pixel `(i, j)` is `f(x, y)` at the pixel's centre.
    pub fn from_fn(
        grid: Grid,
        name: impl Into<String>,
        unit: impl Into<String>,
        mut f: impl FnMut(f64, f64) -> f64,
    ) -> Self {
        let mut m = Map::new(grid, name, unit);
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let (x, y) = grid.centre(i, j);
                m.data[j * grid.nx + i] = f(x, y);
            }
        }
        m
    }

    /// Pixels along x.
    pub fn nx(&self) -> usize {
        self.grid.nx
    }

    /// Pixels along y.
    pub fn ny(&self) -> usize {
        self.grid.ny
    }

    /// Value of pixel `(i, j)`.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.data[j * self.grid.nx + i]
    }

    /// Sets pixel `(i, j)`.
    pub fn set(&mut self, i: usize, j: usize, v: f64) {
        let nx = self.grid.nx;
        self.data[j * nx + i] = v;
    }

    /// The same map under another name.
    pub fn renamed(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }

    /// Smallest and largest non-NaN values; `None` when every pixel is NaN. Infinite values
    /// count (they are data, if odd ones).
    pub fn min_max(&self) -> Option<(f64, f64)> {
        min_max(&self.data)
    }

    /// Count, min, max, mean, RMS and max |v| over the non-NaN values.
    pub fn stats(&self) -> Stats {
        let mut s = Stats {
            count: 0,
            min: f64::NAN,
            max: f64::NAN,
            mean: f64::NAN,
            rms: f64::NAN,
            max_abs: f64::NAN,
        };
        let (mut sum, mut sum2) = (0.0, 0.0);
        for &v in self.data.iter().filter(|v| !v.is_nan()) {
            if s.count == 0 {
                s.min = v;
                s.max = v;
                s.max_abs = v.abs();
            }
            s.count += 1;
            s.min = s.min.min(v);
            s.max = s.max.max(v);
            s.max_abs = s.max_abs.max(v.abs());
            sum += v;
            sum2 += v * v;
        }
        if s.count > 0 {
            s.mean = sum / s.count as f64;
            s.rms = (sum2 / s.count as f64).sqrt();
        }
        s
    }

    /// Bins scattered samples `(x, y, value)` (m, m, SI) onto `grid`: each pixel gets the mean
    /// of the samples inside it, NaN if none. Samples outside the grid, and samples whose
    /// value is NaN, are dropped. Used to resample SVE lines (many samples per pixel) onto
    /// the 50 × 20 image, or DIVE taps onto their raster.
    pub fn bin(
        grid: Grid,
        name: impl Into<String>,
        unit: impl Into<String>,
        samples: impl IntoIterator<Item = (f64, f64, f64)>,
    ) -> Binned {
        let mut map = Map::new(grid, name, unit);
        let mut sum = vec![0.0f64; grid.len()];
        let mut count = vec![0u32; grid.len()];
        for (x, y, v) in samples {
            if v.is_nan() {
                continue;
            }
            if let Some((i, j)) = grid.cell_of(x, y) {
                sum[j * grid.nx + i] += v;
                count[j * grid.nx + i] += 1;
            }
        }
        for k in 0..grid.len() {
            if count[k] > 0 {
                map.data[k] = sum[k] / count[k] as f64;
            }
        }
        Binned { map, count }
    }

    /// `self − other`, pixel by pixel, named `"{self} − {other}"`, with `self`'s unit.
    /// NaN wherever either is NaN.
    ///
    /// # Errors
    /// When the grids differ (resample one first with [`Map::resample_mean`] or
    /// [`Map::resample_bilinear`]) or the units differ.
    pub fn difference(&self, other: &Map) -> Result<Map, String> {
        if !self.grid.same_as(&other.grid) {
            return Err(format!(
                "cannot subtract `{}` ({} × {}) from `{}` ({} × {}): the grids differ",
                other.name, other.grid.nx, other.grid.ny, self.name, self.grid.nx, self.grid.ny
            ));
        }
        if self.unit != other.unit {
            return Err(format!(
                "cannot subtract `{}` ({}) from `{}` ({}): the units differ",
                other.name, other.unit, self.name, self.unit
            ));
        }
        let data = self
            .data
            .iter()
            .zip(&other.data)
            .map(|(a, b)| a - b)
            .collect();
        Ok(Map {
            grid: self.grid,
            name: format!("{} − {}", self.name, other.name),
            unit: self.unit.clone(),
            data,
        })
    }

    /// The error of an estimate in percent of a full-scale value, as in the paper's Fig. 7:
    /// `100 · (estimate − given) / full_scale`, unit `%`. Same grid required (see
    /// [`Map::difference`]).
    pub fn error_percent(estimate: &Map, given: &Map, full_scale: f64) -> Result<Map, String> {
        let mut d = estimate.difference(given)?;
        for v in &mut d.data {
            *v *= 100.0 / full_scale;
        }
        d.unit = "%".into();
        d.name = format!("error of {}", estimate.name);
        Ok(d)
    }

    /// The value at `(x, y)` interpolated bilinearly between pixel centres (clamped to the
    /// outermost centres at the border). NaN outside the area, or where a NaN pixel takes part.
    pub fn sample_bilinear(&self, x: f64, y: f64) -> f64 {
        let g = &self.grid;
        if !(x >= g.x0 && x <= g.x1() && y >= g.y0 && y <= g.y1()) {
            return f64::NAN;
        }
        let fx = ((x - g.x0) / g.dx - 0.5).clamp(0.0, (g.nx - 1) as f64);
        let fy = ((y - g.y0) / g.dy - 0.5).clamp(0.0, (g.ny - 1) as f64);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(g.nx - 1), (j0 + 1).min(g.ny - 1));
        let (tx, ty) = (fx - i0 as f64, fy - j0 as f64);
        let v = |i, j| self.get(i, j);
        let a = v(i0, j0) * (1.0 - tx) + v(i1, j0) * tx;
        let b = v(i0, j1) * (1.0 - tx) + v(i1, j1) * tx;
        // A NaN neighbour with zero weight still poisons the product (0·NaN = NaN): intended,
        // an interpolant next to a hole is not data.
        a * (1.0 - ty) + b * ty
    }

    /// This map resampled onto `grid` by bilinear interpolation at the new pixel centres.
    pub fn resample_bilinear(&self, grid: Grid) -> Map {
        Map::from_fn(grid, self.name.clone(), self.unit.clone(), |x, y| {
            self.sample_bilinear(x, y)
        })
    }

    /// This map resampled onto `grid` by area-weighted averaging: each new pixel is the mean
    /// of the old pixels it overlaps, weighted by the overlap area, NaN pixels left out (NaN
    /// when no valid old pixel overlaps). Right for going to a coarser grid (the given 50 × 50
    /// properties onto the 20 × 20 DIVE raster) without aliasing.
    pub fn resample_mean(&self, grid: Grid) -> Map {
        let s = &self.grid;
        let mut out = Map::new(grid, self.name.clone(), self.unit.clone());
        // Overlap of [a0, a1] with the source pixels along one axis: (index, length) pairs.
        let overlaps = |a0: f64, a1: f64, o: f64, d: f64, n: usize| -> Vec<(usize, f64)> {
            let lo = ((a0 - o) / d).floor().max(0.0) as usize;
            let hi = (((a1 - o) / d).ceil().max(0.0) as usize).min(n);
            (lo..hi)
                .filter_map(|k| {
                    let c0 = o + k as f64 * d;
                    let len = (a1.min(c0 + d) - a0.max(c0)).max(0.0);
                    (len > 0.0).then_some((k, len))
                })
                .collect()
        };
        for j in 0..grid.ny {
            let ys = grid.y0 + j as f64 * grid.dy;
            let oy = overlaps(ys, ys + grid.dy, s.y0, s.dy, s.ny);
            for i in 0..grid.nx {
                let xs = grid.x0 + i as f64 * grid.dx;
                let ox = overlaps(xs, xs + grid.dx, s.x0, s.dx, s.nx);
                let (mut sum, mut w) = (0.0, 0.0);
                for &(jj, ly) in &oy {
                    for &(ii, lx) in &ox {
                        let v = self.get(ii, jj);
                        if !v.is_nan() {
                            sum += v * lx * ly;
                            w += lx * ly;
                        }
                    }
                }
                if w > 0.0 {
                    out.set(i, j, sum / w);
                }
            }
        }
        out
    }

    /// The values along the row nearest to `y` (m), as `(x, value)` pairs at pixel centres:
    /// a cross-section like the paper's Fig. 8. `None` when `y` is outside the area.
    pub fn row_at(&self, y: f64) -> Option<Vec<(f64, f64)>> {
        let (_, j) = self.grid.cell_of(self.grid.x0, y)?;
        Some(
            (0..self.grid.nx)
                .map(|i| (self.grid.centre(i, j).0, self.get(i, j)))
                .collect(),
        )
    }

    /// A boolean map (1 where `pred(value)`, 0 elsewhere, NaN where the value is NaN), e.g. a
    /// "steep" mask from a slope map, for [`crate::output::figure::MapStyle::mask`].
    pub fn threshold(&self, name: impl Into<String>, pred: impl Fn(f64) -> bool) -> Map {
        let data = self
            .data
            .iter()
            .map(|&v| {
                if v.is_nan() {
                    f64::NAN
                } else if pred(v) {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        Map {
            grid: self.grid,
            name: name.into(),
            unit: String::new(),
            data,
        }
    }

    /// The magnitude of the gradient, |∇v| (unit `{unit}/m`), by central differences
    /// (one-sided at the border). For a height map it is the slope (m/m), the quantity that
    /// decides where the tip–sample geometry spoils the estimates (paper, Appendix B).
    pub fn gradient_magnitude(&self) -> Map {
        let g = self.grid;
        let mut out = Map::new(g, format!("|∇{}|", self.name), format!("{}/m", self.unit));
        for j in 0..g.ny {
            for i in 0..g.nx {
                let (il, ir) = (i.saturating_sub(1), (i + 1).min(g.nx - 1));
                let (jb, jt) = (j.saturating_sub(1), (j + 1).min(g.ny - 1));
                let gx = if ir > il {
                    (self.get(ir, j) - self.get(il, j)) / ((ir - il) as f64 * g.dx)
                } else {
                    0.0
                };
                let gy = if jt > jb {
                    (self.get(i, jt) - self.get(i, jb)) / ((jt - jb) as f64 * g.dy)
                } else {
                    0.0
                };
                out.set(i, j, gx.hypot(gy));
            }
        }
        out
    }
}

/// Smallest and largest non-NaN values of a slice; `None` if there is none.
pub fn min_max(values: &[f64]) -> Option<(f64, f64)> {
    let mut it = values.iter().copied().filter(|v| !v.is_nan());
    let first = it.next()?;
    Some(it.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn g() -> Grid {
        Grid::over(4, 2, 0.0, 4e-6, 0.0, 2e-6)
    }

    #[test]
    fn geometry() {
        let g = g();
        assert_eq!(g.centre(0, 0), (0.5e-6, 0.5e-6));
        assert_eq!(g.cell_of(3.99e-6, 1.0e-6), Some((3, 1)));
        assert_eq!(g.cell_of(4e-6, 2e-6), Some((3, 1)));
        assert_eq!(g.cell_of(-1e-9, 0.0), None);
        assert_eq!(g.cell_of(f64::NAN, 0.0), None);
        let c = Grid::covering(50, 50, 0.05e-6, 0.05e-6, 0.1e-6, 0.1e-6);
        assert!((c.x0).abs() < 1e-20 && (c.x1() - 5e-6).abs() < 1e-18);
    }

    #[test]
    fn stats_ignore_nan() {
        let m = Map::from_vec(
            g(),
            "h",
            "m",
            vec![1.0, f64::NAN, -3.0, 2.0, 0.0, 0.0, 0.0, 0.0],
        );
        let s = m.stats();
        assert_eq!((s.count, s.min, s.max, s.max_abs), (7, -3.0, 2.0, 3.0));
        assert_eq!(m.min_max(), Some((-3.0, 2.0)));
        let empty = Map::new(g(), "x", "");
        assert_eq!(empty.min_max(), None);
        assert!(empty.stats().mean.is_nan());
    }

    #[test]
    fn binning_means_and_counts() {
        let b = Map::bin(
            g(),
            "v",
            "m",
            [
                (0.1e-6, 0.1e-6, 1.0),
                (0.9e-6, 0.9e-6, 3.0),
                (3.5e-6, 1.5e-6, 7.0),
                (9.0, 9.0, 100.0),
                (0.5e-6, 0.5e-6, f64::NAN),
            ],
        );
        assert_eq!(b.map.get(0, 0), 2.0);
        assert_eq!(b.count[0], 2);
        assert_eq!(b.map.get(3, 1), 7.0);
        assert!(b.map.get(1, 0).is_nan());
        assert_eq!(b.count.iter().sum::<u32>(), 3);
    }

    #[test]
    fn difference_needs_same_grid() {
        let a = Map::from_fn(g(), "a", "m", |x, _| x);
        let b = Map::from_fn(g(), "b", "m", |_, y| y);
        let d = a.difference(&b).unwrap();
        assert_eq!(d.get(3, 0), 3.5e-6 - 0.5e-6);
        let other = Map::new(Grid::over(2, 2, 0.0, 4e-6, 0.0, 2e-6), "c", "m");
        assert!(a.difference(&other).unwrap_err().contains("grids differ"));
        let e = Map::error_percent(&a, &b, 1e-5).unwrap();
        assert_eq!(e.unit, "%");
        assert!((e.get(3, 0) - 30.0).abs() < 1e-9);
    }

    #[test]
    fn resampling() {
        let fine = Map::from_fn(Grid::over(4, 4, 0.0, 4.0, 0.0, 4.0), "v", "", |x, y| x + y);
        let coarse = fine.resample_mean(Grid::over(2, 2, 0.0, 4.0, 0.0, 4.0));
        assert_eq!(coarse.get(0, 0), 2.0);
        assert_eq!(coarse.get(1, 1), 6.0);
        // Bilinear reproduces a linear function exactly inside.
        assert!((fine.sample_bilinear(1.3, 2.2) - 3.5).abs() < 1e-12);
        let b = fine.resample_bilinear(Grid::over(8, 8, 0.0, 4.0, 0.0, 4.0));
        assert!((b.get(3, 4) - (1.75 + 2.25)).abs() < 1e-12);
        let row = fine.row_at(2.5).unwrap();
        assert_eq!(row[0], (0.5, 3.0));
    }

    #[test]
    fn gradient_of_a_plane() {
        let m = Map::from_fn(Grid::over(5, 5, 0.0, 5.0, 0.0, 5.0), "h", "m", |x, y| {
            3.0 * x + 4.0 * y
        });
        let s = m.gradient_magnitude();
        assert!(s.data.iter().all(|v| (v - 5.0).abs() < 1e-12));
        let mask = s.threshold("steep", |v| v > 4.0);
        assert!(mask.data.iter().all(|&v| v == 1.0));
    }
}
