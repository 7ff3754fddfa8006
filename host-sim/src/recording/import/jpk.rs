//! JPK force files: `.jpk-force` (one curve), `.jpk-force-map` (one curve per grid point) and
//! `.jpk-qi-data` (quantitative imaging).
//!
//! # The container
//! A zip archive. `header.properties` describes the whole file; a single curve has
//! `segments/N/segment-header.properties` and `segments/N/channels/<channel>.dat`, a map has the
//! same under `index/I/` plus `index/I/header.properties` for the curve. Newer files move the
//! parts common to all segments into `shared-data/header.properties` and reference them with
//! keys ending in `.*`: `channel.height.lcd-info.*=0` means "every key `lcd-info.0.<rest>` of
//! the shared header applies as `channel.height.<rest>`" (the same for
//! `force-segment-header.force-segment-header-info.*`). QI files use the layout of maps; there
//! is no QI sample among the test files, so `.jpk-qi-data` goes through exactly the map code
//! path and is covered by the map tests only.
//!
//! # The numbers
//! A `.dat` file holds big-endian raw samples (`encoder.type` `signedshort`, `unsignedshort`,
//! `signedinteger`, `unsignedinteger`, `signedlong`; or `float`/`double` data without encoder).
//! `encoder.scaling` (offset, multiplier) turns them into the channel's base unit (volts for
//! `height` and `vDeflection`). A conversion set then defines calibration slots, each a linear
//! map from its `base-calibration-slot`: height `volts → nominal → calibrated` (m),
//! deflection `volts → distance` (m, the multiplier is the sensitivity in m/V)
//! `→ force` (N, the multiplier is the spring constant in N/m). The importer follows these
//! chains as declared instead of assuming them.
//!
//! # Signals
//! - `u_m` = the base position measured by the z sensor (`strainGaugeHeight`,
//!   `capacitiveSensorHeight` or `measuredHeight`, nominal slot, the first one that every
//!   segment has); only without a sensor, the piezo drive `height` (or `head-height`) in its
//!   calibrated slot (nominal if uncalibrated). Both are z up: they decrease while the piezo
//!   extends towards the sample.
//!
//!   Why the sensor: JPK's `height` channel is the drive signal of the piezo scaled by a
//!   nominal linear calibration, not the position. In the test files it understates the stroke
//!   by up to 45 % (2.69 µm on a 5 µm approach that the sensor and the settings both call
//!   5 µm), differs between extend and retract (piezo hysteresis), and during a constant-force
//!   hold on a gel it moves *up* by 0.62 µm while the sensor shows the base creeping *down*
//!   0.25 µm into the sample: the closed z loop compensating piezo creep. The contract's U is
//!   the base position that makes Z = U − D the tip position; that is the sensor's reading
//!   (JPK's own "vertical tip position" is built from it too). The drive signal is kept as
//!   `height_piezo_m`.
//! - `d_m` = −`vDeflection` (distance slot): JPK's deflection is positive when the sample
//!   pushes the cantilever up, the contract's D is negative then.
//! - `force_vendor_n` = `vDeflection` in its force slot, JPK's sign (positive = repulsive), so
//!   `force_vendor_n = −k·d_m` unless `--spring-constant` overrides the file's k.
//! - `height_piezo_m` = the piezo drive `height` (calibrated), when `u_m` comes from the
//!   sensor.
//! - `t_s` = start of segment + i·duration/points: segments may run at different rates (a
//!   pause at 256 Hz between ramps at 2048 Hz), so time is built per segment.
//! - `segment` = the segment number; `# segments: 0=extend,1=retract` gives its kind.
//!
//! # Metadata written
//! `source_file`, `source_format`, `instrument`, `vendor_software`, `jpk_file_format_version`,
//! `curve_index` and `position_index` (maps), `position_x_m`, `position_y_m`,
//! `spring_constant_source`, `spring_constant_file_n_per_m`, `sensitivity_m_per_v`,
//! `sensitivity_source`, `tip_radius_source`, `setpoint_v`, `setpoint_n` (relative to the
//! baseline when `setpoint_relative: true`), `baseline_v`, `start_time`, `segments`,
//! `segment_points`, `segment_durations_s`, `segment_rates_hz`, and `u_m_from`, `d_m_from`,
//! `force_vendor_n_from`, `height_piezo_m_from` naming the channels used.
//!
//! JPK files never hold the tip radius, so `--tip-radius` is always needed.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use zip::ZipArchive;

use super::properties::Properties;
use super::{
    check_recording, missing_error, num, num_list, resolve, Format, ImportOptions, NEED_K, NEED_R,
    NEED_SENS,
};
use crate::recording::error::{ErrorKind, RecordingError, Result};
use crate::recording::{Column, Metadata, Mode, Recording};

/// Largest properties member read, bytes (real ones are a few kB).
const MAX_PROPERTIES_BYTES: u64 = 16 << 20;
/// Largest number of points in one segment accepted (1 GiB of 8-byte samples).
const MAX_SEGMENT_POINTS: usize = 1 << 27;

/// Where one curve's segments live in the archive.
#[derive(Debug, Clone)]
struct CurveLoc {
    /// `""` for a single curve, `index/I/` in a map.
    prefix: String,
    /// Number of segments `0..n`.
    segments: usize,
}

/// An opened JPK archive.
pub struct JpkArchive {
    path: PathBuf,
    format: Format,
    opts: ImportOptions,
    zip: ZipArchive<BufReader<File>>,
    general: Properties,
    shared: Option<Properties>,
    curves: BTreeMap<usize, CurveLoc>,
    is_map: bool,
}

/// Layered properties of one segment: the segment header, what it pulls from the shared
/// header, the curve header (maps) and the file header, looked up in that order.
struct Layers {
    layers: Vec<(String, Properties)>,
    /// The segment header's member name, for "missing property" messages.
    entry: String,
}

