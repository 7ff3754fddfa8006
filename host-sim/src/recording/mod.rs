//! Recordings: the measured or simulated signals every host tool reads and writes.
//!
//! A recording is the interchange format of `shared/spec/recording.md`: typed metadata (format
//! version, mode, sampling rate, cantilever and tip), the three required signals `t_s`, `u_m`,
//! `d_m` (time, commanded base position U, deflection D; z up, D < 0 when the sample pushes the
//! tip up), the optional lateral position `x_m`/`y_m` and `tap` index, and any number of extra
//! named columns that the estimator ignores but that must survive a round trip.
//!
//! Why two APIs:
//! - [`Recording`] holds everything in memory as `Vec<f64>` columns. It is what importers
//!   produce and what small tools and tests use.
//! - [`RecordingReader`] / [`RecordingWriter`] stream row by row with bounded memory, so a
//!   60 M-row log of a long SVE scan can be checked, identified or replayed without ever being
//!   loaded whole. The in-memory path is built on the streaming one, so both enforce the same
//!   contract with the same error messages.
//!
//! Strictness: the contract is a promise to other programs, so a file that breaks it is refused
//! as a whole with a [`RecordingError`] naming file, line, reason and fix; nothing is
//! half-processed. Writing is atomic (temporary file in the target directory, renamed on
//! success), so a failed write leaves no output behind. Numbers are written in Rust's shortest
//! round-trip notation, so reading a written file gives back bit-identical `f64`s.
//!
//! Vendor files (JPK, AFM Workshop, NT-MDT, Asylum Research, Optics11) become recordings through [`import`].
#![forbid(unsafe_code)]

mod csv;
mod error;
pub mod import;

pub use csv::{format_f64, PendingFile, RecordingReader, RecordingWriter, MAX_LINE_BYTES};
pub use error::{ErrorKind, RecordingError, Result};

use std::path::Path;

/// The format version this build reads and writes (`# visco-recording: 1`).
pub const FORMAT_VERSION: u32 = 1;

/// Metadata keys with a typed meaning in the contract.
pub mod keys {
    /// Format version.
    pub const VERSION: &str = "visco-recording";
    /// `dive`, `sve` or `force-curve`.
    pub const MODE: &str = "mode";
    /// Nominal sampling rate; `t_s` still rules.
    pub const SAMPLE_RATE_HZ: &str = "sample_rate_hz";
    /// Cantilever spring constant K.
    pub const CANTILEVER_K_N_PER_M: &str = "cantilever_k_n_per_m";
    /// Cantilever damping C.
    pub const CANTILEVER_C_NS_PER_M: &str = "cantilever_c_ns_per_m";
    /// Cantilever effective mass M.
    pub const CANTILEVER_M_KG: &str = "cantilever_m_kg";
    /// First-mode resonance frequency.
    pub const CANTILEVER_F0_HZ: &str = "cantilever_f0_hz";
    /// First-mode quality factor.
    pub const CANTILEVER_Q: &str = "cantilever_q";
    /// Spherical tip radius R.
    pub const TIP_RADIUS_M: &str = "tip_radius_m";
    /// RMS noise of D.
    pub const DEFLECTION_NOISE_M: &str = "deflection_noise_m";

    /// All typed keys, in the order they are written.
    pub const TYPED: [&str; 10] = [
        VERSION,
        MODE,
        SAMPLE_RATE_HZ,
        CANTILEVER_K_N_PER_M,
        CANTILEVER_C_NS_PER_M,
        CANTILEVER_M_KG,
        CANTILEVER_F0_HZ,
        CANTILEVER_Q,
        TIP_RADIUS_M,
        DEFLECTION_NOISE_M,
    ];
}

