//! AFM Workshop force–distance CSV.
//!
//! ```text
//! Force-Distance Curve   (key and value are separated by a tab)
//! File Format:    3
//!
//! Date:    22 October 2020
//! ...
//! X, um:    0.500000
//! Y, um:    0.500000
//!
//! Extend Z-Sense(nm),Extend Force(nN),Retract Z-Sense(nm),Retract Force(nN)
//! 4129.0327,0.0531,5345.0327,0.0709
//! ```
//!
//! Z-Sense is the measured piezo extension in nm: it *grows* while extending towards the
//! sample, so U = −Z-Sense (z up). Each row holds one extend and one retract sample; in time
//! the extend column runs first, top to bottom, then the retract column, top to bottom.
//! Deflection comes either as force (`Force(nN)`, positive = repulsive, so D = −F/k) or as the
//! photodiode signal (`T-B(V)`, D = −V·sensitivity).
//!
//! The file holds no sampling rate, and usually no spring constant (a `Force Constant, nN/nm`
//! line, when present and not the default 1, is used) and no sensitivity (`Light Lever Gain,
//! mV/nm`, likewise). So `--spring-constant`, `--sample-rate` and `--tip-radius` are needed,
//! and `--sensitivity` too for `T-B(V)` files. The sensitivity plays no part for `Force(nN)`
//! files, whose deflection follows from force and k alone; it is recorded if given.
//!
//! A map (`Mode: Mapping`) is written as one CSV per point; a zip of them imports as a map,
//! its curves in the members' name order ([`import_zip`]; each also carries `archive_entry`).
//!
//! Metadata written: `source_file`, `source_format`, `instrument`, `workshop_file_format`,
//! `date`, `time`, `workshop_mode`, `point`, `position_x_m`, `position_y_m`,
//! `spring_constant_source`, `sensitivity_m_per_v` (if known), `sample_rate_source`,
//! `tip_radius_source`, `segments`, `segment_points`, `u_m_from`, `d_m_from`,
//! `force_vendor_n_from`.

use std::path::Path;

use super::{
    check_recording, missing_error, num, resolve, ImportOptions, NEED_K, NEED_R, NEED_RATE,
    NEED_SENS,
};
use crate::recording::csv::read_text_limited;
use crate::recording::error::{ErrorKind, RecordingError, Result};
use crate::recording::{Column, Metadata, Mode, Recording};

const MAX_BYTES: u64 = 512 << 20;

/// What a data column holds.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    ExtendZ,
    ExtendForce,
    ExtendTb,
    RetractZ,
    RetractForce,
    RetractTb,
    Unknown,
}

/// Parses an AFM Workshop force–distance CSV into a recording.
pub fn import(path: &Path, opts: &ImportOptions, warnings: &mut Vec<String>) -> Result<Recording> {
    let bytes = read_text_limited(path, MAX_BYTES)?;
    import_bytes(path, &bytes, opts, warnings)
}

/// Whether a zip archive's members are all CSV files (an AFM Workshop map), and there are any.
pub fn is_csv_zip(names: &[&str]) -> bool {
    let data: Vec<&&str> = names.iter().filter(|n| !zip_extra(n)).collect();
    !data.is_empty() && data.iter().all(|n| n.to_lowercase().ends_with(".csv"))
}

/// A zip member that is not an export: a folder, or the resource forks macOS's Finder adds
/// (`__MACOSX/…`, `._name`).
fn zip_extra(name: &str) -> bool {
    name.ends_with('/')
        || name.starts_with("__MACOSX/")
        || name.rsplit('/').next().is_some_and(|f| f.starts_with("._"))
}

/// An AFM Workshop map zipped: its CSVs (one per point) in the members' name order, each read
/// when asked for, so that a map never sits in memory whole. An error names the member.
pub struct WorkshopZip {
    path: std::path::PathBuf,
    opts: ImportOptions,
    zip: zip::ZipArchive<std::fs::File>,
    names: Vec<String>,
    /// Warnings said so far (each is said once, naming the first member it came from: a flag
    /// that overrides the files' value would otherwise be said for each of hundreds of points).
    seen: Vec<String>,
}

