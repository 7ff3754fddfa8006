//! The recording CSV, streamed: a reader that yields checked rows one at a time and a writer
//! that checks each row before it goes out and only publishes the file once it is complete.
//!
//! Memory stays bounded by one line (at most [`MAX_LINE_BYTES`]) plus the header, whatever the
//! number of rows, so the same code serves a 4000-point force curve and a 60 M-row scan.
//!
//! The rules enforced here are those of `recording.md`, and they are enforced identically on
//! both sides: a writer cannot produce a file the reader would refuse.
//! - metadata lines `# key: value` first; `visco-recording: 1`, `mode`, `sample_rate_hz`,
//!   `cantilever_k_n_per_m` and `tip_radius_m` required; unknown keys kept in order;
//! - then one header line naming the columns, in any order, each once; `t_s`, `u_m`, `d_m`
//!   required, `x_m`/`y_m` together (and required for `sve`, and for `dive` files whose `tap`
//!   changes), `tap` a non-negative integer;
//! - then at least one row, each with exactly one cell per column, every cell a finite number
//!   with `.` as the decimal point, `t_s` strictly increasing;
//! - UTF-8; `\r\n` line ends are accepted (files pass through Windows tools), blank lines are
//!   not.

use crate::output::atomic;
use std::fmt::Write as _;
use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::error::{ErrorKind, RecordingError, Result};
use super::{check_column_name, check_key, check_range, columns, keys};
use super::{Columns, Header, Metadata, Mode, Row, FORMAT_VERSION};

/// Longest line accepted on read, in bytes. A real row is well under 1 kB; the bound keeps a
/// corrupt or hostile file from exhausting memory.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// Formats a number so that parsing it gives back the identical `f64`.
///
/// Rust's `Display` and `LowerExp` both print the shortest digit string that round-trips;
/// plain notation is used for magnitudes a person reads easily, exponent notation otherwise
/// (so 2.5e-7 m stays short instead of growing zeros).
pub fn format_f64(v: f64, out: &mut String) {
    let a = v.abs();
    // Writing into a String cannot fail.
    let _ = if a == 0.0 || (1e-3..1e7).contains(&a) {
        write!(out, "{v}")
    } else {
        write!(out, "{v:e}")
    };
}

/// Parses one numeric cell strictly: a finite number with `.` as decimal point.
fn parse_number(cell: &str) -> std::result::Result<f64, String> {
    let s = cell.trim_matches(' ');
    match s.parse::<f64>() {
        Ok(v) if v.is_nan() => Err("NaN is not allowed".into()),
        Ok(v) if v.is_infinite() => Err(format!("`{s}` is not a finite number")),
        Ok(v) => Ok(v),
        Err(_) if s.is_empty() => Err("empty cell".into()),
        Err(_) => Err(format!("`{s}` is not a number")),
    }
}

/// Parses a `tap` cell: a non-negative integer.
fn parse_tap(cell: &str) -> std::result::Result<u32, String> {
    let s = cell.trim_matches(' ');
    s.parse::<u32>()
        .map_err(|_| format!("tap `{s}` is not a non-negative integer"))
}

/// Where a cell of the file goes.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Slot {
    T,
    U,
    D,
    X,
    Y,
    Tap,
    Extra(usize),
}

/// Reads a line of at most [`MAX_LINE_BYTES`] into `buf` (without the line end). Returns
/// `Ok(false)` at end of input.
fn read_bounded_line<R: BufRead>(input: &mut R, buf: &mut Vec<u8>) -> io::Result<bool> {
    buf.clear();
    let mut any = false;
    loop {
        let chunk = input.fill_buf()?;
        if chunk.is_empty() {
            break;
        }
        any = true;
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        let room = MAX_LINE_BYTES.saturating_sub(buf.len());
        if take > room + 1 {
            return Err(io::Error::new(io::ErrorKind::InvalidData, "line too long"));
        }
        buf.extend_from_slice(&chunk[..take]);
        input.consume(take);
        if done {
            break;
        }
    }
    if buf.last() == Some(&b'\n') {
        buf.pop();
    }
    if buf.last() == Some(&b'\r') {
        buf.pop();
    }
    Ok(any)
}