/// Names of the columns with a meaning in the contract.
pub mod columns {
    /// Time, s, strictly increasing.
    pub const T_S: &str = "t_s";
    /// Commanded base position U, m.
    pub const U_M: &str = "u_m";
    /// Measured deflection D, m (D < 0 when the sample pushes the tip up).
    pub const D_M: &str = "d_m";
    /// Lateral tip position X, m.
    pub const X_M: &str = "x_m";
    /// Lateral tip position Y, m.
    pub const Y_M: &str = "y_m";
    /// Tap index (non-negative integer).
    pub const TAP: &str = "tap";
    /// All standard columns, in the order they are written.
    pub const STANDARD: [&str; 6] = [T_S, U_M, D_M, X_M, Y_M, TAP];
}

/// What kind of experiment a recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// One or more taps at fixed X, Y.
    Dive,
    /// Scanning at depth.
    Sve,
    /// A quasi-static approach/hold/retract, as commercial AFMs record.
    ForceCurve,
}

impl Mode {
    /// The contract's spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Dive => "dive",
            Mode::Sve => "sve",
            Mode::ForceCurve => "force-curve",
        }
    }

    /// Parses the contract's spelling (exact, lower case).
    pub fn parse(s: &str) -> Option<Mode> {
        match s {
            "dive" => Some(Mode::Dive),
            "sve" => Some(Mode::Sve),
            "force-curve" => Some(Mode::ForceCurve),
            _ => None,
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The `# key: value` lines of a recording.
///
/// The typed fields are those the contract gives a meaning to; everything else is kept in
/// `extra`, in file order, and written back unchanged.
#[derive(Debug, Clone, PartialEq)]
pub struct Metadata {
    /// Format version; always [`FORMAT_VERSION`] for a value that was read or will be written.
    pub version: u32,
    /// Experiment kind.
    pub mode: Mode,
    /// Nominal sampling rate, Hz (> 0).
    pub sample_rate_hz: f64,
    /// Cantilever spring constant K, N/m (> 0).
    pub cantilever_k_n_per_m: f64,
    /// Cantilever damping C, N·s/m (≥ 0), if known.
    pub cantilever_c_ns_per_m: Option<f64>,
    /// Cantilever effective mass M, kg (> 0), if known.
    pub cantilever_m_kg: Option<f64>,
    /// First-mode resonance frequency, Hz (> 0), if known.
    pub cantilever_f0_hz: Option<f64>,
    /// First-mode quality factor (> 0), if known.
    pub cantilever_q: Option<f64>,
    /// Spherical tip radius R, m (> 0).
    pub tip_radius_m: f64,
    /// RMS noise of D, m (≥ 0), if known.
    pub deflection_noise_m: Option<f64>,
    /// All other keys, in order, passed through untouched.
    pub extra: Vec<(String, String)>,
}

impl Metadata {
    /// Metadata with the required values and nothing optional.
    pub fn new(mode: Mode, sample_rate_hz: f64, k_n_per_m: f64, tip_radius_m: f64) -> Self {
        Metadata {
            version: FORMAT_VERSION,
            mode,
            sample_rate_hz,
            cantilever_k_n_per_m: k_n_per_m,
            cantilever_c_ns_per_m: None,
            cantilever_m_kg: None,
            cantilever_f0_hz: None,
            cantilever_q: None,
            tip_radius_m,
            deflection_noise_m: None,
            extra: Vec::new(),
        }
    }

    /// The value of a pass-through key, if present.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.extra
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Sets a pass-through key, replacing an earlier value, and sanitising the value so that
    /// it can be written (line breaks become spaces, surrounding blanks are trimmed). Use this
    /// for text that comes from vendor files.
    pub fn set(&mut self, key: &str, value: impl AsRef<str>) {
        let clean: String = value
            .as_ref()
            .chars()
            .map(|c| if c == '\n' || c == '\r' { ' ' } else { c })
            .collect();
        let clean = clean.trim().to_string();
        if let Some(slot) = self.extra.iter_mut().find(|(k, _)| k == key) {
            slot.1 = clean;
        } else {
            self.extra.push((key.to_string(), clean));
        }
    }

    /// Checks the typed values' ranges and the pass-through keys' spelling. Returns the key at
    /// fault and the reason.
    pub fn check(&self) -> std::result::Result<(), (String, String)> {
        if self.version != FORMAT_VERSION {
            return Err((
                keys::VERSION.into(),
                format!(
                    "format version {} is not supported (this build handles {FORMAT_VERSION})",
                    self.version
                ),
            ));
        }
        let positive = [
            (keys::SAMPLE_RATE_HZ, Some(self.sample_rate_hz)),
            (keys::CANTILEVER_K_N_PER_M, Some(self.cantilever_k_n_per_m)),
            (keys::TIP_RADIUS_M, Some(self.tip_radius_m)),
            (keys::CANTILEVER_M_KG, self.cantilever_m_kg),
            (keys::CANTILEVER_F0_HZ, self.cantilever_f0_hz),
            (keys::CANTILEVER_Q, self.cantilever_q),
        ];
        for (key, value) in positive {
            if let Some(v) = value {
                check_range(v, false).map_err(|r| (key.to_string(), r))?;
            }
        }
        let non_negative = [
            (keys::CANTILEVER_C_NS_PER_M, self.cantilever_c_ns_per_m),
            (keys::DEFLECTION_NOISE_M, self.deflection_noise_m),
        ];
        for (key, value) in non_negative {
            if let Some(v) = value {
                check_range(v, true).map_err(|r| (key.to_string(), r))?;
            }
        }
        let mut seen: Vec<&str> = Vec::with_capacity(self.extra.len());
        for (k, v) in &self.extra {
            check_key(k).map_err(|r| (k.clone(), r))?;
            if keys::TYPED.contains(&k.as_str()) || seen.contains(&k.as_str()) {
                return Err((k.clone(), format!("key `{k}` appears twice")));
            }
            seen.push(k);
            if k.len() + v.len() + 4 > MAX_LINE_BYTES {
                return Err((
                    k.clone(),
                    format!("the value of `{k}` is too long for one line"),
                ));
            }
            if v.contains(['\n', '\r']) || v.trim() != v {
                return Err((
                    k.clone(),
                    format!("the value of `{k}` has a line break or surrounding blanks"),
                ));
            }
        }
        Ok(())
    }
}

/// Range check of a typed metadata value.
pub(crate) fn check_range(v: f64, zero_ok: bool) -> std::result::Result<(), String> {
    if !v.is_finite() {
        Err(format!("{v} is not a finite number"))
    } else if v < 0.0 || (v == 0.0 && !zero_ok) {
        Err(format!(
            "{v} is out of range (must be {})",
            if zero_ok { "≥ 0" } else { "> 0" }
        ))
    } else {
        Ok(())
    }
}

/// Spelling rules of a pass-through metadata key.
pub(crate) fn check_key(k: &str) -> std::result::Result<(), String> {
    if k.is_empty() {
        return Err("empty metadata key".into());
    }
    if k.trim() != k || k.contains([':', '\n', '\r']) {
        return Err(format!(
            "metadata key `{k}` has a colon, a line break or surrounding blanks"
        ));
    }
    Ok(())
}

/// Spelling rules of a column name.
pub(crate) fn check_column_name(name: &str) -> std::result::Result<(), String> {
    if name.is_empty() {
        return Err("empty column name".into());
    }
    if name.trim() != name || name.contains([',', '\n', '\r']) || name.starts_with('#') {
        return Err(format!(
            "column name `{name}` has a comma, a line break, surrounding blanks or a leading `#`"
        ));
    }
    Ok(())
}

/// Which columns a recording has besides the required `t_s`, `u_m`, `d_m`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Columns {
    /// `x_m` and `y_m` (always together).
    pub has_xy: bool,
    /// `tap`.
    pub has_tap: bool,
    /// Extra columns, by name, in order.
    pub extra: Vec<String>,
}

impl Columns {
    /// The header line's names, in the order they are written.
    pub fn names(&self) -> Vec<&str> {
        let mut v = vec![columns::T_S, columns::U_M, columns::D_M];
        if self.has_xy {
            v.push(columns::X_M);
            v.push(columns::Y_M);
        }
        if self.has_tap {
            v.push(columns::TAP);
        }
        v.extend(self.extra.iter().map(String::as_str));
        v
    }

    /// Number of cells per row.
    pub fn len(&self) -> usize {
        3 + 2 * usize::from(self.has_xy) + usize::from(self.has_tap) + self.extra.len()
    }

    /// Never true: `t_s`, `u_m`, `d_m` are always there.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Position of an extra column.
    pub fn extra_index(&self, name: &str) -> Option<usize> {
        self.extra.iter().position(|n| n == name)
    }

    /// Checks names: valid spelling, no duplicates, no standard name among the extras.
    pub fn check(&self) -> std::result::Result<(), String> {
        for (i, name) in self.extra.iter().enumerate() {
            check_column_name(name)?;
            if columns::STANDARD.contains(&name.as_str()) || self.extra[..i].contains(name) {
                return Err(format!("column `{name}` appears twice"));
            }
        }
        Ok(())
    }
}

/// Everything before the first data row: metadata and column layout.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// The `# key: value` lines.
    pub meta: Metadata,
    /// The columns.
    pub columns: Columns,
}