impl WorkshopZip {
    /// Opens the archive and lists its CSVs.
    pub fn open(path: &Path, opts: &ImportOptions) -> Result<Self> {
        let file =
            std::fs::File::open(path).map_err(|e| RecordingError::io(path, "cannot open", &e))?;
        let zip = zip::ZipArchive::new(file).map_err(|e| {
            RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("not a readable zip archive: {e}"),
            )
        })?;
        let mut names: Vec<String> = zip
            .file_names()
            .filter(|n| !zip_extra(n))
            .map(str::to_string)
            .collect();
        names.sort_unstable();
        Ok(WorkshopZip {
            path: path.to_path_buf(),
            opts: *opts,
            zip,
            names,
            seen: Vec::new(),
        })
    }

    /// The number of curves (CSV members).
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Whether the archive holds no curve.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Reads curve `i` (the `i`-th member in name order).
    pub fn read(&mut self, i: usize, warnings: &mut Vec<String>) -> Result<Recording> {
        use std::io::Read;
        let path = self.path.as_path();
        let Some(name) = self.names.get(i).cloned() else {
            return Err(RecordingError::new(
                path,
                ErrorKind::Usage,
                format!(
                    "the map holds curves 0–{}, not curve {i}",
                    self.names.len().saturating_sub(1)
                ),
            ));
        };
        let mut bytes = Vec::new();
        self.zip
            .by_name(&name)
            .map_err(|e| RecordingError::new(path, ErrorKind::Vendor, e.to_string()))
            .and_then(|f| {
                f.take(MAX_BYTES + 1)
                    .read_to_end(&mut bytes)
                    .map_err(|e| RecordingError::io(path, "cannot read", &e))
            })
            .map_err(|e| e.in_entry(name.clone()))?;
        if bytes.len() as u64 > MAX_BYTES {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("member larger than {MAX_BYTES} bytes; not a force curve export"),
            )
            .in_entry(name.clone()));
        }
        let mut own = Vec::new();
        let mut rec = import_bytes(path, &bytes, &self.opts, &mut own)
            .map_err(|e| e.in_entry(name.clone()))?;
        for w in own {
            if !self.seen.contains(&w) {
                warnings.push(format!("{name}: {w}"));
                self.seen.push(w);
            }
        }
        rec.meta.set("source_format", "afm-workshop-zip");
        rec.meta.set("archive_entry", &name);
        rec.meta.set("curve_index", i.to_string());
        Ok(rec)
    }
}

/// Every curve of a zipped AFM Workshop map ([`WorkshopZip`]), in memory.
pub fn import_zip(
    path: &Path,
    opts: &ImportOptions,
    warnings: &mut Vec<String>,
) -> Result<Vec<Recording>> {
    let mut z = WorkshopZip::open(path, opts)?;
    (0..z.len()).map(|i| z.read(i, warnings)).collect()
}