impl Layers {
    fn get(&self, key: &str) -> Option<(&str, &str, u64)> {
        self.layers
            .iter()
            .find_map(|(e, p)| p.get_with_line(key).map(|(v, l)| (v, e.as_str(), l)))
    }

    fn str(&self, key: &str) -> Option<&str> {
        self.get(key).map(|(v, _, _)| v)
    }

    fn first_str(&self, keys: &[String]) -> Option<&str> {
        keys.iter().find_map(|k| self.str(k))
    }

    fn req_str(&self, path: &Path, key: &str) -> Result<&str> {
        self.str(key).ok_or_else(|| {
            RecordingError::new(path, ErrorKind::Vendor, format!("missing property `{key}`"))
                .in_entry(self.entry.clone())
        })
    }

    /// A number, `None` when absent; an error names the member and line when it is garbage.
    fn f64(&self, path: &Path, key: &str) -> Result<Option<f64>> {
        let Some((v, entry, line)) = self.get(key) else {
            return Ok(None);
        };
        v.trim().parse::<f64>().map(Some).map_err(|_| {
            RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("property `{key}` = `{v}` is not a number"),
            )
            .in_entry(entry)
            .at_line(line)
        })
    }

    fn req_f64(&self, path: &Path, key: &str) -> Result<f64> {
        self.f64(path, key)?.ok_or_else(|| {
            RecordingError::new(path, ErrorKind::Vendor, format!("missing property `{key}`"))
                .in_entry(self.entry.clone())
        })
    }

    fn first_f64(&self, path: &Path, keys: &[String]) -> Result<Option<f64>> {
        for k in keys {
            if let Some(v) = self.f64(path, k)? {
                return Ok(Some(v));
            }
        }
        Ok(None)
    }

    /// A finite number required by the data path.
    fn finite(&self, path: &Path, key: &str) -> Result<f64> {
        let v = self.req_f64(path, key)?;
        if v.is_finite() {
            Ok(v)
        } else {
            let (_, entry, line) = self.get(key).unwrap_or(("", "", 0));
            Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("property `{key}` is {v}, not a finite number"),
            )
            .in_entry(entry)
            .at_line(line))
        }
    }
}

/// How raw samples are stored.
#[derive(Debug, Clone, Copy)]
enum Raw {
    I16,
    U16,
    I32,
    U32,
    I64,
    F32,
    F64,
}

impl Raw {
    fn width(self) -> usize {
        match self {
            Raw::I16 | Raw::U16 => 2,
            Raw::I32 | Raw::U32 | Raw::F32 => 4,
            Raw::I64 | Raw::F64 => 8,
        }
    }

    fn decode(self, b: &[u8]) -> f64 {
        let mut a = [0u8; 8];
        let n = self.width().min(b.len());
        a[..n].copy_from_slice(&b[..n]);
        match self {
            Raw::I16 => f64::from(i16::from_be_bytes([a[0], a[1]])),
            Raw::U16 => f64::from(u16::from_be_bytes([a[0], a[1]])),
            Raw::I32 => f64::from(i32::from_be_bytes([a[0], a[1], a[2], a[3]])),
            Raw::U32 => f64::from(u32::from_be_bytes([a[0], a[1], a[2], a[3]])),
            Raw::I64 => i64::from_be_bytes(a) as f64,
            Raw::F32 => f64::from(f32::from_be_bytes([a[0], a[1], a[2], a[3]])),
            Raw::F64 => f64::from_be_bytes(a),
        }
    }
}

/// One segment's decoded signals.
struct Segment {
    style: String,
    points: usize,
    duration_s: f64,
    piezo_m: Vec<f64>,
    defl_m: Vec<f64>,
    force_n: Option<Vec<f64>>,
    measured_m: Option<Vec<f64>>,
    k_file: Option<f64>,
    sens_file: Option<f64>,
    setpoint_v: Option<f64>,
    baseline_v: Option<f64>,
    time_stamp: Option<String>,
    piezo_from: String,
}

const HEIGHT_CHANNELS: [&str; 2] = ["height", "head-height"];
const MEASURED_CHANNELS: [&str; 3] = [
    "strainGaugeHeight",
    "capacitiveSensorHeight",
    "measuredHeight",
];
const DEFLECTION: &str = "vDeflection";