/// One sample, in the layout of its [`Columns`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Row {
    /// Time, s.
    pub t_s: f64,
    /// Commanded base position U, m.
    pub u_m: f64,
    /// Deflection D, m.
    pub d_m: f64,
    /// Lateral position X, m, when the recording has `x_m`/`y_m`.
    pub x_m: Option<f64>,
    /// Lateral position Y, m, when the recording has `x_m`/`y_m`.
    pub y_m: Option<f64>,
    /// Tap index, when the recording has `tap`.
    pub tap: Option<u32>,
    /// Extra columns, in the order of [`Columns::extra`].
    pub extra: Vec<f64>,
}

/// An extra column held in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    /// Its name in the header.
    pub name: String,
    /// One value per row.
    pub values: Vec<f64>,
}

/// A whole recording in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The metadata.
    pub meta: Metadata,
    /// Time, s, strictly increasing.
    pub t_s: Vec<f64>,
    /// Commanded base position U, m.
    pub u_m: Vec<f64>,
    /// Deflection D, m (D < 0 when the sample pushes the tip up).
    pub d_m: Vec<f64>,
    /// Lateral position X, m (present together with `y_m`).
    pub x_m: Option<Vec<f64>>,
    /// Lateral position Y, m (present together with `x_m`).
    pub y_m: Option<Vec<f64>>,
    /// Tap index.
    pub tap: Option<Vec<u32>>,
    /// Extra columns, in order.
    pub extra: Vec<Column>,
}

