//! Gwyddion Simple Field (`.gsf`) files: one map per file, opened by Gwyddion ≥ 2.20
//! ("File → Open") and by Python's `gsffile`.
//!
//! # Layout (Gwyddion user guide, "Simple Field Files"; Gwyddion's `gsffile.c`)
//! 1. The magic line `Gwyddion Simple Field 1.0\n`.
//! 2. Header lines `Key = Value\n`, UTF-8, no NUL. We write, in this order: `XRes`, `YRes`
//!    (pixels), `XReal`, `YReal` (physical size, m), `XOffset`, `YOffset` (m), `XYUnits = m`,
//!    `ZUnits` (the map's unit in Gwyddion's syntax, see below), `Title` (the map's name), and
//!    `NoDataPixels`/`NoDataFill` when the map has NaN pixels (see below). Numbers are written
//!    in Rust's shortest round-trip form (`5e-6`), which Gwyddion's `g_ascii_strtod` reads
//!    back to the same `f64`.
//! 3. One to four NUL bytes, so that the data start at a multiple of 4 bytes: exactly
//!    `4 − (header length mod 4)` NULs, the rule of Gwyddion's own exporter (a header already
//!    a multiple of 4 long gets four).
//! 4. `XRes·YRes` IEEE-754 `f32` values, little-endian, by rows from top to bottom and in
//!    each row from left to right. The file is therefore exactly
//!    `header + padding + 4·XRes·YRes` bytes long, which Gwyddion checks.
//!
//! # Orientation
//! Gwyddion draws the first stored row at the top of the image and its y axis runs
//! downwards. We store the map's *top* row (largest y) first, so Gwyddion shows the same
//! picture as our PNG figures (y up). `XOffset`/`YOffset` are the area's corner `(x0, y0)`,
//! so the extents agree; only Gwyddion's y *reading* counts from the top edge.
//! [`read_gsf`] undoes the flip, so a round trip gives back the same map.
//!
//! # Units
//! Gwyddion parses units as whitespace-separated symbols with an optional `/`, and rejects
//! `*` and `·`. So `N·s/m` is written `N s/m`; [`read_gsf`] turns the spaces back into `·`.
//!
//! # NaN ("no data")
//! GSF has no mask, and Gwyddion's GSF loader copies values verbatim: a NaN would poison
//! every statistic and the false-colour scale there. By default ([`NanPolicy::FillMean`]) NaN
//! pixels are written as the mean of the valid pixels (what Gwyddion itself does with bad
//! pixels on import), and the header records how many there were (`NoDataPixels`) and the
//! fill value (`NoDataFill`), which Gwyddion shows under "Metadata". [`write_gsf_mask`]
//! writes the matching mask as its own `.gsf` (1 = no data) to load as a mask in Gwyddion.
//! [`NanPolicy::Keep`] writes the NaN bits unchanged (a bit-exact archive for our own
//! reader); [`NanPolicy::Fill`] writes a given value.

use std::path::Path;

use super::error::{read_all, write_atomic, OutputError, Result};
use super::map::{Grid, Map};

/// The magic line.
pub const MAGIC: &str = "Gwyddion Simple Field 1.0\n";

/// What to write for NaN pixels (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum NanPolicy {
    /// The mean of the valid pixels (0 if there is none); the count and the value go in the
    /// header. The default: what Gwyddion users expect.
    #[default]
    FillMean,
    /// This value; the count and the value go in the header.
    Fill(f64),
    /// NaN as is (Gwyddion will show a broken colour scale; our reader is fine).
    Keep,
}

/// A `.gsf` file read back: the map and every header field, in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct GsfFile {
    /// The data, bottom row first as every [`Map`]; unit from `ZUnits`, name from `Title`.
    pub map: Map,
    /// All `Key = Value` pairs of the header, trimmed, in file order.
    pub header: Vec<(String, String)>,
    /// Bytes before the data (magic + header + padding).
    pub data_offset: usize,
}