impl JpkArchive {
    /// Opens the archive, reads the file-level headers, lists the curves and checks that the
    /// values the contract needs are available (from the file or the flags).
    pub fn open(path: &Path, format: Format, opts: &ImportOptions) -> Result<JpkArchive> {
        let file = File::open(path).map_err(|e| RecordingError::io(path, "cannot open", &e))?;
        let zip = ZipArchive::new(BufReader::new(file)).map_err(|e| {
            RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("not a readable zip archive ({e})"),
            )
            .with_fix("the file is truncated or damaged; copy it again from the instrument")
        })?;
        let mut curves: BTreeMap<usize, CurveLoc> = BTreeMap::new();
        let mut seg_sets: BTreeMap<(bool, usize), Vec<usize>> = BTreeMap::new();
        for name in zip.file_names() {
            if let Some((index, seg)) = parse_segment_header_name(name) {
                seg_sets
                    .entry((index.is_some(), index.unwrap_or(0)))
                    .or_default()
                    .push(seg);
            }
        }
        let is_map = seg_sets.keys().any(|(m, _)| *m);
        if is_map && seg_sets.keys().any(|(m, _)| !*m) {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                "the archive mixes a single curve (segments/) and a map (index/)",
            ));
        }
        for ((_, index), mut segs) in seg_sets {
            segs.sort_unstable();
            for (i, s) in segs.iter().enumerate() {
                if *s != i {
                    let prefix = if is_map {
                        format!("index/{index}/")
                    } else {
                        String::new()
                    };
                    return Err(RecordingError::new(
                        path,
                        ErrorKind::Vendor,
                        format!("segment {i} is missing while segment {s} exists"),
                    )
                    .in_entry(format!("{prefix}segments/{i}/segment-header.properties")));
                }
            }
            let prefix = if is_map {
                format!("index/{index}/")
            } else {
                String::new()
            };
            curves.insert(
                index,
                CurveLoc {
                    prefix,
                    segments: segs.len(),
                },
            );
        }
        let mut archive = JpkArchive {
            path: path.to_path_buf(),
            format,
            opts: *opts,
            zip,
            general: Properties::default(),
            shared: None,
            curves,
            is_map,
        };
        let members = archive.member_summary();
        archive.general = archive.properties("header.properties")?.ok_or_else(|| {
            // A zip of another vendor's exports (AFM Workshop's maps are zips of its CSVs)
            // is named for what it holds, not blamed on JPK.
            let jpk_like = archive.is_map || !archive.curves.is_empty();
            let (what, fix) = if jpk_like {
                (
                    "the archive has no header.properties".to_string(),
                    "this is not a complete JPK file; export it again".to_string(),
                )
            } else {
                (
                    format!("a zip archive without JPK's header.properties: it holds {members}"),
                    "import reads JPK archives; unzip it and import its files one by one \
                     (AFM Workshop .csv, NT-MDT .txt)"
                        .to_string(),
                )
            };
            RecordingError::new(path, ErrorKind::Vendor, what).with_fix(fix)
        })?;
        archive.shared = archive.properties("shared-data/header.properties")?;
        if archive.curves.is_empty() {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                "the archive holds no segments (no segments/N/segment-header.properties)",
            ));
        }
        // Check up front what the contract needs, from the first curve, so one message names
        // every missing flag before any work is done.
        let first = archive.curves.keys().next().copied().unwrap_or(0);
        let (k_file, sens_file) = archive.calibration(first)?;
        let mut warnings = Vec::new();
        let mut missing = Vec::new();
        resolve(
            &NEED_K,
            opts.spring_constant_n_per_m,
            k_file,
            "N/m",
            &mut warnings,
            &mut missing,
        );
        resolve(
            &NEED_SENS,
            opts.sensitivity_m_per_unit,
            sens_file,
            "m/V",
            &mut warnings,
            &mut missing,
        );
        resolve(
            &NEED_R,
            opts.tip_radius_m,
            None,
            "m",
            &mut warnings,
            &mut missing,
        );
        if !missing.is_empty() {
            return Err(missing_error(path, &missing));
        }
        Ok(archive)
    }

    /// Curve numbers (0 for a single curve; the `index/I` numbers of a map).
    pub fn curves(&self) -> Vec<usize> {
        self.curves.keys().copied().collect()
    }

    /// Reads a member whole, at most `limit` bytes; `None` when absent.
    fn member(&mut self, name: &str, limit: u64) -> Result<Option<Vec<u8>>> {
        let path = self.path.clone();
        let mut f = match self.zip.by_name(name) {
            Ok(f) => f,
            Err(zip::result::ZipError::FileNotFound) => return Ok(None),
            Err(e) => {
                return Err(RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("cannot read the member ({e})"),
                )
                .in_entry(name))
            }
        };
        let mut buf = Vec::new();
        (&mut f)
            .take(limit + 1)
            .read_to_end(&mut buf)
            .map_err(|e| {
                RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("cannot decompress the member ({e})"),
                )
                .in_entry(name)
            })?;
        if buf.len() as u64 > limit {
            return Err(RecordingError::new(
                &path,
                ErrorKind::Vendor,
                format!("member larger than {limit} bytes"),
            )
            .in_entry(name));
        }
        Ok(Some(buf))
    }

    /// "N files: a, b, c, …" of the archive, for an error that says what it holds.
    fn member_summary(&self) -> String {
        let names: Vec<&str> = self.zip.file_names().collect();
        let mut shown: Vec<&str> = names.clone();
        shown.sort_unstable();
        let list = shown.iter().take(3).copied().collect::<Vec<_>>().join(", ");
        let more = if names.len() > 3 { ", …" } else { "" };
        format!("{} file(s): {list}{more}", names.len())
    }

    fn properties(&mut self, name: &str) -> Result<Option<Properties>> {
        Ok(self
            .member(name, MAX_PROPERTIES_BYTES)?
            .map(|b| Properties::parse(&b)))
    }

    fn loc(&self, curve: usize) -> Result<CurveLoc> {
        self.curves.get(&curve).cloned().ok_or_else(|| {
            let have: Vec<String> = self.curves.keys().map(|c| c.to_string()).collect();
            RecordingError::new(
                &self.path,
                ErrorKind::Usage,
                format!("there is no curve {curve} in this file"),
            )
            .with_fix(format!("choose --curve among {}", abbreviate(&have)))
        })
    }

    /// The curve header (maps) or `None` (single curve: the file header plays that role).
    fn curve_header(&mut self, loc: &CurveLoc) -> Result<Option<(String, Properties)>> {
        if loc.prefix.is_empty() {
            return Ok(None);
        }
        let name = format!("{}header.properties", loc.prefix);
        match self.properties(&name)? {
            Some(p) => Ok(Some((name, p))),
            None => Err(RecordingError::new(
                &self.path,
                ErrorKind::Vendor,
                "the curve has no header.properties",
            )
            .in_entry(name)),
        }
    }

    /// The merged properties of one segment.
    fn segment_layers(
        &mut self,
        loc: &CurveLoc,
        seg: usize,
        curve_header: &Option<(String, Properties)>,
    ) -> Result<Layers> {
        let entry = format!("{}segments/{seg}/segment-header.properties", loc.prefix);
        let seg_props = self.properties(&entry)?.ok_or_else(|| {
            RecordingError::new(&self.path, ErrorKind::Vendor, "missing segment header")
                .in_entry(entry.clone())
        })?;
        let mut expanded = Properties::default();
        let shared_name = "shared-data/header.properties".to_string();
        let mut sources: Vec<(&str, &Properties)> = vec![(entry.as_str(), &seg_props)];
        if let Some((n, p)) = curve_header {
            sources.push((n.as_str(), p));
        }
        for (src_entry, props) in sources {
            for key in props.keys() {
                let Some(head) = key.strip_suffix(".*") else {
                    continue;
                };
                let Some((headkey, mediator)) = head.rsplit_once('.') else {
                    continue;
                };
                let (index, line) = props.get_with_line(key).unwrap_or(("", 0));
                let Some(shared) = &self.shared else {
                    return Err(RecordingError::new(
                        &self.path,
                        ErrorKind::Vendor,
                        format!(
                            "`{key}` refers to shared-data/header.properties, which the archive lacks"
                        ),
                    )
                    .in_entry(src_entry)
                    .at_line(line));
                };
                let start = format!("{mediator}.{}.", index.trim());
                let mut found = false;
                for k2 in shared.keys() {
                    if let Some(rest) = k2.strip_prefix(&start) {
                        let (v, l) = shared.get_with_line(k2).unwrap_or(("", 0));
                        expanded.insert(format!("{headkey}.{rest}"), v.to_string(), l);
                        found = true;
                    }
                }
                if !found {
                    return Err(RecordingError::new(
                        &self.path,
                        ErrorKind::Vendor,
                        format!(
                            "`{key}={index}` refers to `{start}*` keys that shared-data/header.properties lacks"
                        ),
                    )
                    .in_entry(src_entry)
                    .at_line(line));
                }
            }
        }
        let mut layers = vec![(entry.clone(), seg_props), (shared_name, expanded)];
        if let Some((n, p)) = curve_header {
            layers.push((n.clone(), p.clone()));
        }
        layers.push(("header.properties".into(), self.general.clone()));
        Ok(Layers { layers, entry })
    }

    /// The file's spring constant and sensitivity for a curve (first segment), if declared.
    fn calibration(&mut self, curve: usize) -> Result<(Option<f64>, Option<f64>)> {
        let loc = self.loc(curve)?;
        let ch = self.curve_header(&loc)?;
        let layers = self.segment_layers(&loc, 0, &ch)?;
        let chain = |slot: &str| conversion_chain(&self.path, &layers, DEFLECTION, slot);
        let k = match chain("force") {
            Ok((steps, unit)) if unit == "N" => steps.last().map(|s| s.0),
            _ => None,
        };
        let sens = match chain("distance") {
            Ok((steps, unit)) if unit == "m" && steps.len() == 1 => steps.first().map(|s| s.0),
            _ => None,
        };
        Ok((k, sens))
    }

    /// Reads one curve as a recording.
    pub fn read_curve(&mut self, curve: usize, warnings: &mut Vec<String>) -> Result<Recording> {
        let loc = self.loc(curve)?;
        let path = self.path.clone();
        let ch = self.curve_header(&loc)?;
        let mut segments = Vec::with_capacity(loc.segments);
        let mut all_layers = Vec::with_capacity(loc.segments);
        for s in 0..loc.segments {
            all_layers.push(self.segment_layers(&loc, s, &ch)?);
        }
        // The measured-height channel: the first candidate every segment has.
        let measured = MEASURED_CHANNELS.iter().copied().find(|c| {
            all_layers
                .iter()
                .all(|l| channel_list(l).iter().any(|x| x == c))
        });
        for (s, layers) in all_layers.iter().enumerate() {
            segments.push(self.read_segment(&loc, s, layers, measured, warnings)?);
        }
        let series = if self.is_map {
            ch.as_ref().map(|(_, p)| p)
        } else {
            Some(&self.general)
        };
        if let Some(declared) = series.and_then(|p| {
            [
                "force-scan-series.force-segments.count",
                "quantitative-imaging-series.force-segments.count",
            ]
            .iter()
            .find_map(|k| p.get(k))
            .and_then(|v| v.trim().parse::<usize>().ok())
        }) {
            if declared != loc.segments {
                let w = format!(
                    "{}: the header declares {declared} segments, the archive holds {}; imported those present",
                    path.display(),
                    loc.segments
                );
                if !warnings.contains(&w) {
                    warnings.push(w);
                }
            }
        }

        // Calibration: the flag wins; the file's value comes from the first segment that has it.
        let k_file = segments.iter().find_map(|s| s.k_file);
        let sens_file = segments.iter().find_map(|s| s.sens_file);
        for s in &segments {
            for (what, a, b) in [
                ("spring constant", s.k_file, k_file),
                ("sensitivity", s.sens_file, sens_file),
            ] {
                if let (Some(a), Some(b)) = (a, b) {
                    if (a - b).abs() > 1e-12 * a.abs().max(b.abs()) {
                        return Err(RecordingError::new(
                            &path,
                            ErrorKind::Vendor,
                            format!("segments disagree on the {what} ({a} vs {b})"),
                        ));
                    }
                }
            }
        }
        let mut missing = Vec::new();
        let k = resolve(
            &NEED_K,
            self.opts.spring_constant_n_per_m,
            k_file,
            "N/m",
            warnings,
            &mut missing,
        );
        let sens = resolve(
            &NEED_SENS,
            self.opts.sensitivity_m_per_unit,
            sens_file,
            "m/V",
            warnings,
            &mut missing,
        );
        let r = resolve(
            &NEED_R,
            self.opts.tip_radius_m,
            None,
            "m",
            warnings,
            &mut missing,
        );
        let (Some((k, k_src)), Some((sens, sens_src)), Some((r, _))) = (k, sens, r) else {
            return Err(missing_error(&path, &missing));
        };

        let rate_of = |s: &Segment| s.points as f64 / s.duration_s;
        let nominal = segments
            .iter()
            .find(|s| s.style == "extend" && s.points > 0)
            .or_else(|| segments.iter().find(|s| s.points > 0))
            .map(|s| round_significant(rate_of(s), 12))
            .ok_or_else(|| {
                RecordingError::new(&path, ErrorKind::Vendor, "the curve holds no samples")
            })?;
        let mut meta = Metadata::new(Mode::ForceCurve, nominal, k, r);
        let total: usize = segments.iter().map(|s| s.points).sum();
        let mut rec = Recording::new(Metadata::new(Mode::ForceCurve, nominal, k, r));
        rec.t_s.reserve(total);
        let mut seg_col = Vec::with_capacity(total);
        let has_force = segments.iter().all(|s| s.force_n.is_some());
        let has_measured = segments.iter().all(|s| s.measured_m.is_some());
        let mut force = Vec::new();
        let mut piezo_col = Vec::new();
        let mut start_s = 0.0;
        for (i, s) in segments.iter().enumerate() {
            let dt = s.duration_s / s.points.max(1) as f64;
            for j in 0..s.points {
                rec.t_s.push(start_s + j as f64 * dt);
            }
            start_s += s.duration_s;
            // U: the z sensor when every segment has it, else the piezo drive (module docs).
            match (&s.measured_m, has_measured) {
                (Some(m), true) => {
                    rec.u_m.extend_from_slice(m);
                    piezo_col.extend_from_slice(&s.piezo_m);
                }
                _ => rec.u_m.extend_from_slice(&s.piezo_m),
            }
            // The contract's sign: D < 0 when the sample pushes the tip up (JPK: positive).
            match self.opts.sensitivity_m_per_unit {
                Some(_) => rec.d_m.extend(s.defl_m.iter().map(|v| -v * sens)),
                None => rec.d_m.extend(s.defl_m.iter().map(|v| -v)),
            }
            seg_col.extend(std::iter::repeat_n(i as f64, s.points));
            if has_force {
                force.extend_from_slice(s.force_n.as_deref().unwrap_or(&[]));
            }
        }
        rec.extra.push(Column {
            name: "segment".into(),
            values: seg_col,
        });
        if has_force {
            rec.extra.push(Column {
                name: "force_vendor_n".into(),
                values: force,
            });
        }
        if has_measured {
            rec.extra.push(Column {
                name: "height_piezo_m".into(),
                values: piezo_col,
            });
        }

        // Metadata.
        meta.set("source_file", path.display().to_string());
        meta.set("source_format", self.format.name());
        let top_prefixes = [
            "force-scan-series",
            "force-scan-map",
            "quantitative-imaging-map",
            "quantitative-imaging-series",
        ];
        let g = |suffix: &str| {
            top_prefixes
                .iter()
                .find_map(|p| self.general.get(&format!("{p}.{suffix}")))
                .map(str::trim)
                .filter(|v| !v.is_empty())
                .map(str::to_string)
        };
        if let Some(v) = g("description.instrument") {
            meta.set("instrument", v);
        }
        if let Some(v) = g("description.source-software") {
            meta.set("vendor_software", format!("JPK {v}"));
        }
        if let Some(v) = self.general.get("file-format-version") {
            meta.set("jpk_file_format_version", v);
        }
        if self.is_map {
            meta.set("curve_index", curve.to_string());
        }
        let first = all_layers.first();
        let series_keys = |suffix: &str| -> Vec<String> {
            vec![
                format!("force-scan-series.header.{suffix}"),
                format!("quantitative-imaging-series.header.{suffix}"),
                format!("force-segment-header.{suffix}"),
            ]
        };
        if let Some(l) = first {
            if let Some(v) = l.first_str(&series_keys("position-index")) {
                meta.set("position_index", v);
            }
            for (axis, key) in [("x", "position_x_m"), ("y", "position_y_m")] {
                let mut v = l.first_f64(&path, &series_keys(&format!("position.{axis}")))?;
                if v.is_none() {
                    // Newer segment headers: environment.xy-scanner-position-map.xy-scanner.<name>.position.x
                    v = l.layers.first().and_then(|(_, p)| {
                        p.keys()
                            .find(|k| {
                                k.starts_with("force-segment-header.environment.xy-scanner-position-map.xy-scanner.")
                                    && k.ends_with(&format!(".position.{axis}"))
                            })
                            .and_then(|k| p.get(k))
                            .and_then(|s| s.trim().parse::<f64>().ok())
                    });
                }
                if let Some(v) = v.filter(|v| v.is_finite()) {
                    meta.set(key, num(v));
                }
            }
        }
        super::set_spring_constant_source(&mut meta, k_src, k_file);
        meta.set("sensitivity_m_per_v", num(sens));
        meta.set(
            "sensitivity_source",
            if sens_src == "flag" {
                "--sensitivity"
            } else {
                "file"
            },
        );
        meta.set("tip_radius_source", "--tip-radius");
        if let Some(sp) = segments
            .iter()
            .filter(|s| s.style == "extend")
            .find_map(|s| s.setpoint_v)
        {
            meta.set("setpoint_v", num(sp));
            meta.set("setpoint_n", num(sp * sens * k));
            let relative = top_prefixes.iter().any(|p| {
                [
                    format!("{p}.header.force-settings.type"),
                    format!("{p}.settings.force-settings.type"),
                ]
                .iter()
                .any(|key| {
                    first
                        .and_then(|l| l.str(key))
                        .is_some_and(|v| v.contains("relative"))
                })
            });
            meta.set("setpoint_relative", relative.to_string());
        }
        if let Some(b) = segments.iter().find_map(|s| s.baseline_v) {
            meta.set("baseline_v", num(b));
        }
        if let Some(t) = segments.iter().find_map(|s| s.time_stamp.clone()) {
            meta.set("start_time", t);
        }
        meta.set(
            "segments",
            segments
                .iter()
                .enumerate()
                .map(|(i, s)| format!("{i}={}", s.style))
                .collect::<Vec<_>>()
                .join(","),
        );
        meta.set(
            "segment_points",
            segments
                .iter()
                .map(|s| s.points.to_string())
                .collect::<Vec<_>>()
                .join(","),
        );
        meta.set(
            "segment_durations_s",
            num_list(&segments.iter().map(|s| s.duration_s).collect::<Vec<_>>()),
        );
        meta.set(
            "segment_rates_hz",
            num_list(
                &segments
                    .iter()
                    .map(|s| round_significant(rate_of(s), 12))
                    .collect::<Vec<_>>(),
            ),
        );
        match (has_measured, measured) {
            (true, Some(m)) => {
                meta.set("u_m_from", format!("{m} (nominal): the z sensor"));
                if let Some(s) = segments.first() {
                    meta.set(
                        "height_piezo_m_from",
                        format!("{}: the piezo drive", s.piezo_from),
                    );
                }
            }
            _ => {
                if let Some(s) = segments.first() {
                    meta.set(
                        "u_m_from",
                        format!("{}: the piezo drive (no z sensor)", s.piezo_from),
                    );
                }
            }
        }
        meta.set(
            "d_m_from",
            if self.opts.sensitivity_m_per_unit.is_some() {
                "-vDeflection (volts) × --sensitivity"
            } else {
                "-vDeflection (distance)"
            },
        );
        if has_force {
            meta.set(
                "force_vendor_n_from",
                "vDeflection (force); JPK sign: positive = repulsive",
            );
        }
        rec.meta = meta;
        check_recording(&path, &rec)?;
        Ok(rec)
    }

    fn read_segment(
        &mut self,
        loc: &CurveLoc,
        seg: usize,
        layers: &Layers,
        measured: Option<&str>,
        warnings: &mut Vec<String>,
    ) -> Result<Segment> {
        let path = self.path.clone();
        let points_key = "force-segment-header.num-points";
        let points = match layers.f64(&path, points_key)? {
            Some(p) if p >= 0.0 && p.fract() == 0.0 && p <= MAX_SEGMENT_POINTS as f64 => p as usize,
            Some(p) => {
                let (_, entry, line) = layers.get(points_key).unwrap_or(("", "", 0));
                return Err(RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("`{points_key}` = {p} is not a point count"),
                )
                .in_entry(entry)
                .at_line(line));
            }
            None => {
                return Err(RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("missing property `{points_key}`"),
                )
                .in_entry(layers.entry.clone()))
            }
        };
        let duration_s = layers.finite(&path, "force-segment-header.duration")?;
        if points > 0 && duration_s <= 0.0 {
            let (_, entry, line) = layers
                .get("force-segment-header.duration")
                .unwrap_or(("", "", 0));
            return Err(RecordingError::new(
                &path,
                ErrorKind::Vendor,
                format!("segment duration {duration_s} s is not positive"),
            )
            .in_entry(entry)
            .at_line(line));
        }
        let style_raw = layers
            .str("force-segment-header.settings.style")
            .or_else(|| layers.str("force-segment-header.settings.segment-settings.style"))
            .map(str::to_string)
            .or_else(|| {
                layers.str("force-segment-header.name.name").and_then(|n| {
                    ["extend", "retract", "pause"]
                        .into_iter()
                        .find(|s| n.starts_with(s))
                        .map(str::to_string)
                })
            })
            .unwrap_or_else(|| "unknown".into());
        let style: String = style_raw
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
            .collect();
        let style = if style.is_empty() {
            "unknown".into()
        } else {
            style
        };

        let list = channel_list(layers);
        let seg_dir = format!("{}segments/{seg}/", loc.prefix);
        let height = HEIGHT_CHANNELS
            .iter()
            .copied()
            .find(|c| list.iter().any(|x| x == c))
            .ok_or_else(|| {
                RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    "the segment has no piezo height channel (`height` or `head-height` in channels.list)",
                )
                .in_entry(layers.entry.clone())
            })?;
        if !list.iter().any(|x| x == DEFLECTION) {
            return Err(RecordingError::new(
                &path,
                ErrorKind::Vendor,
                "the segment has no vDeflection channel in channels.list",
            )
            .in_entry(layers.entry.clone()));
        }

        let mut piezo_m = self.read_channel(&seg_dir, layers, height, points)?;
        let u_slot = ["calibrated", "nominal"]
            .into_iter()
            .find(|slot| {
                matches!(conversion_chain(&path, layers, height, slot), Ok((_, u)) if u == "m")
            })
            .ok_or_else(|| {
                RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("channel `{height}` has no calibrated or nominal conversion to metres"),
                )
                .in_entry(layers.entry.clone())
            })?;
        apply_chain(&path, layers, height, u_slot, &mut piezo_m)?;

        let volts = self.read_channel(&seg_dir, layers, DEFLECTION, points)?;
        let dist_chain = conversion_chain(&path, layers, DEFLECTION, "distance");
        let force_chain = conversion_chain(&path, layers, DEFLECTION, "force");
        let k_file = match &force_chain {
            Ok((steps, unit)) if unit == "N" => steps.last().map(|s| s.0),
            _ => None,
        };
        let sens_file = match &dist_chain {
            Ok((steps, unit)) if unit == "m" && steps.len() == 1 => steps.first().map(|s| s.0),
            _ => None,
        };
        // With --sensitivity the importer scales volts itself (read_curve); otherwise the
        // file's distance slot gives metres.
        let defl_m = if self.opts.sensitivity_m_per_unit.is_some() {
            volts.clone()
        } else {
            let mut d = volts.clone();
            match &dist_chain {
                Ok((_, unit)) if unit == "m" => {
                    apply_chain(&path, layers, DEFLECTION, "distance", &mut d)?
                }
                Ok((_, unit)) => {
                    return Err(RecordingError::new(
                        &path,
                        ErrorKind::Vendor,
                        format!("vDeflection distance slot is in `{unit}`, not metres"),
                    )
                    .in_entry(layers.entry.clone()))
                }
                Err(e) => {
                    let mut e = e.clone();
                    e.kind = ErrorKind::MissingValue;
                    e.fix = Some("pass --sensitivity M_PER_V".into());
                    return Err(e);
                }
            }
            d
        };
        let force_n = match &force_chain {
            Ok((_, unit)) if unit == "N" => {
                let mut f = volts;
                apply_chain(&path, layers, DEFLECTION, "force", &mut f)?;
                Some(f)
            }
            _ => None,
        };
        let measured_m = match measured {
            Some(m) => {
                let mut v = self.read_channel(&seg_dir, layers, m, points)?;
                match conversion_chain(&path, layers, m, "nominal") {
                    Ok((_, unit)) if unit == "m" => {
                        apply_chain(&path, layers, m, "nominal", &mut v)?;
                        Some(v)
                    }
                    _ => {
                        let w = format!(
                            "{}: channel {m} has no nominal slot in metres; not imported",
                            path.display()
                        );
                        if !warnings.contains(&w) {
                            warnings.push(w);
                        }
                        None
                    }
                }
            }
            None => None,
        };
        let setpoint_v = layers
            .f64(
                &path,
                "force-segment-header.settings.segment-settings.setpoint",
            )?
            .filter(|v| v.is_finite());
        let baseline_v = layers
            .f64(&path, "force-segment-header.baseline.baseline")?
            .filter(|v| v.is_finite());
        let piezo_from = format!("{height} ({u_slot})");
        Ok(Segment {
            style,
            points,
            duration_s,
            piezo_m,
            defl_m,
            force_n,
            measured_m,
            k_file,
            sens_file,
            setpoint_v,
            baseline_v,
            time_stamp: layers
                .str("force-segment-header.time-stamp")
                .map(str::to_string),
            piezo_from,
        })
    }

    /// Reads a channel's samples in its base unit (encoder scaling applied).
    fn read_channel(
        &mut self,
        seg_dir: &str,
        layers: &Layers,
        channel: &str,
        points: usize,
    ) -> Result<Vec<f64>> {
        let path = self.path.clone();
        let c = |s: &str| format!("channel.{channel}.{s}");
        let file = layers
            .req_str(&path, &c("data.file.name"))?
            .trim()
            .to_string();
        if let Some(fmt) = layers.str(&c("data.file.format")) {
            if fmt.trim() != "raw" {
                return Err(RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("channel {channel}: data format `{fmt}` is not supported (only raw)"),
                )
                .in_entry(layers.entry.clone()));
            }
        }
        if let Some(n) = layers.f64(&path, &c("data.num-points"))? {
            if n != points as f64 {
                return Err(RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("channel {channel} declares {n} points, the segment {points}"),
                )
                .in_entry(layers.entry.clone()));
            }
        }
        let enc_type = layers.first_str(&[c("data.encoder.type"), c("encoder.type")]);
        let data_type = layers.first_str(&[c("data.type"), c("type")]).unwrap_or("");
        let (raw, scale) = match enc_type.map(str::trim) {
            Some(enc) => {
                let raw = match enc {
                    "signedshort" => Raw::I16,
                    "unsignedshort" => Raw::U16,
                    "signedinteger" => Raw::I32,
                    "unsignedinteger" => Raw::U32,
                    "signedlong" => Raw::I64,
                    "float" | "float-data" => Raw::F32,
                    "double" | "double-data" => Raw::F64,
                    other => {
                        return Err(RecordingError::new(
                            &path,
                            ErrorKind::Vendor,
                            format!("channel {channel}: encoder `{other}` is not supported"),
                        )
                        .in_entry(layers.entry.clone()))
                    }
                };
                let prefix = if layers.str(&c("data.encoder.type")).is_some() {
                    "data.encoder.scaling"
                } else {
                    "encoder.scaling"
                };
                if let Some(style) = layers.str(&c(&format!("{prefix}.style"))) {
                    if style.trim() != "offsetmultiplier" {
                        return Err(RecordingError::new(
                            &path,
                            ErrorKind::Vendor,
                            format!("channel {channel}: scaling style `{style}` is not supported"),
                        )
                        .in_entry(layers.entry.clone()));
                    }
                }
                let off = layers.finite(&path, &c(&format!("{prefix}.offset")))?;
                let mul = layers.finite(&path, &c(&format!("{prefix}.multiplier")))?;
                (raw, Some((mul, off)))
            }
            None => {
                let raw = match data_type.trim() {
                    "float" | "float-data" => Raw::F32,
                    "double" | "double-data" => Raw::F64,
                    other => {
                        return Err(RecordingError::new(
                            &path,
                            ErrorKind::Vendor,
                            format!("channel {channel}: no encoder for data type `{other}`"),
                        )
                        .in_entry(layers.entry.clone()))
                    }
                };
                (raw, None)
            }
        };
        let member = format!("{seg_dir}{file}");
        let expected = points.saturating_mul(raw.width());
        let bytes = self.member(&member, expected as u64)?.ok_or_else(|| {
            RecordingError::new(
                &path,
                ErrorKind::Vendor,
                "the data file named in the header is missing",
            )
            .in_entry(member.clone())
        })?;
        if bytes.len() != expected {
            return Err(RecordingError::new(
                &path,
                ErrorKind::Vendor,
                format!(
                    "holds {} bytes, the header says {points} points of {} bytes",
                    bytes.len(),
                    raw.width()
                ),
            )
            .in_entry(member));
        }
        let mut out = Vec::with_capacity(points);
        for (i, chunk) in bytes.chunks_exact(raw.width()).enumerate() {
            let v = raw.decode(chunk);
            let v = match scale {
                Some((mul, off)) => v * mul + off,
                None => v,
            };
            if !v.is_finite() {
                return Err(RecordingError::new(
                    &path,
                    ErrorKind::Vendor,
                    format!("sample {i} is not a finite number"),
                )
                .in_entry(member));
            }
            out.push(v);
        }
        Ok(out)
    }
}