/// Streams the rows of a recording CSV after checking its header.
///
/// ```no_run
/// # use visco::recording::{RecordingReader, Row};
/// let mut reader = RecordingReader::open("cell.csv".as_ref())?;
/// let k = reader.header().meta.cantilever_k_n_per_m;
/// let mut row = Row::default();
/// while reader.read_row(&mut row)? {
///     let _force_n = -k * row.d_m;
/// }
/// # Ok::<(), visco::recording::RecordingError>(())
/// ```
pub struct RecordingReader<R> {
    path: PathBuf,
    input: R,
    header: Header,
    slots: Vec<Slot>,
    line_no: u64,
    raw: Vec<u8>,
    prev_t: Option<f64>,
    first_tap: Option<u32>,
    rows: u64,
    finished: bool,
}

impl RecordingReader<BufReader<File>> {
    /// Opens a file and reads its header.
    pub fn open(path: &Path) -> Result<Self> {
        let file = File::open(path).map_err(|e| RecordingError::io(path, "cannot open", &e))?;
        Self::new(path, BufReader::with_capacity(1 << 16, file))
    }
}

impl<R: BufRead> RecordingReader<R> {
    /// Reads the header from any buffered input; `path` is only used in messages.
    pub fn new(path: &Path, mut input: R) -> Result<Self> {
        let mut raw = Vec::new();
        let mut line_no = 0u64;
        let mut meta_lines: Vec<(u64, String, String)> = Vec::new();
        let header_line: String;
        loop {
            let got = read_bounded_line(&mut input, &mut raw)
                .map_err(|e| line_error(path, line_no + 1, &e))?;
            line_no += 1;
            if !got {
                return Err(if line_no == 1 {
                    RecordingError::contract(path, 1, "empty file").with_fix(
                        "a recording starts with `# visco-recording: 1` and the other metadata lines",
                    )
                } else {
                    RecordingError::contract(path, line_no, "no header line after the metadata")
                        .with_fix("add the column names, e.g. `t_s,u_m,d_m`, then the rows")
                });
            }
            let text = utf8(path, line_no, &raw)?;
            if let Some(rest) = text.strip_prefix('#') {
                let Some((k, v)) = rest.split_once(':') else {
                    return Err(RecordingError::contract(
                        path,
                        line_no,
                        format!("metadata line `{text}` has no `:`"),
                    )
                    .with_fix("write metadata as `# key: value`"));
                };
                let (k, v) = (k.trim(), v.trim());
                if let Err(reason) = check_key(k) {
                    return Err(RecordingError::contract(path, line_no, reason));
                }
                if meta_lines.iter().any(|(_, key, _)| key == k) {
                    return Err(RecordingError::contract(
                        path,
                        line_no,
                        format!("metadata key `{k}` appears twice"),
                    )
                    .with_fix("keep one of the two lines"));
                }
                meta_lines.push((line_no, k.to_string(), v.to_string()));
            } else if text.trim().is_empty() {
                return Err(RecordingError::contract(path, line_no, "blank line")
                    .with_fix("remove blank lines; the header line follows the metadata"));
            } else {
                header_line = text.to_string();
                break;
            }
        }
        let meta = parse_metadata(path, line_no, meta_lines)?;
        let (columns, slots) = parse_header(path, line_no, &header_line, meta.mode)?;
        Ok(RecordingReader {
            path: path.to_path_buf(),
            input,
            header: Header { meta, columns },
            slots,
            line_no,
            raw,
            prev_t: None,
            first_tap: None,
            rows: 0,
            finished: false,
        })
    }

    /// Metadata and columns.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The file named in messages.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Rows read so far.
    pub fn rows_read(&self) -> u64 {
        self.rows
    }

    /// Reads the next row into `row` (reusing its allocation). Returns `Ok(false)` at the end.
    /// After an error, further calls return `Ok(false)`.
    pub fn read_row(&mut self, row: &mut Row) -> Result<bool> {
        if self.finished {
            return Ok(false);
        }
        match self.read_row_inner(row) {
            Ok(true) => Ok(true),
            other => {
                self.finished = true;
                other
            }
        }
    }

