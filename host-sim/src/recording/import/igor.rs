//! Asylum Research force curves: Igor Pro binary waves (`.ibw`, version 5), as the Asylum
//! software saves one curve per file.
//!
//! The file (Igor Technical Note 003): a 64-byte binary header (version 5, the byte order told
//! by it: little-endian from Windows, big-endian from classic Macs; the sizes of the wave, the
//! formula, the note and the dimension labels), a 320-byte wave header (points per dimension,
//! the number type, the first dimension's step), the data, the formula, the note and the
//! labels. A force curve is a 2-D wave: rows are samples (the step is the sample interval, s),
//! columns are channels named by the second dimension's labels (31 characters each): `Raw`
//! (the piezo's height, m), `Defl` (deflection, m: the raw signal times `InvOLS`), `ZSnsr` (the
//! z sensor, m). Both heights grow as the piezo extends towards the sample. The note is
//! `Key:Value` lines separated by carriage returns; read here: `SpringConstant` (N/m), `InvOLS`
//! (m/V), `NumPtsPerSec` (Hz), `Indexes` (the rows where segments end, from 0) and `Direction`
//! (per segment: 1 towards the sample, −1 away, 0 a dwell), plus the thermal tune and the
//! instrument for the metadata.
//!
//! Signals: U = −ZSnsr (z up; −Raw where there is no sensor), D = −Defl (Asylum's deflection
//! is positive when the sample pushes the lever up), t from the wave's step. Extra columns:
//! `segment`, `height_piezo_m` = −Raw when a sensor gives U. The file's thermal tune (f₀, Q,
//! usually in air) is kept as `asylum_thermal_*` metadata, not as the contract's
//! `cantilever_f0_hz`/`cantilever_q`: the lever's resonance in the measuring liquid differs.
//!
//! Metadata written: `source_file`, `source_format`, `instrument`, `vendor_software`,
//! `spring_constant_source`, `spring_constant_file_n_per_m`, `sensitivity_m_per_v`,
//! `tip_radius_source`, `segments`, `segment_points`, `start_time`, `asylum_wave`,
//! `asylum_thermal_frequency_hz`, `asylum_thermal_q`, `u_m_from`, `d_m_from`.

use std::path::Path;

use super::{check_recording, missing_error, num, resolve, ImportOptions, NEED_K, NEED_R};
use crate::recording::csv::read_text_limited;
use crate::recording::error::{ErrorKind, RecordingError, Result};
use crate::recording::{Column, Metadata, Mode, Recording};

const MAX_BYTES: u64 = 512 << 20;
/// Sizes of the version-5 headers.
const BIN_HEADER: usize = 64;
const WAVE_HEADER: usize = 320;
/// Bytes per dimension label (31 characters and a NUL).
const LABEL: usize = 32;

/// The start of an Igor binary wave of version 5, in either byte order.
pub fn is_ibw5(head: &[u8]) -> bool {
    matches!(head.get(..2), Some([5, 0]) | Some([0, 5]))
}

/// Reads the header's numbers in the file's byte order.
struct Reader<'a> {
    bytes: &'a [u8],
    little: bool,
}

impl Reader<'_> {
    fn slice(&self, at: usize, len: usize) -> Option<&[u8]> {
        self.bytes.get(at..at.checked_add(len)?)
    }
    fn i16(&self, at: usize) -> Option<i16> {
        let b: [u8; 2] = self.slice(at, 2)?.try_into().ok()?;
        Some(if self.little {
            i16::from_le_bytes(b)
        } else {
            i16::from_be_bytes(b)
        })
    }
    fn i32(&self, at: usize) -> Option<i32> {
        let b: [u8; 4] = self.slice(at, 4)?.try_into().ok()?;
        Some(if self.little {
            i32::from_le_bytes(b)
        } else {
            i32::from_be_bytes(b)
        })
    }
    fn f64(&self, at: usize) -> Option<f64> {
        let b: [u8; 8] = self.slice(at, 8)?.try_into().ok()?;
        Some(if self.little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        })
    }
    /// Element `i` of the data (type 2: f32, type 4: f64) starting at `at`.
    fn value(&self, at: usize, wide: bool, i: usize) -> Option<f64> {
        if wide {
            self.f64(at.checked_add(i.checked_mul(8)?)?)
        } else {
            let b: [u8; 4] = self
                .slice(at.checked_add(i.checked_mul(4)?)?, 4)?
                .try_into()
                .ok()?;
            Some(f64::from(if self.little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            }))
        }
    }
    fn size(&self, at: usize, what: &str, path: &Path) -> Result<usize> {
        self.i32(at)
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| {
                vendor(
                    path,
                    format!("the binary header's {what} size is not readable"),
                )
            })
    }
}