/// `(multiplier, offset)` steps from the base slot to `slot` (in application order) and the
/// unit of `slot`.
fn conversion_chain(
    path: &Path,
    layers: &Layers,
    channel: &str,
    slot: &str,
) -> Result<(Vec<(f64, f64)>, String)> {
    let set = format!("channel.{channel}.conversion-set");
    let base = layers
        .req_str(path, &format!("{set}.conversions.base"))?
        .trim()
        .to_string();
    let mut steps = Vec::new();
    let mut cur = slot.to_string();
    let mut unit: Option<String> = None;
    while cur != base {
        if steps.len() > 16 {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("channel {channel}: conversion chain to `{slot}` loops"),
            )
            .in_entry(layers.entry.clone()));
        }
        let conv = format!("{set}.conversion.{cur}");
        if layers.str(&format!("{conv}.defined")).map(str::trim) != Some("true") {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!("channel {channel}: calibration slot `{cur}` is not defined"),
            )
            .in_entry(layers.entry.clone()));
        }
        if let Some(style) = layers.str(&format!("{conv}.scaling.style")) {
            if style.trim() != "offsetmultiplier" {
                return Err(RecordingError::new(
                    path,
                    ErrorKind::Vendor,
                    format!(
                        "channel {channel}: scaling style `{style}` of `{cur}` is not supported"
                    ),
                )
                .in_entry(layers.entry.clone()));
            }
        }
        let mul = layers.finite(path, &format!("{conv}.scaling.multiplier"))?;
        let off = layers.finite(path, &format!("{conv}.scaling.offset"))?;
        if unit.is_none() {
            unit = layers
                .first_str(&[
                    format!("{conv}.scaling.unit.unit"),
                    format!("{conv}.scaling.unit"),
                ])
                .map(|u| u.trim().to_string());
        }
        steps.push((mul, off));
        cur = layers
            .req_str(path, &format!("{conv}.base-calibration-slot"))?
            .trim()
            .to_string();
    }
    steps.reverse();
    Ok((steps, unit.unwrap_or_default()))
}

