//! Sample files.
//!
//! All values are SI: heights in m, damping in N·s/m, stiffness in N/m. Lines starting with
//! `#` are comments in every text format; blank lines are skipped.
//!
//! ## 1. Element table (one CSV file, `*.csv`) — what [`Sample::save_element_csv`] writes
//!
//! ```text
//! # any comment
//! x_m,y_m,h_m,c_n_s_per_m,k_n_per_m
//! 5e-08,5e-08,4.1e-09,4.2e-07,0.0048
//! 1.5e-07,5e-08,4.3e-09,4.2e-07,0.0048
//! ...
//! ```
//!
//! One row per element, in any order; the header names the five columns (in any order). The
//! lattice is inferred: the distinct x and y values must each be equally spaced with one common
//! pitch (to 10⁻⁶ of it), and every lattice site must appear exactly once. A single row or
//! column takes the pitch from the other direction; a single element cannot define a pitch and
//! is refused.
//!
//! ## 2. Grids (three files) and their manifest (`*.sample`)
//!
//! Each of h, c, k is a grid of `ny` rows by `nx` columns, either
//! - a CSV matrix: row `r` of the file (comments and blank lines skipped) is lattice row
//!   `j = r` (y increasing with the row number), column `i` of it is x index `i`; values SI; or
//! - a 16-bit (or 8-bit) grayscale PNG, image row `r` = lattice row `j = r` as for CSV, with
//!   `value = min + (max − min) · code / code_max` (`code_max` = 65535 for 16 bit).
//!
//! So a viewer that draws row 0 at the top shows the sample with y pointing down. The three
//! grids must have the same size. A manifest ties them together:
//!
//! ```text
//! # visco sample manifest; paths relative to this file
//! pitch_m = 100e-9
//! origin_x_m = 50e-9      # position of element (0, 0); default pitch/2
//! origin_y_m = 50e-9
//! h = cell_h.png
//! h_min = 0               # PNG only: the values of code 0 and of the largest code
//! h_max = 0.3e-6
//! c = cell_c.csv          # CSV grid: values as they are
//! k = cell_k.png
//! k_min = 2e-3
//! k_max = 5e-3
//! ```
//!
//! [`Sample::save_grids`] writes the PNG form of this (manifest plus three PNGs), so
//! a sample can be edited in an image editor and read back. The same scales can also come
//! from code or command-line flags via [`GridSpec`] and [`Sample::from_grid_files`].
//!
//! Every error names the file and, where it can, the 1-based line and the reason.

use super::{Sample, SampleError};
use std::collections::BTreeMap;
use std::fs;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

fn io_err(path: &Path, source: std::io::Error) -> SampleError {
    SampleError::Io {
        path: path.display().to_string(),
        source,
    }
}

fn parse_err(path: &Path, line: Option<usize>, reason: impl Into<String>) -> SampleError {
    SampleError::Parse {
        path: path.display().to_string(),
        line,
        reason: reason.into(),
    }
}

/// A coordinate for messages: nm, to 0.001 nm, without trailing zeros.
fn nm(v_m: f64) -> String {
    format!("{}", (v_m * 1e12).round() / 1e3)
}

/// Non-comment, non-blank lines with their 1-based line numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim();
        (!l.is_empty() && !l.starts_with('#')).then_some((i + 1, l))
    })
}

fn parse_f64(path: &Path, line: usize, col: usize, field: &str) -> Result<f64, SampleError> {
    let v: f64 = field.trim().parse().map_err(|_| {
        parse_err(
            path,
            Some(line),
            format!("column {col}: '{}' is not a number", field.trim()),
        )
    })?;
    if !v.is_finite() {
        return Err(parse_err(
            path,
            Some(line),
            format!("column {col}: {v} is not finite"),
        ));
    }
    Ok(v)
}

/// The scales and lattice placement of a set of grid files (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct GridSpec {
    pub pitch_m: f64,
    /// Position of element (0, 0); `None` = half a pitch from the origin, as in the paper.
    pub origin_m: Option<[f64; 2]>,
    /// `(min, max)` of h for PNG grids (m); ignored for CSV grids.
    pub h_range_m: Option<(f64, f64)>,
    /// `(min, max)` of c for PNG grids (N·s/m).
    pub c_range_n_s_per_m: Option<(f64, f64)>,
    /// `(min, max)` of k for PNG grids (N/m).
    pub k_range_n_per_m: Option<(f64, f64)>,
}