fn vendor(path: &Path, reason: impl Into<String>) -> RecordingError {
    RecordingError::new(path, ErrorKind::Vendor, reason)
}

/// The note's `Key:Value` lines.
fn note_value<'a>(note: &'a str, key: &str) -> Option<&'a str> {
    note.split(['\r', '\n'])
        .filter_map(|l| l.split_once(':'))
        .find(|(k, _)| k.trim() == key)
        .map(|(_, v)| v.trim())
}

fn note_number(note: &str, key: &str) -> Option<f64> {
    note_value(note, key)
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite())
}

/// Imports one Asylum force curve.
pub fn import(path: &Path, opts: &ImportOptions, warnings: &mut Vec<String>) -> Result<Recording> {
    let bytes = read_text_limited(path, MAX_BYTES)?;
    let little = match bytes.get(..2) {
        Some([5, 0]) => true,
        Some([0, 5]) => false,
        Some([a, b]) => {
            let v = u16::from_le_bytes([*a, *b]).min(u16::from_be_bytes([*a, *b]));
            return Err(vendor(
                path,
                format!("an Igor binary wave of version {v}; import reads version 5 (Asylum's)"),
            ));
        }
        _ => return Err(vendor(path, "empty file")),
    };
    let rd = Reader {
        bytes: &bytes,
        little,
    };
    let wfm = rd.size(4, "wave", path)?;
    let formula = rd.size(8, "formula", path)?;
    let note_len = rd.size(12, "note", path)?;
    let data_units = rd.size(16, "data units", path)?;
    let mut dim_units = 0usize;
    let mut dim_labels = [0usize; 4];
    for (d, label) in dim_labels.iter_mut().enumerate() {
        dim_units += rd.size(20 + 4 * d, "dimension units", path)?;
        *label = rd.size(36 + 4 * d, "dimension labels", path)?;
    }
    let wh = BIN_HEADER;
    let kind = rd.i16(wh + 16).unwrap_or(0);
    let wide = match kind {
        2 => false,
        4 => true,
        k => {
            return Err(vendor(
                path,
                format!("the wave's number type {k} is not 32- or 64-bit floating point"),
            ))
        }
    };
    let dims: Vec<usize> = (0..4)
        .map(|d| {
            rd.i32(wh + 68 + 4 * d)
                .and_then(|v| usize::try_from(v).ok())
        })
        .collect::<Option<_>>()
        .ok_or_else(|| vendor(path, "the wave header's dimensions are not readable"))?;
    let (rows, cols) = (dims[0], dims[1]);
    if rows < 2 || cols < 2 || dims[2] > 1 {
        return Err(vendor(
            path,
            format!(
                "a wave of {rows} × {cols} × {} points, not a force curve (samples × channels)",
                dims[2]
            ),
        ));
    }
    let step = rd.f64(wh + 84).filter(|s| *s > 0.0 && s.is_finite());
    let name: String = rd
        .slice(wh + 28, 32)
        .map(|b| {
            b.iter()
                .take_while(|c| **c != 0)
                .map(|c| *c as char)
                .collect()
        })
        .unwrap_or_default();
    let data_at = BIN_HEADER + WAVE_HEADER;
    let n_points = rows
        .checked_mul(cols)
        .ok_or_else(|| vendor(path, "the wave's size overflows"))?;
    let data_len = n_points
        .checked_mul(if wide { 8 } else { 4 })
        .ok_or_else(|| vendor(path, "the wave's size overflows"))?;
    if WAVE_HEADER
        .checked_add(data_len)
        .is_none_or(|need| wfm < need)
    {
        return Err(vendor(
            path,
            format!("the binary header's wave size {wfm} is smaller than its {n_points} points"),
        ));
    }
    let note_at = (wfm - WAVE_HEADER)
        .checked_add(data_at + formula)
        .ok_or_else(|| vendor(path, "the wave's size overflows"))?;
    let note_bytes = rd
        .slice(note_at, note_len)
        .ok_or_else(|| vendor(path, "the file ends inside the wave's note (truncated?)"))?;
    // The note is written in the system's 8-bit encoding: Latin-1 maps every byte.
    let note: String = note_bytes.iter().map(|b| *b as char).collect();
    let labels_at = [note_len, data_units, dim_units, dim_labels[0]]
        .iter()
        .try_fold(note_at, |a, b| a.checked_add(*b))
        .ok_or_else(|| vendor(path, "the wave's size overflows"))?;
    let labels: Vec<String> = (0..cols)
        .map(|c| {
            rd.slice(labels_at.checked_add(LABEL * (c + 1))?, LABEL)
                .map(|b| {
                    b.iter()
                        .take_while(|c| **c != 0)
                        .map(|c| *c as char)
                        .collect()
                })
        })
        .collect::<Option<_>>()
        .filter(|_| dim_labels[1] >= LABEL * (cols + 1))
        .ok_or_else(|| {
            vendor(
                path,
                "the wave has no channel labels (Raw, Defl, ZSnsr): not an Asylum force curve",
            )
        })?;
    let column = |names: &[&str]| labels.iter().position(|l| names.contains(&l.as_str()));
    let defl = column(&["Defl", "Deflection"]).ok_or_else(|| {
        vendor(
            path,
            format!("no deflection channel (Defl) among {}", labels.join(", ")),
        )
    })?;
    let sensor = column(&["ZSnsr", "ZSensor"]);
    let piezo = column(&["Raw", "Height"]);
    let Some(u_col) = sensor.or(piezo) else {
        return Err(vendor(
            path,
            format!(
                "no height channel (ZSnsr or Raw) among {}",
                labels.join(", ")
            ),
        ));
    };
    let read = |c: usize| -> Result<Vec<f64>> {
        (0..rows)
            .map(|i| rd.value(data_at, wide, c * rows + i))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| vendor(path, "the file ends inside the wave's data (truncated?)"))
    };

    let mut missing = Vec::new();
    let k_file = note_number(&note, "SpringConstant").filter(|k| *k > 0.0);
    let k = resolve(
        &NEED_K,
        opts.spring_constant_n_per_m,
        k_file,
        "N/m",
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
    let (Some((k, k_src)), Some((r, _))) = (k, r) else {
        return Err(missing_error(path, &missing));
    };
    if opts.sensitivity_m_per_unit.is_some() {
        warnings.push(
            "--sensitivity is not used: an Asylum wave stores the deflection in metres \
             (its InvOLS applied)"
                .to_string(),
        );
    }
    let rate_note = note_number(&note, "NumPtsPerSec").filter(|r| *r > 0.0);
    let dt = match (step, rate_note) {
        (Some(s), _) => s,
        (None, Some(rate)) => 1.0 / rate,
        (None, None) => {
            return Err(vendor(
                path,
                "neither the wave's step nor the note's NumPtsPerSec gives the sample interval",
            ))
        }
    };
    if let Some(rate) = rate_note {
        if (rate * dt - 1.0).abs() > 1e-3 {
            warnings.push(format!(
                "the note's NumPtsPerSec {rate} Hz disagrees with the wave's step {dt} s; the step is used"
            ));
        }
    }
    // Segments: `Indexes` are the rows where each ends (the first entry 0), `Direction` their
    // sense (its first entry belongs to that 0).
    let ends: Vec<usize> = note_value(&note, "Indexes")
        .map(|v| {
            v.split(',')
                .filter(|s| !s.trim().is_empty())
                .filter_map(|s| s.trim().parse::<f64>().ok())
                .filter(|x| *x >= 0.0)
                .map(|x| x as usize)
                .collect()
        })
        .unwrap_or_default();
    let sense: Vec<f64> = note_value(&note, "Direction")
        .map(|v| {
            v.split(',')
                .filter(|s| !s.trim().is_empty())
                .map(|s| s.trim().parse::<f64>().unwrap_or(f64::NAN))
                .collect()
        })
        .unwrap_or_default();
    let well_formed = ends.len() >= 2
        && ends.first() == Some(&0)
        && ends.windows(2).all(|w| w[0] < w[1])
        && ends.last().is_some_and(|e| *e < rows);
    if !well_formed {
        return Err(vendor(
            path,
            format!(
                "the note's Indexes `{}` do not split the {rows} rows into segments",
                note_value(&note, "Indexes").unwrap_or("")
            ),
        ));
    }
    if ends.last() != Some(&(rows - 1)) {
        warnings.push(format!(
            "the note's segments end at row {}, the wave has {rows} rows; the rest are left out",
            ends.last().copied().unwrap_or(0) + 1
        ));
    }
    let n = ends.last().copied().unwrap_or(0) + 1;
    let kinds: Vec<&str> = (1..ends.len())
        .map(|j| match sense.get(j).copied() {
            Some(s) if s > 0.0 => "extend",
            Some(s) if s < 0.0 => "retract",
            Some(0.0) => "pause", // ±0 (a float pattern matches by ==), not NaN
            _ => "other",
        })
        .collect();

    let d_raw = read(defl)?;
    let u_raw = read(u_col)?;
    let piezo_raw = match (sensor, piezo) {
        (Some(_), Some(p)) => Some(read(p)?),
        _ => None,
    };
    let mut meta = Metadata::new(Mode::ForceCurve, 1.0 / dt, k, r);
    let mut rec = Recording::new(meta.clone());
    let mut seg = Vec::with_capacity(n);
    let mut points = vec![0usize; kinds.len()];
    for i in 0..n {
        // Row i belongs to the first segment whose end is at or after it.
        let j = ends[1..].iter().position(|e| i <= *e).unwrap_or(0);
        points[j] += 1;
        seg.push(j as f64);
        rec.t_s.push(i as f64 * dt);
        rec.u_m.push(-u_raw[i]);
        rec.d_m.push(-d_raw[i]);
    }
    rec.extra.push(Column {
        name: "segment".into(),
        values: seg,
    });
    if let Some(p) = piezo_raw {
        rec.extra.push(Column {
            name: "height_piezo_m".into(),
            values: p.iter().take(n).map(|h| -h).collect(),
        });
    }
    meta.set("source_file", path.display().to_string());
    meta.set("source_format", "asylum-ibw");
    meta.set(
        "instrument",
        format!(
            "Asylum Research {}",
            note_value(&note, "MicroscopeModel").unwrap_or("")
        ),
    );
    if let Some(v) = note_value(&note, "Version") {
        meta.set("vendor_software", v);
    }
    super::set_spring_constant_source(&mut meta, k_src, k_file);
    if let Some(s) = note_number(&note, "InvOLS") {
        meta.set("sensitivity_m_per_v", num(s));
    }
    meta.set("tip_radius_source", "--tip-radius");
    meta.set(
        "segments",
        kinds
            .iter()
            .enumerate()
            .map(|(j, k)| format!("{j}={k}"))
            .collect::<Vec<_>>()
            .join(","),
    );
    meta.set(
        "segment_points",
        points
            .iter()
            .map(|p| p.to_string())
            .collect::<Vec<_>>()
            .join(","),
    );
    if let (Some(d), Some(t)) = (note_value(&note, "Date"), note_value(&note, "Time")) {
        meta.set("start_time", format!("{d} {t}"));
    }
    meta.set("asylum_wave", name);
    if let Some(f) = note_number(&note, "ThermalFrequency") {
        meta.set("asylum_thermal_frequency_hz", num(f));
    }
    if let Some(q) = note_number(&note, "ThermalQ") {
        meta.set("asylum_thermal_q", num(q));
    }
    meta.set(
        "u_m_from",
        if sensor.is_some() {
            "-ZSnsr (m): the z sensor"
        } else {
            "-Raw (m): the piezo's height"
        },
    );
    meta.set("d_m_from", "-Defl (m)");
    rec.meta = meta;
    check_recording(path, &rec)?;
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn note_lines() {
        let note = "SpringConstant:0.31451\rInvOLS: 2.0364e-07\rIndexes: 0,5057,10096\rX:";
        assert_eq!(note_number(note, "SpringConstant"), Some(0.31451));
        assert_eq!(note_number(note, "InvOLS"), Some(2.0364e-7));
        assert_eq!(note_value(note, "Indexes"), Some("0,5057,10096"));
        assert_eq!(note_number(note, "X"), None);
        assert_eq!(note_number(note, "Missing"), None);
    }

    #[test]
    fn version_five_in_both_byte_orders() {
        assert!(is_ibw5(&[5, 0, 1, 2]));
        assert!(is_ibw5(&[0, 5, 1, 2]));
        assert!(!is_ibw5(&[2, 0]));
        assert!(!is_ibw5(b"PK\x03\x04"));
    }
}
