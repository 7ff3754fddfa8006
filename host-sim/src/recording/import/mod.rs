//! Importers: commercial AFM force-curve files → `mode: force-curve` recordings.
//!
//! Why: identification and diagnosis must run on real measurements, and labs record them with
//! commercial instruments. Each importer turns one vendor format into the contract's signals:
//!
//! - `u_m`: the base (piezo) position U, z up, so extending towards the sample makes U
//!   *decrease*; where the file has a z sensor (JPK), its reading, since the piezo drive
//!   signal is not the position (see [`jpk`]);
//! - `d_m`: the deflection D in metres with the contract's sign, D < 0 when the sample pushes
//!   the tip up. All vendors here report the repulsive deflection as *positive*, so
//!   D = −(vendor deflection);
//! - `t_s`: from the vendor's rate and durations (per segment: JPK segments may differ in rate);
//! - extra columns: `segment` (the segment number, in time order; `# segments:` maps numbers to
//!   kinds `extend`/`pause`/`retract`), `force_vendor_n` (the vendor's own force channel, vendor
//!   sign: positive = repulsive, so it equals −k·d_m) and `height_piezo_m` (JPK: the piezo
//!   drive signal, when `u_m` comes from the z sensor);
//! - metadata: the vendor's spring constant, sensitivity, rates, setpoint, position,
//!   instrument and source file, under the keys listed in each importer's docs.
//!
//! The contract needs the spring constant and the tip radius; some formats also lack the
//! sensitivity or any time base. A missing value is never guessed: the import is refused with
//! a message naming the flag that supplies it ([`ImportOptions`]). A flag given explicitly
//! overrides the file's value, with a warning when the two disagree.
//!
//! Formats: [`jpk`] (`.jpk-force`, `.jpk-force-map`, `.jpk-qi-data`), [`workshop`] (AFM
//! Workshop CSV), [`ntmdt`] (NT-MDT Nova text export), [`igor`] (Asylum Research `.ibw`),
//! [`chiaro`] (Optics11 Chiaro text export), [`afmformats_tab`] (the afmformats package's
//! `.tab` export).
#![forbid(unsafe_code)]

pub mod afmformats_tab;
pub mod chiaro;
pub mod igor;
pub mod jpk;
pub mod ntmdt;
pub mod properties;
pub mod workshop;

use std::io::Read;
use std::path::Path;

use super::error::{ErrorKind, RecordingError, Result};
use super::Recording;

/// Values given on the command line; each overrides the file's value when given.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ImportOptions {
    /// Cantilever spring constant, N/m (`--spring-constant`).
    pub spring_constant_n_per_m: Option<f64>,
    /// Deflection sensitivity, metres of deflection per unit of the raw deflection signal the
    /// file stores: m/V for JPK and AFM Workshop, m/nA for NT-MDT (`--sensitivity`).
    pub sensitivity_m_per_unit: Option<f64>,
    /// Spherical tip radius, m (`--tip-radius`).
    pub tip_radius_m: Option<f64>,
    /// Sampling rate, Hz, for formats without a time base (`--sample-rate`).
    pub sample_rate_hz: Option<f64>,
}

/// The vendor formats understood.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// JPK single force curve (zip).
    JpkForce,
    /// JPK force map (zip, one curve per grid point).
    JpkForceMap,
    /// JPK quantitative imaging data (zip, same layout as a force map).
    JpkQiData,
    /// AFM Workshop force–distance CSV.
    AfmWorkshopCsv,
    /// NT-MDT Nova text export (decimal commas).
    NtMdtTxt,
    /// Asylum Research force curve, an Igor binary wave (version 5).
    AsylumIbw,
    /// Optics11 Chiaro nanoindenter text export.
    ChiaroTxt,
    /// AFM Workshop map: a zip of its force–distance CSVs, one per point.
    AfmWorkshopZip,
    /// The afmformats Python package's tab-separated export.
    AfmformatsTab,
}