impl Recording {
    /// An empty recording with the given metadata and no optional columns.
    pub fn new(meta: Metadata) -> Self {
        Recording {
            meta,
            t_s: Vec::new(),
            u_m: Vec::new(),
            d_m: Vec::new(),
            x_m: None,
            y_m: None,
            tap: None,
            extra: Vec::new(),
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// True without samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// The column layout.
    pub fn columns(&self) -> Columns {
        Columns {
            has_xy: self.x_m.is_some() || self.y_m.is_some(),
            has_tap: self.tap.is_some(),
            extra: self.extra.iter().map(|c| c.name.clone()).collect(),
        }
    }

    /// Metadata and column layout.
    pub fn header(&self) -> Header {
        Header {
            meta: self.meta.clone(),
            columns: self.columns(),
        }
    }

    /// An extra column's values by name.
    pub fn extra_column(&self, name: &str) -> Option<&[f64]> {
        self.extra
            .iter()
            .find(|c| c.name == name)
            .map(|c| c.values.as_slice())
    }

    /// Row `i`, or `None` past the end or when a column is shorter than `t_s`.
    pub fn row(&self, i: usize) -> Option<Row> {
        let pick = |c: &Option<Vec<f64>>| -> Option<Option<f64>> {
            match c {
                Some(v) => v.get(i).copied().map(Some),
                None => Some(None),
            }
        };
        let mut extra = Vec::with_capacity(self.extra.len());
        for c in &self.extra {
            extra.push(*c.values.get(i)?);
        }
        Some(Row {
            t_s: *self.t_s.get(i)?,
            u_m: *self.u_m.get(i)?,
            d_m: *self.d_m.get(i)?,
            x_m: pick(&self.x_m)?,
            y_m: pick(&self.y_m)?,
            tap: match &self.tap {
                Some(v) => Some(*v.get(i)?),
                None => None,
            },
            extra,
        })
    }

    /// All rows in order (stops early if a column is shorter than `t_s`).
    pub fn rows(&self) -> impl Iterator<Item = Row> + '_ {
        (0..self.len()).map_while(|i| self.row(i))
    }

    /// Appends a row (which must match this recording's column layout).
    pub fn push_row(&mut self, row: &Row) {
        self.t_s.push(row.t_s);
        self.u_m.push(row.u_m);
        self.d_m.push(row.d_m);
        if let (Some(x), Some(v)) = (&mut self.x_m, row.x_m) {
            x.push(v);
        }
        if let (Some(y), Some(v)) = (&mut self.y_m, row.y_m) {
            y.push(v);
        }
        if let (Some(t), Some(v)) = (&mut self.tap, row.tap) {
            t.push(v);
        }
        for (c, v) in self.extra.iter_mut().zip(&row.extra) {
            c.values.push(*v);
        }
    }

    /// Reads and checks a whole recording CSV.
    pub fn read(path: &Path) -> Result<Recording> {
        let mut reader = RecordingReader::open(path)?;
        let header = reader.header().clone();
        let mut rec = Recording::new(header.meta);
        if header.columns.has_xy {
            rec.x_m = Some(Vec::new());
            rec.y_m = Some(Vec::new());
        }
        if header.columns.has_tap {
            rec.tap = Some(Vec::new());
        }
        rec.extra = header
            .columns
            .extra
            .iter()
            .map(|n| Column {
                name: n.clone(),
                values: Vec::new(),
            })
            .collect();
        let mut row = Row::default();
        while reader.read_row(&mut row)? {
            rec.push_row(&row);
        }
        Ok(rec)
    }

    /// Checks the recording against the contract and writes it atomically to `path`.
    pub fn write(&self, path: &Path) -> Result<()> {
        self.write_pending(path)?.commit()
    }

    /// Like [`Recording::write`] but stops before the final rename: the caller commits (or
    /// drops, which removes the temporary file). Used to write several files all-or-nothing.
    pub fn write_pending(&self, path: &Path) -> Result<PendingFile> {
        let lengths_ok = self.u_m.len() == self.len()
            && self.d_m.len() == self.len()
            && self.x_m.as_ref().is_none_or(|v| v.len() == self.len())
            && self.y_m.as_ref().is_none_or(|v| v.len() == self.len())
            && self.tap.as_ref().is_none_or(|v| v.len() == self.len())
            && self.extra.iter().all(|c| c.values.len() == self.len());
        if !lengths_ok {
            return Err(RecordingError::new(
                path,
                ErrorKind::Contract,
                "cannot write: the columns have different lengths",
            ));
        }
        if self.x_m.is_some() != self.y_m.is_some() {
            return Err(RecordingError::new(
                path,
                ErrorKind::Contract,
                "cannot write: x_m and y_m must be present together",
            ));
        }
        let mut writer = RecordingWriter::create(path, &self.header())?;
        for i in 0..self.len() {
            // `row` only fails on a length mismatch, excluded above.
            if let Some(row) = self.row(i) {
                writer.write_row(&row)?;
            }
        }
        writer.finish_pending()
    }
}