/// A grid read from one file: `ny` rows of `nx` values, row-major.
struct Grid {
    nx: usize,
    ny: usize,
    values: Vec<f64>,
}

fn read_csv_grid(path: &Path) -> Result<Grid, SampleError> {
    let text = fs::read_to_string(path).map_err(|e| io_err(path, e))?;
    let mut values = Vec::new();
    let mut nx = 0;
    let mut ny = 0;
    for (line, l) in data_lines(&text) {
        let row: Vec<f64> = l
            .split(',')
            .enumerate()
            .map(|(col, f)| parse_f64(path, line, col + 1, f))
            .collect::<Result<_, _>>()?;
        if ny == 0 {
            nx = row.len();
        } else if row.len() != nx {
            return Err(parse_err(
                path,
                Some(line),
                format!("{} values, the first row has {nx}", row.len()),
            ));
        }
        values.extend(row);
        ny += 1;
    }
    if ny == 0 {
        return Err(parse_err(path, None, "no data rows"));
    }
    Ok(Grid { nx, ny, values })
}

fn read_png_grid(path: &Path, range: Option<(f64, f64)>, what: &str) -> Result<Grid, SampleError> {
    let (lo, hi) = range.ok_or_else(|| {
        parse_err(
            path,
            None,
            format!("a PNG grid needs the range of {what} ({what}_min and {what}_max)"),
        )
    })?;
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(parse_err(
            path,
            None,
            format!("range of {what} ({lo}, {hi}) is not finite"),
        ));
    }
    let file = fs::File::open(path).map_err(|e| io_err(path, e))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    // Keep 16-bit samples as they are; expand palettes so an indexed image is an error below
    // rather than a silent misread.
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder
        .read_info()
        .map_err(|e| parse_err(path, None, format!("not a readable PNG: {e}")))?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| parse_err(path, None, "image too large"))?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| parse_err(path, None, format!("cannot decode PNG: {e}")))?;
    if info.color_type != png::ColorType::Grayscale {
        return Err(parse_err(
            path,
            None,
            format!(
                "colour type {:?}: a sample grid must be a single-channel grayscale PNG",
                info.color_type
            ),
        ));
    }
    let (nx, ny) = (info.width as usize, info.height as usize);
    let (codes, code_max): (Vec<u32>, f64) = match info.bit_depth {
        png::BitDepth::Sixteen => (
            buf[..nx * ny * 2]
                .chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]]) as u32)
                .collect(),
            65535.0,
        ),
        png::BitDepth::Eight => (buf[..nx * ny].iter().map(|&b| b as u32).collect(), 255.0),
        d => {
            return Err(parse_err(
                path,
                None,
                format!("bit depth {d:?}: use 16-bit (or 8-bit) grayscale"),
            ))
        }
    };
    let values = codes
        .into_iter()
        .map(|c| lo + (hi - lo) * c as f64 / code_max)
        .collect();
    Ok(Grid { nx, ny, values })
}

fn read_grid(path: &Path, range: Option<(f64, f64)>, what: &str) -> Result<Grid, SampleError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("csv") | Some("txt") => read_csv_grid(path),
        Some("png") => read_png_grid(path, range, what),
        _ => Err(parse_err(
            path,
            None,
            "unknown grid format: the name must end in .csv or .png",
        )),
    }
}