impl Format {
    /// Name used in metadata (`source_format`) and messages.
    pub fn name(self) -> &'static str {
        match self {
            Format::JpkForce => "jpk-force",
            Format::JpkForceMap => "jpk-force-map",
            Format::JpkQiData => "jpk-qi-data",
            Format::AfmWorkshopCsv => "afm-workshop-csv",
            Format::NtMdtTxt => "ntmdt-txt",
            Format::AsylumIbw => "asylum-ibw",
            Format::ChiaroTxt => "chiaro-txt",
            Format::AfmWorkshopZip => "afm-workshop-zip",
            Format::AfmformatsTab => "afmformats-tab",
        }
    }
}

/// Recognises the format from the extension, confirmed by the content.
pub fn detect_format(path: &Path) -> Result<Format> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let mut head = [0u8; 64];
    let n = std::fs::File::open(path)
        .and_then(|mut f| f.read(&mut head))
        .map_err(|e| RecordingError::io(path, "cannot read", &e))?;
    let head = head.get(..n).unwrap_or(&[]);
    let is_zip = head.starts_with(b"PK\x03\x04") || head.starts_with(b"PK\x05\x06");
    let by_ext = if name.ends_with(".jpk-force") {
        Some(Format::JpkForce)
    } else if name.ends_with(".jpk-force-map") {
        Some(Format::JpkForceMap)
    } else if name.ends_with(".jpk-qi-data") {
        Some(Format::JpkQiData)
    } else {
        None
    };
    if let Some(f) = by_ext {
        if n == 0 {
            return Err(RecordingError::new(path, ErrorKind::Vendor, "empty file"));
        }
        if !is_zip {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                "not a zip archive, so not a JPK file",
            ));
        }
        return Ok(f);
    }
    if is_zip {
        // A zip of CSVs is AFM Workshop's map; any other zip is taken for JPK's container
        // (whose reader says what an archive without its headers holds).
        let names: Vec<String> = std::fs::File::open(path)
            .ok()
            .and_then(|f| zip::ZipArchive::new(f).ok())
            .map(|z| z.file_names().map(str::to_string).collect())
            .unwrap_or_default();
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        if workshop::is_csv_zip(&names) {
            return Ok(Format::AfmWorkshopZip);
        }
        return Ok(Format::JpkForce);
    }
    if name.ends_with(".ibw") {
        if n == 0 {
            return Err(RecordingError::new(path, ErrorKind::Vendor, "empty file"));
        }
        if !igor::is_ibw5(head) {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                "not an Igor binary wave of version 5, so not an Asylum force curve",
            ));
        }
        return Ok(Format::AsylumIbw);
    }
    if n == 0 {
        return Err(RecordingError::new(path, ErrorKind::Vendor, "empty file").at_line(1));
    }
    let text = String::from_utf8_lossy(head);
    if text.starts_with("Force-Distance Curve") {
        return Ok(Format::AfmWorkshopCsv);
    }
    if text.starts_with("# visco-recording") {
        return Err(RecordingError::new(
            path,
            ErrorKind::Usage,
            "this is already a visco recording; there is nothing to import",
        ));
    }
    if head.starts_with(b"\x89HDF\r\n\x1a\n") {
        return Err(RecordingError::new(
            path,
            ErrorKind::Usage,
            "an HDF5 file, which import does not read",
        )
        .with_fix(
            "if afmformats wrote it, export the curves from afmformats as .tab \
                     (tab-separated), which import reads",
        ));
    }
    if afmformats_tab::looks_like(&text) {
        return Ok(Format::AfmformatsTab);
    }
    if text.starts_with("Date\t") {
        // A Chiaro export: its table's header comes after some 40 header lines.
        let mut more = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(16 << 10).read_to_end(&mut more))
            .map_err(|e| RecordingError::io(path, "cannot read", &e))?;
        let more: String = more.iter().map(|b| *b as char).collect();
        if chiaro::looks_like(&more) {
            return Ok(Format::ChiaroTxt);
        }
    }
    if name.ends_with(".txt") || text.lines().next().is_some_and(|l| l.contains('\t')) {
        return Ok(Format::NtMdtTxt);
    }
    Err(
        RecordingError::new(path, ErrorKind::Usage, "unknown file format").with_fix(
            "import reads JPK .jpk-force/.jpk-force-map/.jpk-qi-data, AFM Workshop .csv, \
         NT-MDT and Optics11 Chiaro .txt exports, Asylum Research .ibw and afmformats .tab",
        ),
    )
}

