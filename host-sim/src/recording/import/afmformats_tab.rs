//! The tab-separated export of the `afmformats` Python package (`.tab`), which nanite and
//! PyJibe users write from any vendor's file.
//!
//! `#`-commented lines first: a version line, the metadata as JSON between `# BEGIN METADATA`
//! and `# END METADATA` (`spring constant` N/m, `sensitivity` m/V, `rate approach` Hz,
//! `position x`/`y` m, `instrument`, `software`, `software version`), then the columns' names,
//! then one tab-separated row per sample: `force` (N, positive = repulsive), `height
//! (measured)` and `height (piezo)` (m, z up: they fall towards the sample), `segment`
//! (`False` approach, `True` retract), `time` (s). Version 0.13.3 wrote the names' line without
//! its line end, the first row glued to it (`…\ttime-6.77e-10\t…`): the names are split from
//! the values they run into.
//!
//! U = height (measured) (the piezo's where there is none), D = −force/k (the file's k, with
//! which the force was computed, also where `--spring-constant` overrides it), the force kept as
//! `force_vendor_n`. The tip radius is not in the metadata: `--tip-radius`.
//!
//! Metadata written: `source_file`, `source_format`, `instrument`, `vendor_software`,
//! `spring_constant_source`, `spring_constant_file_n_per_m`, `sensitivity_m_per_v`,
//! `tip_radius_source`, `position_x_m`, `position_y_m`, `segments`, `segment_points`,
//! `afmformats_version`, `u_m_from`, `d_m_from`.

use std::path::Path;

use super::{
    check_recording, missing_error, num, resolve, set_spring_constant_source, ImportOptions,
    NEED_K, NEED_R, NEED_RATE,
};
use crate::recording::csv::read_text_limited;
use crate::recording::error::{ErrorKind, RecordingError, Result};
use crate::recording::{Column, Metadata, Mode, Recording};

const MAX_BYTES: u64 = 512 << 20;
/// The columns afmformats writes for force–distance data.
const NAMES: [&str; 6] = [
    "force",
    "height (measured)",
    "height (piezo)",
    "segment",
    "time",
    "tip position",
];

/// Whether a text starts as an afmformats `.tab` export.
pub fn looks_like(head: &str) -> bool {
    head.starts_with("# afmformats") || head.contains("# BEGIN METADATA")
}

/// A cell: a number, or `False`/`True` (0/1).
fn cell(s: &str) -> Option<f64> {
    match s.trim() {
        "False" => Some(0.0),
        "True" => Some(1.0),
        v => v.parse::<f64>().ok().filter(|x| x.is_finite()),
    }
}