fn apply_chain(
    path: &Path,
    layers: &Layers,
    channel: &str,
    slot: &str,
    v: &mut [f64],
) -> Result<()> {
    let (steps, _) = conversion_chain(path, layers, channel, slot)?;
    for x in v.iter_mut() {
        for (mul, off) in &steps {
            *x = *x * mul + off;
        }
    }
    Ok(())
}

fn channel_list(layers: &Layers) -> Vec<String> {
    layers
        .str("channels.list")
        .map(|l| l.split_whitespace().map(str::to_string).collect())
        .unwrap_or_default()
}

/// `segments/N/segment-header.properties` → (None, N); `index/I/segments/N/...` → (Some(I), N).
fn parse_segment_header_name(name: &str) -> Option<(Option<usize>, usize)> {
    let (index, rest) = match name.strip_prefix("index/") {
        Some(r) => {
            let (i, rest) = r.split_once('/')?;
            (Some(i.parse::<usize>().ok()?), rest)
        }
        None => (None, name),
    };
    let seg = rest
        .strip_prefix("segments/")?
        .strip_suffix("/segment-header.properties")?;
    Some((index, seg.parse::<usize>().ok()?))
}

/// Rounds to `digits` significant digits: a rate of 2000 points in 0.9999999999999998 s is
/// 2000 Hz, not 2000.0000000000005 Hz. (Nominal values only; `t_s` keeps the exact grid.)
fn round_significant(v: f64, digits: usize) -> f64 {
    format!("{v:.*e}", digits.saturating_sub(1))
        .parse::<f64>()
        .unwrap_or(v)
}