impl GsfFile {
    /// The value of a header field.
    pub fn field(&self, key: &str) -> Option<&str> {
        self.header
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// The map's unit in Gwyddion's syntax: `·`, `⋅` and `*` become spaces.
pub fn gwyddion_unit(unit: &str) -> String {
    unit.replace(['·', '⋅', '*'], " ")
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// Header text without characters a header line cannot hold (line breaks, NUL).
fn one_line(s: &str) -> String {
    s.chars()
        .map(|c| if c == '\n' || c == '\r' { ' ' } else { c })
        .filter(|&c| c != '\0')
        .collect()
}

/// Serialises `map` as a complete `.gsf` file.
pub fn gsf_bytes(map: &Map, nan: NanPolicy) -> Vec<u8> {
    let g = &map.grid;
    let nan_count = map.data.iter().filter(|v| v.is_nan()).count();
    let fill = match nan {
        NanPolicy::Keep => None,
        NanPolicy::Fill(v) => Some(v),
        NanPolicy::FillMean => {
            let s = map.stats();
            Some(if s.count > 0 { s.mean } else { 0.0 })
        }
    };
    let mut h = String::from(MAGIC);
    h += &format!("XRes = {}\n", g.nx);
    h += &format!("YRes = {}\n", g.ny);
    h += &format!("XReal = {:e}\n", g.width());
    h += &format!("YReal = {:e}\n", g.height());
    h += &format!("XOffset = {:e}\n", g.x0);
    h += &format!("YOffset = {:e}\n", g.y0);
    h += "XYUnits = m\n";
    h += &format!("ZUnits = {}\n", one_line(&gwyddion_unit(&map.unit)));
    h += &format!("Title = {}\n", one_line(&map.name));
    if nan_count > 0 {
        h += &format!("NoDataPixels = {nan_count}\n");
        if let Some(f) = fill {
            h += &format!("NoDataFill = {f:e}\n");
        }
    }
    let mut out = h.into_bytes();
    let pad = 4 - out.len() % 4;
    out.extend(std::iter::repeat_n(0u8, pad));
    out.reserve(4 * g.len());
    for j in (0..g.ny).rev() {
        for i in 0..g.nx {
            let mut v = map.get(i, j);
            if v.is_nan() {
                if let Some(f) = fill {
                    v = f;
                }
            }
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    out
}

/// Writes `map` to `path` as a Gwyddion Simple Field file, atomically (see
/// [`write_atomic`](super::error::write_atomic)). NaN pixels as `nan` says.
pub fn write_gsf(path: &Path, map: &Map, nan: NanPolicy) -> Result<()> {
    write_atomic(path, &gsf_bytes(map, nan))
}

/// Writes the no-data mask of `map` as a `.gsf`: 1 where `map` is NaN, 0 elsewhere, titled
/// `"no data: {name}"`. In Gwyddion, open it next to the data and use it as the mask
/// (Data Process → Multidata → Mask by correlation, or drag it onto the data window).
pub fn write_gsf_mask(path: &Path, map: &Map) -> Result<()> {
    let mask = Map {
        grid: map.grid,
        name: format!("no data: {}", map.name),
        unit: String::new(),
        data: map
            .data
            .iter()
            .map(|v| if v.is_nan() { 1.0 } else { 0.0 })
            .collect(),
    };
    write_gsf(path, &mask, NanPolicy::Keep)
}

/// Reads a `.gsf` file, checking it the way Gwyddion does (magic, a NUL-terminated header,
/// positive `XRes`/`YRes`, exact file size). Missing `XReal`/`YReal` default to 1 (m) and
/// missing offsets to 0, as in Gwyddion.
pub fn read_gsf(path: &Path) -> Result<GsfFile> {
    let bytes = read_all(path)?;
    parse_gsf(&bytes).map_err(|reason| OutputError::new(path, reason))
}

/// [`read_gsf`] on bytes in memory; the error is the reason alone.
pub fn parse_gsf(bytes: &[u8]) -> std::result::Result<GsfFile, String> {
    if !bytes.starts_with(MAGIC.as_bytes()) {
        return Err("not a Gwyddion Simple Field file (the first line is not \
                    `Gwyddion Simple Field 1.0`)"
            .into());
    }
    let nul = bytes[MAGIC.len()..]
        .iter()
        .position(|&b| b == 0)
        .map(|p| p + MAGIC.len())
        .ok_or("the header is truncated: no NUL byte ends it")?;
    let data_offset = nul + (4 - nul % 4);
    if bytes.len() < data_offset || bytes[nul..data_offset].iter().any(|&b| b != 0) {
        return Err(format!(
            "bad padding: bytes {nul}..{data_offset} after the header must all be NUL"
        ));
    }
    let text = std::str::from_utf8(&bytes[MAGIC.len()..nul])
        .map_err(|e| format!("the header is not UTF-8: {e}"))?;
    let mut header = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .ok_or_else(|| format!("header line {} has no `=`: {line:?}", k + 2))?;
        header.push((key.trim().to_string(), value.trim().to_string()));
    }
    let field = |key: &str| {
        header
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    };
    let res = |key: &str| -> std::result::Result<usize, String> {
        let v = field(key).ok_or_else(|| format!("the mandatory field {key} is missing"))?;
        v.parse::<usize>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| format!("{key} = {v:?} is not a positive integer"))
    };
    let real = |key: &str, default: f64| -> std::result::Result<f64, String> {
        match field(key) {
            None => Ok(default),
            Some(v) => v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{key} = {v:?} is not a finite number")),
        }
    };
    let (nx, ny) = (res("XRes")?, res("YRes")?);
    let n = nx
        .checked_mul(ny)
        .filter(|n| *n <= (usize::MAX - data_offset) / 4)
        .ok_or("XRes × YRes is too large")?;
    let expected = data_offset + 4 * n;
    if bytes.len() != expected {
        return Err(format!(
            "the file is {} bytes, but a {nx} × {ny} field after a {data_offset}-byte header \
             needs exactly {expected}",
            bytes.len()
        ));
    }
    let (xreal, yreal) = (real("XReal", 1.0)?.abs(), real("YReal", 1.0)?.abs());
    if xreal == 0.0 || yreal == 0.0 {
        return Err("XReal and YReal must not be 0".into());
    }
    let grid = Grid {
        nx,
        ny,
        x0: real("XOffset", 0.0)?,
        y0: real("YOffset", 0.0)?,
        dx: xreal / nx as f64,
        dy: yreal / ny as f64,
    };
    let unit = field("ZUnits")
        .unwrap_or("")
        .split_whitespace()
        .collect::<Vec<_>>()
        .join("·");
    let name = field("Title").unwrap_or("").to_string();
    let mut map = Map::new(grid, name, unit);
    let data = &bytes[data_offset..];
    for (r, row) in data.chunks_exact(4 * nx).enumerate() {
        let j = ny - 1 - r;
        for (i, b) in row.chunks_exact(4).enumerate() {
            map.set(i, j, f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64);
        }
    }
    Ok(GsfFile {
        map,
        header,
        data_offset,
    })
}