/// An opened vendor file: lists its curves and reads them one at a time, so a map with
/// thousands of curves never sits in memory whole.
pub struct Import {
    format: Format,
    inner: Inner,
    warnings: Vec<String>,
}

enum Inner {
    Jpk(Box<jpk::JpkArchive>),
    Single(Box<Recording>),
    /// A zip of AFM Workshop CSVs, each read when asked for.
    WorkshopZip(Box<workshop::WorkshopZip>),
}

impl Import {
    /// Opens and checks a vendor file. Text formats are parsed here whole (they hold one
    /// curve); JPK archives only have their headers read.
    pub fn open(path: &Path, opts: &ImportOptions) -> Result<Import> {
        let format = detect_format(path)?;
        let mut warnings = Vec::new();
        let inner = match format {
            Format::JpkForce | Format::JpkForceMap | Format::JpkQiData => {
                Inner::Jpk(Box::new(jpk::JpkArchive::open(path, format, opts)?))
            }
            Format::AfmWorkshopCsv => {
                Inner::Single(Box::new(workshop::import(path, opts, &mut warnings)?))
            }
            Format::NtMdtTxt => Inner::Single(Box::new(ntmdt::import(path, opts, &mut warnings)?)),
            Format::AsylumIbw => Inner::Single(Box::new(igor::import(path, opts, &mut warnings)?)),
            Format::ChiaroTxt => {
                Inner::Single(Box::new(chiaro::import(path, opts, &mut warnings)?))
            }
            Format::AfmWorkshopZip => {
                Inner::WorkshopZip(Box::new(workshop::WorkshopZip::open(path, opts)?))
            }
            Format::AfmformatsTab => {
                Inner::Single(Box::new(afmformats_tab::import(path, opts, &mut warnings)?))
            }
        };
        Ok(Import {
            format,
            inner,
            warnings,
        })
    }

    /// The format recognised.
    pub fn format(&self) -> Format {
        self.format
    }

    /// Curve numbers available (for maps, the archive's `index/N`; otherwise `[0]`).
    pub fn curves(&self) -> Vec<usize> {
        match &self.inner {
            Inner::Jpk(a) => a.curves(),
            Inner::Single(_) => vec![0],
            Inner::WorkshopZip(z) => (0..z.len()).collect(),
        }
    }

    /// Whether the file holds a map (curves addressed by index) rather than one curve.
    pub fn is_map(&self) -> bool {
        matches!(
            self.format,
            Format::JpkForceMap | Format::JpkQiData | Format::AfmWorkshopZip
        )
    }

    /// Reads one curve.
    pub fn read_curve(&mut self, curve: usize) -> Result<Recording> {
        match &mut self.inner {
            Inner::Jpk(a) => {
                let rec = a.read_curve(curve, &mut self.warnings)?;
                Ok(rec)
            }
            Inner::WorkshopZip(z) => z.read(curve, &mut self.warnings),
            Inner::Single(rec) => {
                if curve == 0 {
                    Ok((**rec).clone())
                } else {
                    Err(RecordingError::new(
                        Path::new(rec.meta.get("source_file").unwrap_or("")),
                        ErrorKind::Usage,
                        format!("the file holds one curve (0), not curve {curve}"),
                    ))
                }
            }
        }
    }

    /// Warnings gathered so far (flags disagreeing with the file, oddities of the file).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }
}

/// Imports every curve of a file, in memory (convenient for tests and small files).
pub fn import_all(path: &Path, opts: &ImportOptions) -> Result<Vec<(usize, Recording)>> {
    let mut imp = Import::open(path, opts)?;
    let mut out = Vec::new();
    for c in imp.curves() {
        out.push((c, imp.read_curve(c)?));
    }
    Ok(out)
}

/// A value the contract needs, with where to get it if missing.
pub(crate) struct Needed {
    /// Human name, e.g. "spring constant".
    pub what: &'static str,
    /// The flag and its unit, e.g. "--spring-constant N_PER_M".
    pub flag: &'static str,
    /// An example value for the fix text.
    pub example: &'static str,
}