fn abbreviate(items: &[String]) -> String {
    if items.len() <= 8 {
        items.join(", ")
    } else {
        format!(
            "{}, ..., {}",
            items[..4].join(", "),
            items[items.len() - 2..].join(", ")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segment_names() {
        assert_eq!(
            parse_segment_header_name("segments/3/segment-header.properties"),
            Some((None, 3))
        );
        assert_eq!(
            parse_segment_header_name("index/12/segments/0/segment-header.properties"),
            Some((Some(12), 0))
        );
        assert_eq!(
            parse_segment_header_name("segments/x/segment-header.properties"),
            None
        );
        assert_eq!(
            parse_segment_header_name("index//segments/0/segment-header.properties"),
            None
        );
    }

    #[test]
    fn raw_decoding_is_big_endian() {
        assert_eq!(Raw::I16.decode(&[0xff, 0xfe]), -2.0);
        assert_eq!(Raw::U16.decode(&[0x01, 0x00]), 256.0);
        assert_eq!(Raw::I32.decode(&[0x80, 0, 0, 0]), f64::from(i32::MIN));
        assert_eq!(Raw::F32.decode(&1.5f32.to_be_bytes()), 1.5);
        assert_eq!(Raw::F64.decode(&(-2.25f64).to_be_bytes()), -2.25);
        // Short input never panics.
        assert_eq!(
            Raw::I32.decode(&[1]),
            f64::from(i32::from_be_bytes([1, 0, 0, 0]))
        );
    }
}