    fn read_row_inner(&mut self, row: &mut Row) -> Result<bool> {
        let path = self.path.as_path();
        let line = self.line_no + 1;
        let got = read_bounded_line(&mut self.input, &mut self.raw)
            .map_err(|e| line_error(path, line, &e))?;
        self.line_no = line;
        if !got {
            if self.rows == 0 {
                return Err(
                    RecordingError::contract(path, line, "no data rows after the header")
                        .with_fix("a recording holds at least one sample"),
                );
            }
            return Ok(false);
        }
        let text = utf8(path, line, &self.raw)?;
        if text.trim().is_empty() {
            return Err(RecordingError::contract(path, line, "blank line")
                .with_fix("remove blank lines between and after the rows"));
        }
        let cells = text.split(',').count();
        if cells != self.slots.len() {
            return Err(RecordingError::contract(
                path,
                line,
                format!(
                    "expected {} cells ({}), found {cells}",
                    self.slots.len(),
                    self.header.columns.names().join(",")
                ),
            ));
        }
        let cols = &self.header.columns;
        row.x_m = None;
        row.y_m = None;
        row.tap = None;
        row.extra.clear();
        row.extra.resize(cols.extra.len(), 0.0);
        for (cell, slot) in text.split(',').zip(&self.slots) {
            if *slot == Slot::Tap {
                let tap = parse_tap(cell).map_err(|r| RecordingError::contract(path, line, r))?;
                row.tap = Some(tap);
                continue;
            }
            let v = parse_number(cell).map_err(|r| {
                RecordingError::contract(
                    path,
                    line,
                    format!("column `{}`: {r}", slot_name(cols, *slot)),
                )
            })?;
            match *slot {
                Slot::T => row.t_s = v,
                Slot::U => row.u_m = v,
                Slot::D => row.d_m = v,
                Slot::X => row.x_m = Some(v),
                Slot::Y => row.y_m = Some(v),
                Slot::Extra(i) => {
                    if let Some(e) = row.extra.get_mut(i) {
                        *e = v;
                    }
                }
                Slot::Tap => {}
            }
        }
        check_row_order(
            path,
            line,
            row,
            &mut self.prev_t,
            &mut self.first_tap,
            &self.header,
        )?;
        self.rows += 1;
        Ok(true)
    }
}

impl<R: BufRead> Iterator for RecordingReader<R> {
    type Item = Result<Row>;

    fn next(&mut self) -> Option<Result<Row>> {
        let mut row = Row::default();
        match self.read_row(&mut row) {
            Ok(true) => Some(Ok(row)),
            Ok(false) => None,
            Err(e) => Some(Err(e)),
        }
    }
}

fn slot_name(cols: &Columns, slot: Slot) -> &str {
    match slot {
        Slot::T => columns::T_S,
        Slot::U => columns::U_M,
        Slot::D => columns::D_M,
        Slot::X => columns::X_M,
        Slot::Y => columns::Y_M,
        Slot::Tap => columns::TAP,
        Slot::Extra(i) => cols.extra.get(i).map(String::as_str).unwrap_or("?"),
    }
}

/// Cross-row rules shared by reader and writer: time strictly increasing; a `dive` file whose
/// tap changes needs `x_m`/`y_m`.
fn check_row_order(
    path: &Path,
    line: u64,
    row: &Row,
    prev_t: &mut Option<f64>,
    first_tap: &mut Option<u32>,
    header: &Header,
) -> Result<()> {
    if let Some(prev) = *prev_t {
        if row.t_s <= prev {
            return Err(RecordingError::contract(
                path,
                line,
                format!(
                    "t_s = {} does not increase (previous row has {})",
                    row.t_s, prev
                ),
            )
            .with_fix("time must strictly increase from row to row"));
        }
    }
    *prev_t = Some(row.t_s);
    if let Some(tap) = row.tap {
        match *first_tap {
            None => *first_tap = Some(tap),
            Some(first) if first != tap && !header.columns.has_xy => {
                return Err(RecordingError::contract(
                    path,
                    line,
                    format!(
                        "tap changes from {first} to {tap} but the file has no x_m/y_m columns"
                    ),
                )
                .with_fix("a multi-tap file needs the lateral position of each tap in x_m,y_m"));
            }
            Some(_) => {}
        }
    }
    Ok(())
}

fn utf8<'a>(path: &Path, line: u64, raw: &'a [u8]) -> Result<&'a str> {
    std::str::from_utf8(raw).map_err(|_| {
        RecordingError::contract(path, line, "not UTF-8 text").with_fix("save the file as UTF-8")
    })
}