/// The spring constant.
pub(crate) const NEED_K: Needed = Needed {
    what: "spring constant",
    flag: "--spring-constant",
    example: "0.1",
};
/// The tip radius.
pub(crate) const NEED_R: Needed = Needed {
    what: "tip radius",
    flag: "--tip-radius",
    example: "5e-6",
};
/// The sensitivity.
pub(crate) const NEED_SENS: Needed = Needed {
    what: "deflection sensitivity",
    flag: "--sensitivity",
    example: "7e-8",
};
/// The sampling rate.
pub(crate) const NEED_RATE: Needed = Needed {
    what: "sampling rate",
    flag: "--sample-rate",
    example: "2000",
};

/// Picks the flag's value over the file's, warning when both exist and differ; collects what
/// is missing into `missing` instead of failing at once, so one message names every flag.
pub(crate) fn resolve(
    need: &'static Needed,
    flag: Option<f64>,
    file: Option<f64>,
    unit: &str,
    warnings: &mut Vec<String>,
    missing: &mut Vec<&'static Needed>,
) -> Option<(f64, &'static str)> {
    match (flag, file) {
        (Some(f), Some(v)) => {
            if (f - v).abs() > 1e-9 * f.abs().max(v.abs()) {
                let w = format!(
                    "{} {f} {unit} from {} overrides the file's {v} {unit}",
                    need.what, need.flag
                );
                if !warnings.contains(&w) {
                    warnings.push(w);
                }
            }
            Some((f, "flag"))
        }
        (Some(f), None) => Some((f, "flag")),
        (None, Some(v)) => Some((v, "file")),
        (None, None) => {
            if !missing.iter().any(|m| m.flag == need.flag) {
                missing.push(need);
            }
            None
        }
    }
}

/// The refusal for missing values: names each value and its flag.
pub(crate) fn missing_error(path: &Path, missing: &[&'static Needed]) -> RecordingError {
    let what: Vec<&str> = missing.iter().map(|m| m.what).collect();
    let flags: Vec<String> = missing
        .iter()
        .map(|m| format!("{} {}", m.flag, m.example))
        .collect();
    RecordingError::new(
        path,
        ErrorKind::MissingValue,
        format!("the file holds no {}", what.join(", no ")),
    )
    .with_fix(format!("pass {}", flags.join(" ")))
}

/// `spring_constant_source` (the flag or the file, as [`resolve`] chose) and the file's own
/// value, `spring_constant_file_n_per_m`, where the file has one.
pub(crate) fn set_spring_constant_source(
    meta: &mut crate::recording::Metadata,
    k_src: &str,
    k_file: Option<f64>,
) {
    meta.set(
        "spring_constant_source",
        if k_src == "flag" {
            "--spring-constant"
        } else {
            "file"
        },
    );
    if let Some(kf) = k_file {
        meta.set("spring_constant_file_n_per_m", num(kf));
    }
}

/// Shortest round-trip text of a number, for metadata values.
pub(crate) fn num(v: f64) -> String {
    let mut s = String::new();
    super::format_f64(v, &mut s);
    s
}

/// A comma-separated list of numbers, for metadata values.
pub(crate) fn num_list(v: &[f64]) -> String {
    v.iter().map(|x| num(*x)).collect::<Vec<_>>().join(",")
}

/// Final check of an importer's output against the contract (same rules as the writer),
/// naming the source file on failure.
pub(crate) fn check_recording(path: &Path, rec: &Recording) -> Result<()> {
    rec.meta.check().map_err(|(k, r)| {
        RecordingError::new(path, ErrorKind::Vendor, format!("metadata `{k}`: {r}"))
    })?;
    if rec.is_empty() {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "the file holds no samples",
        ));
    }
    let mut prev = f64::NEG_INFINITY;
    for (i, &t) in rec.t_s.iter().enumerate() {
        if t.is_nan() || t <= prev {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("time does not increase at sample {i} ({t} s after {prev} s)"),
            ));
        }
        prev = t;
    }
    let all = [("u_m", &rec.u_m), ("d_m", &rec.d_m)]
        .into_iter()
        .chain(rec.extra.iter().map(|c| (c.name.as_str(), &c.values)));
    for (name, col) in all {
        if col.len() != rec.len() {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!(
                    "column {name} has {} samples, time has {}",
                    col.len(),
                    rec.len()
                ),
            ));
        }
        if let Some(i) = col.iter().position(|v| !v.is_finite()) {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("{name} is not a finite number at sample {i}"),
            ));
        }
    }
    Ok(())
}