/// [`import`] of a file's bytes (`path` names it in messages and metadata).
fn import_bytes(
    path: &Path,
    bytes: &[u8],
    opts: &ImportOptions,
    warnings: &mut Vec<String>,
) -> Result<Recording> {
    if bytes.is_empty() {
        return Err(RecordingError::new(path, ErrorKind::Vendor, "empty file").at_line(1));
    }
    let text = String::from_utf8_lossy(bytes);
    let lines: Vec<&str> = text.split('\n').map(|l| l.trim_end_matches('\r')).collect();
    if !lines
        .first()
        .is_some_and(|l| l.trim().starts_with("Force-Distance Curve"))
    {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "not an AFM Workshop force-distance file (line 1 is not `Force-Distance Curve`)",
        )
        .at_line(1));
    }
    let mut meta_pairs: Vec<(String, String)> = Vec::new();
    let mut header: Option<(usize, &str)> = None;
    for (i, line) in lines.iter().enumerate().skip(1) {
        if line.matches(',').count() >= 3 && !line.contains(':') {
            header = Some((i, line));
            break;
        }
        if let Some((k, v)) = line.split_once(':') {
            meta_pairs.push((k.trim().to_string(), v.trim().to_string()));
        }
    }
    let Some((header_idx, header_line)) = header else {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "no column header (a line like `Extend Z-Sense(nm),Extend Force(nN),...`)",
        )
        .at_line(lines.len() as u64));
    };
    let header_no = header_idx as u64 + 1;
    let get = |key: &str| {
        meta_pairs
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    };
    let header_number = |key: &str| -> Result<Option<f64>> {
        match get(key) {
            None => Ok(None),
            Some(v) => match v.parse::<f64>() {
                Ok(x) if x.is_finite() => Ok(Some(x)),
                _ => Err(RecordingError::new(
                    path,
                    ErrorKind::Vendor,
                    format!("`{key}` value `{v}` is not a number"),
                )),
            },
        }
    };

    let kinds: Vec<Kind> = header_line
        .split(',')
        .map(|c| match c.trim() {
            "Extend Z-Sense(nm)" => Kind::ExtendZ,
            "Extend Force(nN)" => Kind::ExtendForce,
            "Extend T-B(V)" => Kind::ExtendTb,
            "Retract Z-Sense(nm)" => Kind::RetractZ,
            "Retract Force(nN)" => Kind::RetractForce,
            "Retract T-B(V)" => Kind::RetractTb,
            _ => Kind::Unknown,
        })
        .collect();
    for (name, kind) in header_line.split(',').zip(&kinds) {
        if *kind == Kind::Unknown {
            warnings.push(format!(
                "{}:{header_no}: unknown column `{}` ignored",
                path.display(),
                name.trim()
            ));
        }
    }
    let col = |k: Kind| kinds.iter().position(|x| *x == k);
    let (Some(ez), Some(rz)) = (col(Kind::ExtendZ), col(Kind::RetractZ)) else {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "the header lacks `Extend Z-Sense(nm)` or `Retract Z-Sense(nm)`",
        )
        .at_line(header_no));
    };
    let force_cols = (col(Kind::ExtendForce), col(Kind::RetractForce));
    let tb_cols = (col(Kind::ExtendTb), col(Kind::RetractTb));
    let uses_force = match (force_cols, tb_cols) {
        ((Some(_), Some(_)), _) => true,
        (_, (Some(_), Some(_))) => false,
        _ => {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                "the header lacks the deflection columns (`Extend/Retract Force(nN)` or `Extend/Retract T-B(V)`)",
            )
            .at_line(header_no))
        }
    };

    // Values: flags first, then the file's own (defaults of 1 mean "not set").
    let file_k = header_number("Force Constant, nN/nm")?.filter(|v| *v != 1.0);
    let file_sens = header_number("Light Lever Gain, mV/nm")?
        .filter(|v| *v != 1.0 && *v != 0.0)
        .map(|g| 1.0 / (g * 1e-3 / 1e-9));
    let mut missing = Vec::new();
    let k = resolve(
        &NEED_K,
        opts.spring_constant_n_per_m,
        file_k,
        "N/m",
        warnings,
        &mut missing,
    );
    let sens = if uses_force {
        opts.sensitivity_m_per_unit
            .or(file_sens)
            .map(|s| (s, "flag"))
    } else {
        resolve(
            &NEED_SENS,
            opts.sensitivity_m_per_unit,
            file_sens,
            "m/V",
            warnings,
            &mut missing,
        )
    };
    let rate = resolve(
        &NEED_RATE,
        opts.sample_rate_hz,
        None,
        "Hz",
        warnings,
        &mut missing,
    );
    let r = resolve(
        &NEED_R,
        opts.tip_radius_m,
        None,
        "m",
        warnings,
        &mut missing,
    );
    let (Some((k, k_src)), Some((rate, _)), Some((r, _))) = (k, rate, r) else {
        return Err(missing_error(path, &missing));
    };

    // Rows.
    let ncols = kinds.len();
    let mut ext: Vec<(f64, f64)> = Vec::new();
    let mut ret: Vec<(f64, f64)> = Vec::new();
    let (ed, rd) = if uses_force { force_cols } else { tb_cols };
    let (ed, rd) = (ed.unwrap_or(0), rd.unwrap_or(0));
    let mut cells: Vec<f64> = vec![0.0; ncols];
    let mut ended_at: Option<usize> = None;
    for (i, line) in lines.iter().enumerate().skip(header_idx + 1) {
        let line_no = i as u64 + 1;
        if line.trim().is_empty() {
            ended_at.get_or_insert(i);
            continue;
        }
        if let Some(end) = ended_at {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("data continues after the blank line {}", end + 1),
            )
            .at_line(line_no));
        }
        let parts: Vec<&str> = line.split(',').collect();
        if parts.len() != ncols {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("expected {ncols} cells, found {}", parts.len()),
            )
            .at_line(line_no));
        }
        for (j, p) in parts.iter().enumerate() {
            let v = p
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    RecordingError::new(
                        path,
                        ErrorKind::Vendor,
                        format!("cell {} `{}` is not a finite number", j + 1, p.trim()),
                    )
                    .at_line(line_no)
                })?;
            if let Some(c) = cells.get_mut(j) {
                *c = v;
            }
        }
        let at = |j: usize| cells.get(j).copied().unwrap_or(0.0);
        ext.push((at(ez), at(ed)));
        ret.push((at(rz), at(rd)));
    }
    if ext.is_empty() {
        return Err(
            RecordingError::new(path, ErrorKind::Vendor, "no data rows after the header")
                .at_line(header_no + 1),
        );
    }

    let n = ext.len() + ret.len();
    let mut meta = Metadata::new(Mode::ForceCurve, rate, k, r);
    let mut rec = Recording::new(meta.clone());
    let mut seg = Vec::with_capacity(n);
    let mut force = Vec::with_capacity(n);
    for (i, (z_nm, defl)) in ext.iter().chain(ret.iter()).enumerate() {
        rec.t_s.push(i as f64 / rate);
        rec.u_m.push(-z_nm * 1e-9);
        let d = if uses_force {
            force.push(defl * 1e-9);
            -(defl * 1e-9) / k
        } else {
            -defl * sens.map(|s| s.0).unwrap_or(0.0)
        };
        rec.d_m.push(d);
        seg.push(if i < ext.len() { 0.0 } else { 1.0 });
    }
    rec.extra.push(Column {
        name: "segment".into(),
        values: seg,
    });
    if uses_force {
        rec.extra.push(Column {
            name: "force_vendor_n".into(),
            values: force,
        });
    }

    meta.set("source_file", path.display().to_string());
    meta.set("source_format", "afm-workshop-csv");
    meta.set("instrument", "AFM Workshop");
    for (key, name) in [
        ("File Format", "workshop_file_format"),
        ("Software Version", "vendor_software"),
        ("Date", "date"),
        ("Time", "time"),
        ("Mode", "workshop_mode"),
        ("Point", "point"),
    ] {
        if let Some(v) = get(key) {
            meta.set(name, v);
        }
    }
    for (key, name) in [("X, um", "position_x_m"), ("Y, um", "position_y_m")] {
        if let Some(v) = header_number(key)? {
            meta.set(name, num(v * 1e-6));
        }
    }
    super::set_spring_constant_source(&mut meta, k_src, None);
    if let Some((s, _)) = sens {
        meta.set("sensitivity_m_per_v", num(s));
    }
    meta.set(
        "sample_rate_source",
        "--sample-rate (the file has no time base)",
    );
    meta.set("tip_radius_source", "--tip-radius");
    meta.set("segments", "0=extend,1=retract");
    meta.set("segment_points", format!("{},{}", ext.len(), ret.len()));
    meta.set("u_m_from", "-Z-Sense");
    meta.set(
        "d_m_from",
        if uses_force {
            "-Force / k"
        } else {
            "-T-B × sensitivity"
        },
    );
    if uses_force {
        meta.set(
            "force_vendor_n_from",
            "Force(nN) × 1e-9; positive = repulsive",
        );
    }
    rec.meta = meta;
    check_recording(path, &rec)?;
    Ok(rec)
}