fn line_error(path: &Path, line: u64, e: &io::Error) -> RecordingError {
    if e.kind() == io::ErrorKind::InvalidData {
        RecordingError::contract(
            path,
            line,
            format!("line longer than {MAX_LINE_BYTES} bytes"),
        )
    } else {
        RecordingError::io(path, "cannot read", e).at_line(line)
    }
}

/// Turns the `# key: value` lines into typed metadata.
fn parse_metadata(
    path: &Path,
    header_line: u64,
    lines: Vec<(u64, String, String)>,
) -> Result<Metadata> {
    let find = |key: &str| lines.iter().find(|(_, k, _)| k == key);
    let missing = |key: &str, example: &str| {
        RecordingError::contract(
            path,
            header_line,
            format!("missing required metadata key `{key}` before the header"),
        )
        .with_fix(format!("add a line `# {key}: {example}` before the header"))
    };
    let number = |key: &str, zero_ok: bool| -> Result<Option<f64>> {
        let Some((line, _, v)) = find(key) else {
            return Ok(None);
        };
        let x = parse_number(v)
            .and_then(|x| check_range(x, zero_ok).map(|_| x))
            .map_err(|r| RecordingError::contract(path, *line, format!("`{key}`: {r}")))?;
        Ok(Some(x))
    };

    let Some((vline, _, version)) = find(keys::VERSION) else {
        return Err(missing(keys::VERSION, "1"));
    };
    if version != &FORMAT_VERSION.to_string() {
        return Err(RecordingError::contract(
            path,
            *vline,
            format!("unknown format version `{version}` (this build reads {FORMAT_VERSION})"),
        )
        .with_fix("write `# visco-recording: 1`, or use a newer visco"));
    }
    let Some((mline, _, mode)) = find(keys::MODE) else {
        return Err(missing(keys::MODE, "force-curve"));
    };
    let Some(mode) = Mode::parse(mode) else {
        return Err(
            RecordingError::contract(path, *mline, format!("unknown mode `{mode}`"))
                .with_fix("use one of dive, sve, force-curve"),
        );
    };
    let sample_rate_hz = number(keys::SAMPLE_RATE_HZ, false)?
        .ok_or_else(|| missing(keys::SAMPLE_RATE_HZ, "2000"))?;
    let k = number(keys::CANTILEVER_K_N_PER_M, false)?
        .ok_or_else(|| missing(keys::CANTILEVER_K_N_PER_M, "0.1"))?;
    let tip_radius_m =
        number(keys::TIP_RADIUS_M, false)?.ok_or_else(|| missing(keys::TIP_RADIUS_M, "3e-7"))?;
    let mut meta = Metadata::new(mode, sample_rate_hz, k, tip_radius_m);
    meta.cantilever_c_ns_per_m = number(keys::CANTILEVER_C_NS_PER_M, true)?;
    meta.cantilever_m_kg = number(keys::CANTILEVER_M_KG, false)?;
    meta.cantilever_f0_hz = number(keys::CANTILEVER_F0_HZ, false)?;
    meta.cantilever_q = number(keys::CANTILEVER_Q, false)?;
    meta.deflection_noise_m = number(keys::DEFLECTION_NOISE_M, true)?;
    meta.extra = lines
        .into_iter()
        .filter(|(_, k, _)| !keys::TYPED.contains(&k.as_str()))
        .map(|(_, k, v)| (k, v))
        .collect();
    Ok(meta)
}

/// Maps the header line's names to slots and checks the column rules.
fn parse_header(path: &Path, line: u64, text: &str, mode: Mode) -> Result<(Columns, Vec<Slot>)> {
    let mut cols = Columns::default();
    let mut slots = Vec::new();
    let mut seen: Vec<&str> = Vec::new();
    for raw in text.split(',') {
        let name = raw.trim_matches(' ');
        check_column_name(name).map_err(|r| RecordingError::contract(path, line, r))?;
        if seen.contains(&name) {
            return Err(RecordingError::contract(
                path,
                line,
                format!("column `{name}` appears twice in the header"),
            )
            .with_fix("give every column a distinct name"));
        }
        seen.push(name);
        slots.push(match name {
            columns::T_S => Slot::T,
            columns::U_M => Slot::U,
            columns::D_M => Slot::D,
            columns::X_M => Slot::X,
            columns::Y_M => Slot::Y,
            columns::TAP => Slot::Tap,
            other => {
                cols.extra.push(other.to_string());
                Slot::Extra(cols.extra.len() - 1)
            }
        });
    }
    for required in [columns::T_S, columns::U_M, columns::D_M] {
        if !seen.contains(&required) {
            return Err(RecordingError::contract(
                path,
                line,
                format!("missing required column `{required}` in the header `{text}`"),
            )
            .with_fix("the header needs t_s, u_m and d_m (any order)"));
        }
    }
    let has_x = seen.contains(&columns::X_M);
    let has_y = seen.contains(&columns::Y_M);
    if has_x != has_y {
        return Err(
            RecordingError::contract(path, line, "x_m and y_m must come together")
                .with_fix("add the missing lateral-position column"),
        );
    }
    if mode == Mode::Sve && !has_x {
        return Err(RecordingError::contract(
            path,
            line,
            "an `sve` recording needs the columns x_m and y_m",
        )
        .with_fix("add the lateral tip position per sample"));
    }
    cols.has_xy = has_x;
    cols.has_tap = seen.contains(&columns::TAP);
    Ok((cols, slots))
}