fn write_png16(path: &Path, nx: usize, ny: usize, codes: &[u16]) -> Result<(), SampleError> {
    let file = fs::File::create(path).map_err(|e| io_err(path, e))?;
    let (w, h) = (
        u32::try_from(nx).map_err(|_| parse_err(path, None, "too wide for PNG"))?,
        u32::try_from(ny).map_err(|_| parse_err(path, None, "too tall for PNG"))?,
    );
    let mut enc = png::Encoder::new(BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut writer = enc
        .write_header()
        .map_err(|e| parse_err(path, None, format!("cannot write PNG: {e}")))?;
    let bytes: Vec<u8> = codes.iter().flat_map(|c| c.to_be_bytes()).collect();
    writer
        .write_image_data(&bytes)
        .map_err(|e| parse_err(path, None, format!("cannot write PNG: {e}")))?;
    writer
        .finish()
        .map_err(|e| parse_err(path, None, format!("cannot write PNG: {e}")))
}

impl Sample {
    /// Load a sample file: `*.csv` is an element table, anything else a manifest (module docs).
    pub fn load(path: impl AsRef<Path>) -> Result<Sample, SampleError> {
        let path = path.as_ref();
        let is_csv = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
        if is_csv {
            Sample::from_element_csv(path)
        } else {
            Sample::from_manifest(path)
        }
    }

    /// Read an element table (format 1 of the module docs).
    pub fn from_element_csv(path: impl AsRef<Path>) -> Result<Sample, SampleError> {
        let path = path.as_ref();
        let text = fs::read_to_string(path).map_err(|e| io_err(path, e))?;
        let mut lines = data_lines(&text);
        let (hline, header) = lines
            .next()
            .ok_or_else(|| parse_err(path, None, "empty file: expected a header line"))?;
        const COLS: [&str; 5] = ["x_m", "y_m", "h_m", "c_n_s_per_m", "k_n_per_m"];
        let names: Vec<&str> = header.split(',').map(|s| s.trim()).collect();
        let mut pos = [0usize; 5];
        for (p, want) in pos.iter_mut().zip(COLS) {
            *p = names.iter().position(|n| *n == want).ok_or_else(|| {
                parse_err(
                    path,
                    Some(hline),
                    format!("header lacks column '{want}' (need {})", COLS.join(",")),
                )
            })?;
        }
        let mut rows: Vec<(usize, [f64; 5])> = Vec::new();
        for (line, l) in lines {
            let fields: Vec<&str> = l.split(',').collect();
            if fields.len() != names.len() {
                return Err(parse_err(
                    path,
                    Some(line),
                    format!("{} fields, the header has {}", fields.len(), names.len()),
                ));
            }
            let mut v = [0.0; 5];
            for (k, &p) in pos.iter().enumerate() {
                v[k] = parse_f64(path, line, p + 1, fields[p])?;
            }
            rows.push((line, v));
        }
        if rows.is_empty() {
            return Err(parse_err(path, None, "no element rows after the header"));
        }
        // Infer the lattice from the distinct coordinates.
        let distinct = |k: usize| {
            let mut v: Vec<f64> = rows.iter().map(|r| r.1[k]).collect();
            v.sort_by(f64::total_cmp);
            v.dedup();
            v
        };
        let xs = distinct(0);
        let ys = distinct(1);
        let step =
            |v: &[f64]| (v.len() > 1).then(|| (v[v.len() - 1] - v[0]) / (v.len() - 1) as f64);
        let pitch = step(&xs).or(step(&ys)).ok_or_else(|| {
            parse_err(
                path,
                None,
                "a single element cannot define the lattice pitch",
            )
        })?;
        let tol = 1e-6 * pitch;
        let (nx, ny) = (xs.len(), ys.len());
        let (x0, y0) = (xs[0], ys[0]);
        let mut h = vec![f64::NAN; nx * ny];
        let mut c = vec![0.0; nx * ny];
        let mut k = vec![0.0; nx * ny];
        for (line, v) in &rows {
            let fi = (v[0] - x0) / pitch;
            let fj = (v[1] - y0) / pitch;
            let (i, j) = (fi.round(), fj.round());
            if (fi - i).abs() * pitch > tol || (fj - j).abs() * pitch > tol {
                return Err(parse_err(
                    path,
                    Some(*line),
                    format!(
                        "({}, {}) nm is not on the lattice of pitch {} nm from ({}, {}) nm",
                        nm(v[0]),
                        nm(v[1]),
                        nm(pitch),
                        nm(x0),
                        nm(y0)
                    ),
                ));
            }
            let (i, j) = (i as usize, j as usize);
            if i >= nx || j >= ny {
                return Err(parse_err(
                    path,
                    Some(*line),
                    format!(
                        "({}, {}) nm lies outside the lattice inferred from the distinct coordinates (uneven spacing?)",
                        nm(v[0]),
                        nm(v[1])
                    ),
                ));
            }
            let idx = j * nx + i;
            if !h[idx].is_nan() {
                return Err(parse_err(
                    path,
                    Some(*line),
                    format!("element ({}, {}) nm appears twice", nm(v[0]), nm(v[1])),
                ));
            }
            h[idx] = v[2];
            c[idx] = v[3];
            k[idx] = v[4];
        }
        if let Some(idx) = h.iter().position(|v| v.is_nan()) {
            return Err(parse_err(
                path,
                None,
                format!(
                    "element at ({}, {}) nm is missing: {} rows for a {nx} × {ny} lattice",
                    nm(x0 + (idx % nx) as f64 * pitch),
                    nm(y0 + (idx / nx) as f64 * pitch),
                    rows.len()
                ),
            ));
        }
        Sample::new(nx, ny, pitch, [x0, y0], h, c, k).map_err(|e| match e {
            SampleError::Invalid(reason) => parse_err(path, None, reason),
            other => other,
        })
    }

    /// Write the element table (format 1), full precision, row-major.
    pub fn save_element_csv(&self, path: impl AsRef<Path>) -> Result<(), SampleError> {
        use std::io::Write;
        let path = path.as_ref();
        let file = fs::File::create(path).map_err(|e| io_err(path, e))?;
        let mut w = BufWriter::new(file);
        let mut write = || -> std::io::Result<()> {
            writeln!(
                w,
                "# visco sample: {} x {} elements, pitch {} m",
                self.nx, self.ny, self.pitch_m
            )?;
            writeln!(w, "x_m,y_m,h_m,c_n_s_per_m,k_n_per_m")?;
            for j in 0..self.ny {
                for i in 0..self.nx {
                    let [x, y] = self.element_xy_m(i, j);
                    let idx = self.index(i, j);
                    writeln!(
                        w,
                        "{x:e},{y:e},{:e},{:e},{:e}",
                        self.h_m[idx], self.c_n_s_per_m[idx], self.k_n_per_m[idx]
                    )?;
                }
            }
            w.flush()
        };
        write().map_err(|e| io_err(path, e))
    }

    /// Assemble a sample from three grid files (CSV or PNG, format 2 of the module docs).
    pub fn from_grid_files(
        h_path: impl AsRef<Path>,
        c_path: impl AsRef<Path>,
        k_path: impl AsRef<Path>,
        spec: &GridSpec,
    ) -> Result<Sample, SampleError> {
        let h = read_grid(h_path.as_ref(), spec.h_range_m, "h")?;
        let c = read_grid(c_path.as_ref(), spec.c_range_n_s_per_m, "c")?;
        let k = read_grid(k_path.as_ref(), spec.k_range_n_per_m, "k")?;
        for (g, p) in [(&c, c_path.as_ref()), (&k, k_path.as_ref())] {
            if (g.nx, g.ny) != (h.nx, h.ny) {
                return Err(parse_err(
                    p,
                    None,
                    format!(
                        "grid is {} × {}, the height grid {} is {} × {}",
                        g.nx,
                        g.ny,
                        h_path.as_ref().display(),
                        h.nx,
                        h.ny
                    ),
                ));
            }
        }
        let origin = spec
            .origin_m
            .unwrap_or([0.5 * spec.pitch_m, 0.5 * spec.pitch_m]);
        Sample::new(
            h.nx,
            h.ny,
            spec.pitch_m,
            origin,
            h.values,
            c.values,
            k.values,
        )
    }

    /// Read a manifest and the grids it names (format 2 of the module docs).
    pub fn from_manifest(path: impl AsRef<Path>) -> Result<Sample, SampleError> {
        let path = path.as_ref();
        let text = fs::read_to_string(path).map_err(|e| io_err(path, e))?;
        let mut kv: BTreeMap<String, (usize, String)> = BTreeMap::new();
        const KEYS: [&str; 12] = [
            "pitch_m",
            "origin_x_m",
            "origin_y_m",
            "h",
            "c",
            "k",
            "h_min",
            "h_max",
            "c_min",
            "c_max",
            "k_min",
            "k_max",
        ];
        for (line, l) in data_lines(&text) {
            let l = l.split('#').next().unwrap_or("").trim();
            let (key, value) = l.split_once('=').ok_or_else(|| {
                parse_err(
                    path,
                    Some(line),
                    format!("expected 'key = value', got '{l}'"),
                )
            })?;
            let key = key.trim();
            if !KEYS.contains(&key) {
                return Err(parse_err(
                    path,
                    Some(line),
                    format!("unknown key '{key}' (known: {})", KEYS.join(", ")),
                ));
            }
            let value = value.trim().trim_matches('"').to_string();
            if kv.insert(key.to_string(), (line, value)).is_some() {
                return Err(parse_err(path, Some(line), format!("'{key}' given twice")));
            }
        }
        let num = |key: &str| -> Result<Option<f64>, SampleError> {
            kv.get(key)
                .map(|(line, v)| {
                    v.parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| {
                            parse_err(
                                path,
                                Some(*line),
                                format!("{key}: '{v}' is not a finite number"),
                            )
                        })
                })
                .transpose()
        };
        let range = |what: &str| -> Result<Option<(f64, f64)>, SampleError> {
            match (num(&format!("{what}_min"))?, num(&format!("{what}_max"))?) {
                (Some(a), Some(b)) => Ok(Some((a, b))),
                (None, None) => Ok(None),
                _ => Err(parse_err(
                    path,
                    None,
                    format!("give both {what}_min and {what}_max, or neither"),
                )),
            }
        };
        let pitch_m = num("pitch_m")?.ok_or_else(|| parse_err(path, None, "missing 'pitch_m'"))?;
        let origin_m = match (num("origin_x_m")?, num("origin_y_m")?) {
            (Some(x), Some(y)) => Some([x, y]),
            (None, None) => None,
            _ => {
                return Err(parse_err(
                    path,
                    None,
                    "give both origin_x_m and origin_y_m, or neither",
                ))
            }
        };
        let dir = path.parent().unwrap_or(Path::new("."));
        let file = |key: &str| -> Result<PathBuf, SampleError> {
            kv.get(key).map(|(_, v)| dir.join(v)).ok_or_else(|| {
                parse_err(path, None, format!("missing '{key}' (the {key} grid file)"))
            })
        };
        let spec = GridSpec {
            pitch_m,
            origin_m,
            h_range_m: range("h")?,
            c_range_n_s_per_m: range("c")?,
            k_range_n_per_m: range("k")?,
        };
        Sample::from_grid_files(file("h")?, file("c")?, file("k")?, &spec).map_err(|e| match e {
            SampleError::Invalid(reason) => parse_err(path, None, reason),
            other => other,
        })
    }

    /// Write the sample as a manifest `<dir>/<stem>.sample` plus `<stem>_h.png`, `<stem>_c.png`,
    /// `<stem>_k.png` (16-bit, each quantity scaled over its own min..max). Returns the
    /// manifest's path. Reading it back is exact to 1/65535 of each quantity's range.
    pub fn save_grids(&self, dir: impl AsRef<Path>, stem: &str) -> Result<PathBuf, SampleError> {
        let dir = dir.as_ref();
        let mut manifest = format!(
            "# visco sample manifest: {} x {} elements\npitch_m = {:e}\norigin_x_m = {:e}\norigin_y_m = {:e}\n",
            self.nx, self.ny, self.pitch_m, self.origin_m[0], self.origin_m[1]
        );
        for (what, v) in [
            ("h", &self.h_m),
            ("c", &self.c_n_s_per_m),
            ("k", &self.k_n_per_m),
        ] {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let mut hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if hi <= lo {
                hi = lo + lo.abs().max(1e-30);
            }
            let codes: Vec<u16> = v
                .iter()
                .map(|x| ((x - lo) / (hi - lo) * 65535.0).round().clamp(0.0, 65535.0) as u16)
                .collect();
            let name = format!("{stem}_{what}.png");
            write_png16(&dir.join(&name), self.nx, self.ny, &codes)?;
            manifest += &format!("{what} = {name}\n{what}_min = {lo:e}\n{what}_max = {hi:e}\n");
        }
        let mpath = dir.join(format!("{stem}.sample"));
        fs::write(&mpath, manifest).map_err(|e| io_err(&mpath, e))?;
        Ok(mpath)
    }
}