/// Imports one afmformats `.tab` curve.
pub fn import(path: &Path, opts: &ImportOptions, warnings: &mut Vec<String>) -> Result<Recording> {
    let bytes = read_text_limited(path, MAX_BYTES)?;
    let text = String::from_utf8_lossy(&bytes);
    let lines: Vec<&str> = text.split('\n').map(|l| l.trim_end_matches('\r')).collect();
    let vendor = |reason: String, line: usize| {
        RecordingError::new(path, ErrorKind::Vendor, reason).at_line(line as u64 + 1)
    };
    // The metadata block.
    let begin = lines.iter().position(|l| l.starts_with("# BEGIN METADATA"));
    let end = lines.iter().position(|l| l.starts_with("# END METADATA"));
    let meta_json: serde_json::Value = match (begin, end) {
        (Some(b), Some(e)) if b < e => {
            let dump: String = lines[b + 1..e]
                .iter()
                .map(|l| l.trim_start_matches('#').trim())
                .collect::<Vec<_>>()
                .join("\n");
            serde_json::from_str(&dump)
                .map_err(|err| vendor(format!("the metadata is not JSON: {err}"), b + 1))?
        }
        _ => serde_json::Value::Null,
    };
    let meta_num = |key: &str| meta_json.get(key).and_then(serde_json::Value::as_f64);
    let meta_str = |key: &str| meta_json.get(key).and_then(serde_json::Value::as_str);
    // The names: the last commented line before the data; values glued to it are the first
    // row's.
    let first_data = lines
        .iter()
        .position(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .ok_or_else(|| vendor("no data rows".to_string(), lines.len().saturating_sub(1)))?;
    let names_at = (0..first_data)
        .rev()
        .find(|&i| lines[i].starts_with('#') && lines[i].contains('\t'))
        .ok_or_else(|| vendor("no line naming the columns".to_string(), first_data))?;
    let mut names: Vec<&str> = Vec::new();
    let mut glued: Vec<f64> = Vec::new();
    for field in lines[names_at].trim_start_matches('#').trim().split('\t') {
        if let Some(v) = cell(field) {
            glued.push(v);
        } else if let Some(name) = NAMES.iter().find(|n| {
            field
                .strip_prefix(**n)
                .is_some_and(|rest| rest.is_empty() || cell(rest).is_some())
        }) {
            names.push(name);
            if let Some(v) = cell(&field[name.len()..]) {
                glued.push(v);
            }
        } else {
            names.push(field.trim());
        }
    }
    let col = |n: &str| names.iter().position(|x| *x == n);
    let force_col = col("force").ok_or_else(|| {
        vendor(
            format!("no force column among {}", names.join(", ")),
            names_at,
        )
    })?;
    let u_col = col("height (measured)")
        .or_else(|| col("height (piezo)"))
        .ok_or_else(|| {
            vendor(
                format!("no height column among {}", names.join(", ")),
                names_at,
            )
        })?;
    let mut rows: Vec<(usize, Vec<f64>)> = Vec::new();
    if !glued.is_empty() {
        rows.push((names_at, glued));
    }
    for (i, line) in lines.iter().enumerate().skip(first_data) {
        if line.trim().is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split('\t')
            .enumerate()
            .map(|(j, c)| {
                cell(c).ok_or_else(|| {
                    vendor(
                        format!(
                            "{} `{}` is not a number",
                            names.get(j).copied().unwrap_or("a cell"),
                            c.trim()
                        ),
                        i,
                    )
                })
            })
            .collect::<Result<_>>()?;
        rows.push((i, v));
    }
    for (i, r) in &rows {
        if r.len() != names.len() {
            return Err(vendor(
                format!("{} cells for {} columns", r.len(), names.len()),
                *i,
            ));
        }
    }
    if rows.len() < 2 {
        return Err(vendor("fewer than two data rows".to_string(), first_data));
    }

    let mut missing = Vec::new();
    let k_file = meta_num("spring constant").filter(|k| *k > 0.0);
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
    let time_col = col("time");
    let rate_file = meta_num("rate approach").filter(|r| *r > 0.0);
    let rate = if time_col.is_some() {
        rate_file.or(opts.sample_rate_hz).map(|r| (r, "file"))
    } else {
        resolve(
            &NEED_RATE,
            opts.sample_rate_hz,
            rate_file,
            "Hz",
            warnings,
            &mut missing,
        )
    };
    let (Some((k, k_src)), Some((r, _))) = (k, r) else {
        return Err(missing_error(path, &missing));
    };
    let n = rows.len();
    let t: Vec<f64> = match time_col {
        Some(c) => rows.iter().map(|(_, v)| v[c] - rows[0].1[c]).collect(),
        None => {
            let Some((rate, _)) = rate else {
                return Err(missing_error(path, &missing));
            };
            (0..n).map(|i| i as f64 / rate).collect()
        }
    };
    let rate = match rate {
        Some((r, _)) => r,
        None => {
            let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
            d.sort_by(f64::total_cmp);
            1.0 / d[d.len() / 2]
        }
    };
    let seg: Vec<f64> = match col("segment") {
        Some(c) => rows.iter().map(|(_, v)| v[c]).collect(),
        None => vec![0.0; n],
    };
    let mut meta = Metadata::new(Mode::ForceCurve, rate, k, r);
    let mut rec = Recording::new(meta.clone());
    rec.t_s = t;
    rec.u_m = rows.iter().map(|(_, v)| v[u_col]).collect();
    // The force was computed with the file's k: the deflection is force over that k, whatever
    // k a flag gives the recording.
    let k_force = k_file.unwrap_or(k);
    rec.d_m = rows.iter().map(|(_, v)| -v[force_col] / k_force).collect();
    let n_ret = seg.iter().filter(|s| **s > 0.5).count();
    rec.extra.push(Column {
        name: "segment".into(),
        values: seg,
    });
    rec.extra.push(Column {
        name: "force_vendor_n".into(),
        values: rows.iter().map(|(_, v)| v[force_col]).collect(),
    });
    meta.set("source_file", path.display().to_string());
    meta.set("source_format", "afmformats-tab");
    if let Some(v) = lines.first().and_then(|l| l.strip_prefix("# afmformats")) {
        meta.set("afmformats_version", v.trim());
    }
    meta.set(
        "instrument",
        meta_str("instrument").unwrap_or("unknown (afmformats export)"),
    );
    if let (Some(s), v) = (meta_str("software"), meta_str("software version")) {
        meta.set("vendor_software", format!("{s} {}", v.unwrap_or("")).trim());
    }
    set_spring_constant_source(&mut meta, k_src, k_file);
    if let Some(s) = meta_num("sensitivity") {
        meta.set("sensitivity_m_per_v", num(s));
    }
    meta.set("tip_radius_source", "--tip-radius");
    for (key, name) in [
        ("position x", "position_x_m"),
        ("position y", "position_y_m"),
    ] {
        if let Some(v) = meta_num(key) {
            meta.set(name, num(v));
        }
    }
    meta.set("segments", "0=extend,1=retract");
    meta.set("segment_points", format!("{},{}", n - n_ret, n_ret));
    meta.set(
        "u_m_from",
        if col("height (measured)").is_some() {
            "height (measured) (m)"
        } else {
            "height (piezo) (m)"
        },
    );
    meta.set("d_m_from", "-force (N) / k");
    rec.meta = meta;
    check_recording(path, &rec)?;
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells() {
        assert_eq!(cell("False"), Some(0.0));
        assert_eq!(cell(" True "), Some(1.0));
        assert_eq!(cell("-6.7e-10"), Some(-6.7e-10));
        assert_eq!(cell("time"), None);
        assert_eq!(cell("NaN"), None);
    }
}