/// A complete output file still under its temporary name ([`crate::output::atomic`], with the
/// recording layer's errors). [`PendingFile::commit`] renames it into place; dropping it removes
/// it. Lets a command write several files all-or-nothing.
#[derive(Debug)]
pub struct PendingFile(atomic::PendingFile);

impl PendingFile {
    /// The final path.
    pub fn path(&self) -> &Path {
        self.0.path()
    }

    /// Renames the temporary file to its final name (replacing an existing file).
    pub fn commit(self) -> Result<()> {
        let path = self.0.path().to_path_buf();
        self.0.commit().map_err(|e| atomic_error(&path, e))
    }
}

fn atomic_error(path: &Path, e: atomic::AtomicError) -> RecordingError {
    match e {
        atomic::AtomicError::NoFileName => {
            RecordingError::new(path, ErrorKind::Usage, "the output path names no file")
        }
        atomic::AtomicError::NoDirectory(_) => {
            RecordingError::new(path, ErrorKind::Io, e.to_string())
        }
        atomic::AtomicError::Io(what, err) => RecordingError::io(path, what, &err),
    }
}

/// Writes a recording CSV row by row, checking every row against the contract, into a
/// temporary file next to the target that becomes the target only on [`RecordingWriter::finish`].
/// Dropped unfinished (an error, a panic elsewhere), it removes the temporary file.
pub struct RecordingWriter {
    pending: Option<PendingFile>,
    out: Option<BufWriter<File>>,
    header: Header,
    line_no: u64,
    prev_t: Option<f64>,
    first_tap: Option<u32>,
    rows: u64,
    buf: String,
}

impl RecordingWriter {
    /// Checks the header and starts the temporary file.
    pub fn create(path: &Path, header: &Header) -> Result<Self> {
        header.meta.check().map_err(|(key, reason)| {
            RecordingError::new(
                path,
                ErrorKind::Contract,
                format!("cannot write `{key}`: {reason}"),
            )
        })?;
        header.columns.check().map_err(|reason| {
            RecordingError::new(path, ErrorKind::Contract, format!("cannot write: {reason}"))
        })?;
        if header.meta.mode == Mode::Sve && !header.columns.has_xy {
            return Err(RecordingError::new(
                path,
                ErrorKind::Contract,
                "cannot write: an `sve` recording needs the columns x_m and y_m",
            ));
        }
        let (file, pending) =
            atomic::PendingFile::create(path).map_err(|e| atomic_error(path, e))?;
        let pending = PendingFile(pending);
        let mut w = RecordingWriter {
            pending: Some(pending),
            out: Some(BufWriter::with_capacity(1 << 16, file)),
            header: header.clone(),
            line_no: 0,
            prev_t: None,
            first_tap: None,
            rows: 0,
            buf: String::with_capacity(256),
        };
        w.write_header()?;
        Ok(w)
    }

    fn path(&self) -> &Path {
        self.pending
            .as_ref()
            .map(|p| p.path())
            .unwrap_or(Path::new(""))
    }

