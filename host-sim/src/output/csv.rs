//! Maps as CSV grids: a commented header, then one line per row of pixels.
//!
//! ```text
//! # visco map 1
//! # name = c (DIVE)
//! # unit = N·s/m
//! # nx = 20
//! # ny = 20
//! # x0_m = 0e0
//! # y0_m = 0e0
//! # dx_m = 2.5e-7
//! # dy_m = 2.5e-7
//! # layout = line 1 is the bottom row (y0 + dy/2), x increasing along a line; pixel centres at x0 + (i+1/2)·dx, y0 + (j+1/2)·dy
//! # nodata = nan
//! 5.12e-7,5.3e-7,...
//! ```
//!
//! - The header lines start with `# ` and hold `key = value`; `name` and `unit` are UTF-8.
//!   `(x0_m, y0_m)` is the lower-left *corner* of the area (see [`Map`]'s conventions), the
//!   pixel size is `dx_m × dy_m`.
//! - Data lines: `ny` lines of `nx` comma-separated values, the *bottom* row (smallest y)
//!   first — the order of [`Map::data`], so `numpy.loadtxt(f, delimiter=",")` gives
//!   `a[j, i]` and `imshow(a, origin="lower")` shows it the right way up.
//! - Values in SI units, in Rust's shortest round-trip exponent form (`5.12e-7`), so reading
//!   them back gives the very same `f64`.
//! - No data (NaN) is written `nan`, which numpy, pandas and R read as NaN. The reader also
//!   takes an empty field as NaN.

use std::path::Path;

use super::error::{read_all, write_atomic, OutputError, Result};
use super::map::{Grid, Map};

/// The first line of every map CSV.
pub const CSV_MAGIC: &str = "# visco map 1";

/// Serialises `map` as CSV text (see the module docs).
pub fn csv_string(map: &Map) -> String {
    let g = &map.grid;
    let one_line = |s: &str| s.replace(['\n', '\r'], " ");
    let mut s = String::with_capacity(64 + g.len() * 14);
    s += CSV_MAGIC;
    s += "\n";
    s += &format!("# name = {}\n", one_line(&map.name));
    s += &format!("# unit = {}\n", one_line(&map.unit));
    s += &format!("# nx = {}\n# ny = {}\n", g.nx, g.ny);
    s += &format!("# x0_m = {:e}\n# y0_m = {:e}\n", g.x0, g.y0);
    s += &format!("# dx_m = {:e}\n# dy_m = {:e}\n", g.dx, g.dy);
    s += "# layout = line 1 is the bottom row (y0 + dy/2), x increasing along a line; \
          pixel centres at x0 + (i+1/2)·dx, y0 + (j+1/2)·dy\n";
    s += "# nodata = nan\n";
    for j in 0..g.ny {
        for i in 0..g.nx {
            if i > 0 {
                s.push(',');
            }
            let v = map.get(i, j);
            if v.is_nan() {
                s += "nan";
            } else {
                s += &format!("{v:e}");
            }
        }
        s.push('\n');
    }
    s
}

/// Writes `map` to `path` as a CSV grid, atomically.
pub fn write_csv(path: &Path, map: &Map) -> Result<()> {
    write_atomic(path, csv_string(map).as_bytes())
}

/// Reads a CSV grid written by [`write_csv`] (or by hand in the same layout).
pub fn read_csv(path: &Path) -> Result<Map> {
    let bytes = read_all(path)?;
    let text = String::from_utf8(bytes).map_err(|_| OutputError::new(path, "not UTF-8 text"))?;
    parse_csv(&text).map_err(|reason| OutputError::new(path, reason))
}

/// [`read_csv`] on text in memory; the error carries the 1-based line when there is one.
pub fn parse_csv(text: &str) -> std::result::Result<Map, String> {
    let mut header: Vec<(String, String)> = Vec::new();
    let mut rows: Vec<(usize, &str)> = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if let Some(c) = line.strip_prefix('#') {
            if let Some((key, value)) = c.split_once('=') {
                header.push((key.trim().to_string(), value.trim().to_string()));
            }
        } else if !line.trim().is_empty() {
            rows.push((k + 1, line));
        }
    }
    let field = |key: &str| -> std::result::Result<&str, String> {
        header
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
            .ok_or_else(|| format!("the header line `# {key} = ...` is missing"))
    };
    let count = |key: &str| -> std::result::Result<usize, String> {
        let v = field(key)?;
        v.parse::<usize>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| format!("{key} = {v:?} is not a positive integer"))
    };
    let real = |key: &str| -> std::result::Result<f64, String> {
        let v = field(key)?;
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{key} = {v:?} is not a finite number"))
    };
    let grid = Grid {
        nx: count("nx")?,
        ny: count("ny")?,
        x0: real("x0_m")?,
        y0: real("y0_m")?,
        dx: real("dx_m")?,
        dy: real("dy_m")?,
    };
    if !(grid.dx > 0.0 && grid.dy > 0.0) {
        return Err("dx_m and dy_m must be positive".into());
    }
    if rows.len() != grid.ny {
        return Err(format!(
            "{} data lines, but ny = {} says there are {}",
            rows.len(),
            grid.ny,
            grid.ny
        ));
    }
    let name = field("name").unwrap_or("").to_string();
    let unit = field("unit").unwrap_or("").to_string();
    let mut map = Map::new(grid, name, unit);
    for (j, (line_no, line)) in rows.into_iter().enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != grid.nx {
            return Err(format!(
                "line {line_no}: {} values, but nx = {}",
                cells.len(),
                grid.nx
            ));
        }
        for (i, c) in cells.into_iter().enumerate() {
            let c = c.trim();
            let v = if c.is_empty() || c.eq_ignore_ascii_case("nan") {
                f64::NAN
            } else {
                c.parse::<f64>().map_err(|_| {
                    format!("line {line_no}, column {}: {c:?} is not a number", i + 1)
                })?
            };
            map.set(i, j, v);
        }
    }
    Ok(map)
}