    fn write_header(&mut self) -> Result<()> {
        let m = &self.header.meta;
        let mut s = String::new();
        let num = |s: &mut String, key: &str, v: Option<f64>| {
            if let Some(v) = v {
                s.push_str("# ");
                s.push_str(key);
                s.push_str(": ");
                format_f64(v, s);
                s.push('\n');
            }
        };
        s.push_str(&format!("# {}: {}\n", keys::VERSION, m.version));
        s.push_str(&format!("# {}: {}\n", keys::MODE, m.mode));
        num(&mut s, keys::SAMPLE_RATE_HZ, Some(m.sample_rate_hz));
        num(
            &mut s,
            keys::CANTILEVER_K_N_PER_M,
            Some(m.cantilever_k_n_per_m),
        );
        num(&mut s, keys::CANTILEVER_C_NS_PER_M, m.cantilever_c_ns_per_m);
        num(&mut s, keys::CANTILEVER_M_KG, m.cantilever_m_kg);
        num(&mut s, keys::CANTILEVER_F0_HZ, m.cantilever_f0_hz);
        num(&mut s, keys::CANTILEVER_Q, m.cantilever_q);
        num(&mut s, keys::TIP_RADIUS_M, Some(m.tip_radius_m));
        num(&mut s, keys::DEFLECTION_NOISE_M, m.deflection_noise_m);
        for (k, v) in &m.extra {
            s.push_str("# ");
            s.push_str(k);
            s.push(':');
            if !v.is_empty() {
                s.push(' ');
                s.push_str(v);
            }
            s.push('\n');
        }
        s.push_str(&self.header.columns.names().join(","));
        s.push('\n');
        self.line_no = s.bytes().filter(|&b| b == b'\n').count() as u64;
        self.put(s.as_bytes())
    }

    fn put(&mut self, bytes: &[u8]) -> Result<()> {
        let res = match self.out.as_mut() {
            Some(out) => out.write_all(bytes),
            None => Ok(()),
        };
        res.map_err(|e| RecordingError::io(self.path(), "cannot write", &e))
    }

    /// Checks and writes one row. The row must have the header's layout.
    pub fn write_row(&mut self, row: &Row) -> Result<()> {
        let line = self.line_no + 1;
        let path = self.path().to_path_buf();
        let cols = &self.header.columns;
        let bad = |reason: String| {
            RecordingError::contract(&path, line, format!("cannot write: {reason}"))
        };
        if row.x_m.is_some() != cols.has_xy
            || row.y_m.is_some() != cols.has_xy
            || row.tap.is_some() != cols.has_tap
            || row.extra.len() != cols.extra.len()
        {
            return Err(bad("the row does not match the header's columns".into()));
        }
        let mut values: Vec<(&str, f64)> = vec![
            (columns::T_S, row.t_s),
            (columns::U_M, row.u_m),
            (columns::D_M, row.d_m),
        ];
        if let (Some(x), Some(y)) = (row.x_m, row.y_m) {
            values.push((columns::X_M, x));
            values.push((columns::Y_M, y));
        }
        for (name, v) in cols.extra.iter().zip(&row.extra) {
            values.push((name, *v));
        }
        for (name, v) in &values {
            if !v.is_finite() {
                return Err(bad(format!("column `{name}` is {v}, not a finite number")));
            }
        }
        check_row_order(
            &path,
            line,
            row,
            &mut self.prev_t,
            &mut self.first_tap,
            &self.header,
        )
        .map_err(|mut e| {
            e.reason = format!("cannot write: {}", e.reason);
            e
        })?;
        let mut s = std::mem::take(&mut self.buf);
        s.clear();
        format_f64(row.t_s, &mut s);
        s.push(',');
        format_f64(row.u_m, &mut s);
        s.push(',');
        format_f64(row.d_m, &mut s);
        if let (Some(x), Some(y)) = (row.x_m, row.y_m) {
            s.push(',');
            format_f64(x, &mut s);
            s.push(',');
            format_f64(y, &mut s);
        }
        if let Some(tap) = row.tap {
            let _ = write!(s, ",{tap}");
        }
        for v in &row.extra {
            s.push(',');
            format_f64(*v, &mut s);
        }
        s.push('\n');
        let res = self.put(s.as_bytes());
        self.buf = s;
        res?;
        self.line_no = line;
        self.rows += 1;
        Ok(())
    }

    /// Rows written so far.
    pub fn rows_written(&self) -> u64 {
        self.rows
    }

    /// Flushes, syncs and returns the complete file under its temporary name.
    pub fn finish_pending(mut self) -> Result<PendingFile> {
        let path = self.path().to_path_buf();
        if self.rows == 0 {
            return Err(RecordingError::new(
                &path,
                ErrorKind::Contract,
                "cannot write a recording without rows",
            ));
        }
        let out = self.out.take();
        if let Some(out) = out {
            let file = out
                .into_inner()
                .map_err(|e| RecordingError::io(&path, "cannot write", e.error()))?;
            file.sync_all()
                .map_err(|e| RecordingError::io(&path, "cannot write", &e))?;
        }
        self.pending.take().ok_or_else(|| {
            RecordingError::new(&path, ErrorKind::Io, "the writer was already finished")
        })
    }

    /// Flushes, syncs and renames the file into place.
    pub fn finish(self) -> Result<()> {
        self.finish_pending()?.commit()
    }
}

/// Reads a whole small text file with a size limit (vendor text exports).
pub(crate) fn read_text_limited(path: &Path, limit: u64) -> Result<Vec<u8>> {
    let file = File::open(path).map_err(|e| RecordingError::io(path, "cannot open", &e))?;
    let mut bytes = Vec::new();
    file.take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| RecordingError::io(path, "cannot read", &e))?;
    if bytes.len() as u64 > limit {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            format!("file larger than {limit} bytes; not a single force curve export"),
        ));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_str(s: &str) -> Result<(Header, Vec<Row>)> {
        let mut r = RecordingReader::new(Path::new("mem.csv"), s.as_bytes())?;
        let h = r.header().clone();
        let rows = r.by_ref().collect::<Result<Vec<_>>>()?;
        Ok((h, rows))
    }

    const HEAD: &str = "# visco-recording: 1\n# mode: dive\n# sample_rate_hz: 500000\n\
        # cantilever_k_n_per_m: 0.18\n# tip_radius_m: 3.0e-7\n";

    #[test]
    fn format_round_trips_awkward_values() {
        for v in [
            0.0,
            -0.0,
            1e-300,
            f64::MIN_POSITIVE,
            5e-324,
            f64::MAX,
            -f64::MAX,
            0.1,
            1.0 / 3.0,
            2.0e-7,
            123456789.123,
            1e-3,
            9.999999999999999e6,
        ] {
            let mut s = String::new();
            format_f64(v, &mut s);
            let back: f64 = s.parse().unwrap();
            assert_eq!(back.to_bits(), v.to_bits(), "{v} -> {s}");
        }
    }

    #[test]
    fn reads_columns_in_any_order_with_extras() {
        let (h, rows) = read_str(&format!(
            "{HEAD}# source: any: free text\nd_m,extra_a,t_s,u_m\n1e-9,5,0,2e-7\n2e-9,6,0.5,3e-7\n"
        ))
        .unwrap();
        assert_eq!(h.meta.get("source"), Some("any: free text"));
        assert_eq!(h.columns.extra, vec!["extra_a".to_string()]);
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].t_s, 0.5);
        assert_eq!(rows[1].u_m, 3e-7);
        assert_eq!(rows[1].d_m, 2e-9);
        assert_eq!(rows[1].extra, vec![6.0]);
    }

    #[test]
    fn crlf_is_accepted() {
        let s = format!("{HEAD}t_s,u_m,d_m\n0,1,2\n1,1,2\n").replace('\n', "\r\n");
        let (_, rows) = read_str(&s).unwrap();
        assert_eq!(rows.len(), 2);
    }

    fn err(s: &str) -> RecordingError {
        match read_str(s) {
            Ok(_) => panic!("accepted:\n{s}"),
            Err(e) => e,
        }
    }

    #[test]
    fn violations_name_line_and_reason() {
        let e = err("");
        assert_eq!((e.line, e.reason.as_str()), (Some(1), "empty file"));
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,2\n1,abc,2\n"));
        assert_eq!(e.line, Some(8));
        assert!(
            e.reason.contains("column `u_m`: `abc` is not a number"),
            "{e}"
        );
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,NaN\n"));
        assert_eq!(e.line, Some(7));
        assert!(e.reason.contains("NaN"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,inf\n"));
        assert!(e.reason.contains("not a finite number"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,2\n0,1,2\n"));
        assert_eq!(e.line, Some(8));
        assert!(e.reason.contains("does not increase"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,2,3\n"));
        assert_eq!(e.line, Some(7));
        assert!(e.reason.contains("expected 3 cells"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m\n0,1\n"));
        assert_eq!(e.line, Some(6));
        assert!(e.reason.contains("missing required column `d_m`"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m,t_s\n0,1,2,0\n"));
        assert!(e.reason.contains("appears twice"), "{e}");
        let e = err(&HEAD.replace("# tip_radius_m: 3.0e-7\n", "").to_string());
        assert!(e.reason.contains("no header line"), "{e}");
        let e = err(&format!(
            "{}t_s,u_m,d_m\n0,1,2\n",
            HEAD.replace("# tip_radius_m: 3.0e-7\n", "")
        ));
        assert_eq!(e.line, Some(5));
        assert!(e.reason.contains("`tip_radius_m`"), "{e}");
        assert!(e.fix.as_deref().unwrap().contains("# tip_radius_m:"), "{e}");
        let e = err(&format!(
            "{}t_s,u_m,d_m\n0,1,2\n",
            HEAD.replace("recording: 1", "recording: 2")
        ));
        assert_eq!(e.line, Some(1));
        assert!(e.reason.contains("unknown format version `2`"), "{e}");
        let e = err(&format!(
            "{}t_s,u_m,d_m\n0,1,2\n",
            HEAD.replace("dive", "tapping")
        ));
        assert_eq!(e.line, Some(2));
        assert!(e.reason.contains("unknown mode"), "{e}");
        let e = err(&format!(
            "{}t_s,u_m,d_m\n0,1,2\n",
            HEAD.replace("0.18", "-0.18")
        ));
        assert_eq!(e.line, Some(4));
        assert!(e.reason.contains("out of range"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n"));
        assert_eq!(e.line, Some(7));
        assert!(e.reason.contains("no data rows"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,2\n\n1,1,2\n"));
        assert_eq!(e.line, Some(8));
        assert!(e.reason.contains("blank line"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,2\n1,1,2\n\n"));
        assert_eq!(e.line, Some(9));
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,\"1,5\",2\n"));
        assert!(e.reason.contains("expected 3 cells"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m,tap\n0,1,2,0\n1,1,2,1\n"));
        assert_eq!(e.line, Some(8));
        assert!(e.reason.contains("tap changes"), "{e}");
        let e = err(&format!("{HEAD}t_s,u_m,d_m,tap\n0,1,2,-1\n"));
        assert!(e.reason.contains("non-negative integer"), "{e}");
        let e = err(&format!(
            "{}t_s,u_m,d_m\n0,1,2\n",
            HEAD.replace("dive", "sve")
        ));
        assert!(e.reason.contains("x_m and y_m"), "{e}");
        let e = err(&format!("{HEAD}# just a comment\nt_s,u_m,d_m\n0,1,2\n"));
        assert_eq!(e.line, Some(6));
        let e = err(&format!(
            "{HEAD}# source: a\n# source: b\nt_s,u_m,d_m\n0,1,2\n"
        ));
        assert_eq!(e.line, Some(7));
        let e = err(&format!("{HEAD}t_s,u_m,d_m\n0,1,2\n1,\u{ff}1,2\n"));
        assert!(e.reason.contains("not a number"), "{e}");
        let mut bytes = format!("{HEAD}t_s,u_m,d_m\n0,1,2\n").into_bytes();
        bytes.extend_from_slice(&[b'1', b',', 0xff, b',', b'2', b'\n']);
        let e = RecordingReader::new(Path::new("x"), bytes.as_slice())
            .and_then(|r| r.collect::<Result<Vec<_>>>())
            .unwrap_err();
        assert_eq!((e.line, e.reason.as_str()), (Some(8), "not UTF-8 text"));
    }

    #[test]
    fn huge_line_is_refused_not_loaded() {
        let s = format!("{HEAD}t_s,u_m,d_m\n{}\n", "1".repeat(MAX_LINE_BYTES + 10));
        let e = err(&s);
        assert!(e.reason.contains("line longer"), "{e}");
        assert_eq!(e.line, Some(7));
    }

    #[test]
    fn reader_is_fused_after_an_error() {
        let s = format!("{HEAD}t_s,u_m,d_m\n0,1,2\nx,1,2\n2,1,2\n");
        let mut r = RecordingReader::new(Path::new("m"), s.as_bytes()).unwrap();
        assert!(r.next().unwrap().is_ok());
        assert!(r.next().unwrap().is_err());
        assert!(r.next().is_none());
    }
}
