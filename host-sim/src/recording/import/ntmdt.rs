//! NT-MDT Nova text export of a force curve.
//!
//! Three tab-separated columns with decimal commas and no header or metadata at all:
//! piezo height (nm), deflection (DFL, nA) on approach, DFL on retract, one row per height.
//! The rows run from the deepest position (most negative height, the tip pressed into the
//! sample, the largest DFL) to the start position near 0. In time the approach goes the other
//! way, so it is the DFL approach column read bottom to top, followed by the retract column
//! read top to bottom. The height is z up: it falls while the piezo extends towards the
//! sample, so U = height. DFL is positive when the sample pushes the cantilever up, so
//! D = −DFL·sensitivity.
//!
//! Exports sometimes pad the start of a column (the deep end) with a repeated constant; as in
//! the afmformats reader, such a run is cut down to its last value, and the number of rows cut
//! is recorded (`ntmdt_cropped_rows_approach` / `_retract`).
//!
//! Nothing but the data is in the file, so `--spring-constant`, `--sensitivity` (here in
//! metres per nA of the DFL signal as exported), `--sample-rate` and `--tip-radius` are all
//! needed. No vendor force channel exists.
//!
//! Metadata written: `source_file`, `source_format`, `instrument`, `spring_constant_source`,
//! `sensitivity_m_per_na`, `sample_rate_source`, `tip_radius_source`, `segments`,
//! `segment_points`, `ntmdt_cropped_rows_approach`, `ntmdt_cropped_rows_retract`, `u_m_from`,
//! `d_m_from`.

use std::path::Path;

use super::{
    check_recording, missing_error, num, resolve, ImportOptions, NEED_K, NEED_R, NEED_RATE,
    NEED_SENS,
};
use crate::recording::csv::read_text_limited;
use crate::recording::error::{ErrorKind, RecordingError, Result};
use crate::recording::{Column, Metadata, Mode, Recording};

const MAX_BYTES: u64 = 512 << 20;

/// Parses a number with a decimal comma (or point).
fn parse_decimal_comma(cell: &str) -> Option<f64> {
    let s = cell.trim();
    if s.matches([',', '.']).count() > 1 {
        return None;
    }
    s.replace(',', ".")
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
}

/// Index of the last element of a leading run of equal values (0 when there is no run).
fn padding_end(values: &[f64]) -> usize {
    let Some(first) = values.first() else {
        return 0;
    };
    values
        .iter()
        .take_while(|v| *v == first)
        .count()
        .saturating_sub(1)
}

/// Parses an NT-MDT text export into a recording.
pub fn import(path: &Path, opts: &ImportOptions, warnings: &mut Vec<String>) -> Result<Recording> {
    let bytes = read_text_limited(path, MAX_BYTES)?;
    if bytes.is_empty() {
        return Err(RecordingError::new(path, ErrorKind::Vendor, "empty file").at_line(1));
    }
    let mut missing = Vec::new();
    let k = resolve(
        &NEED_K,
        opts.spring_constant_n_per_m,
        None,
        "N/m",
        warnings,
        &mut missing,
    );
    let sens = resolve(
        &NEED_SENS,
        opts.sensitivity_m_per_unit,
        None,
        "m/nA",
        warnings,
        &mut missing,
    );
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
    let (Some((k, _)), Some((sens, _)), Some((rate, _)), Some((r, _))) = (k, sens, rate, r) else {
        return Err(missing_error(path, &missing));
    };

    let text = String::from_utf8_lossy(&bytes);
    let lines: Vec<&str> = text.split('\n').map(|l| l.trim_end_matches('\r')).collect();
    let mut height = Vec::new();
    let mut app = Vec::new();
    let mut ret = Vec::new();
    let mut ended_at: Option<usize> = None;
    for (i, line) in lines.iter().enumerate() {
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
        let cells: Vec<&str> = line.split('\t').collect();
        if cells.len() != 3 {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!(
                    "expected 3 tab-separated cells (height nm, DFL approach, DFL retract), found {}",
                    cells.len()
                ),
            )
            .at_line(line_no));
        }
        let mut v = [0.0; 3];
        for (j, (c, slot)) in cells.iter().zip(v.iter_mut()).enumerate() {
            *slot = parse_decimal_comma(c).ok_or_else(|| {
                RecordingError::new(
                    path,
                    ErrorKind::Vendor,
                    format!("cell {} `{}` is not a number", j + 1, c.trim()),
                )
                .at_line(line_no)
            })?;
        }
        height.push(v[0]);
        app.push(v[1]);
        ret.push(v[2]);
    }
    if height.len() < 2 {
        return Err(
            RecordingError::new(path, ErrorKind::Vendor, "fewer than two data rows").at_line(1),
        );
    }
    let crop_a = padding_end(&app);
    let crop_r = padding_end(&ret);
    if crop_a + 1 >= app.len() || crop_r + 1 >= ret.len() {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "a deflection column is constant throughout",
        ));
    }

    let mut meta = Metadata::new(Mode::ForceCurve, rate, k, r);
    let mut rec = Recording::new(meta.clone());
    let mut seg = Vec::new();
    // Approach: bottom to top, stopping at the end of the padding.
    let approach = (crop_a..height.len()).rev().map(|i| (0.0, i, &app));
    let retract = (crop_r..height.len()).map(|i| (1.0, i, &ret));
    for (n, (s, i, col)) in approach.chain(retract).enumerate() {
        let (Some(h), Some(d)) = (height.get(i), col.get(i)) else {
            continue;
        };
        rec.t_s.push(n as f64 / rate);
        rec.u_m.push(h * 1e-9);
        rec.d_m.push(-d * sens);
        seg.push(s);
    }
    let n_app = height.len() - crop_a;
    let n_ret = height.len() - crop_r;
    rec.extra.push(Column {
        name: "segment".into(),
        values: seg,
    });
    meta.set("source_file", path.display().to_string());
    meta.set("source_format", "ntmdt-txt");
    meta.set("instrument", "NT-MDT (Nova text export)");
    meta.set("spring_constant_source", "--spring-constant");
    meta.set("sensitivity_m_per_na", num(sens));
    meta.set(
        "sample_rate_source",
        "--sample-rate (the file has no time base)",
    );
    meta.set("tip_radius_source", "--tip-radius");
    meta.set("segments", "0=extend,1=retract");
    meta.set("segment_points", format!("{n_app},{n_ret}"));
    meta.set("ntmdt_cropped_rows_approach", crop_a.to_string());
    meta.set("ntmdt_cropped_rows_retract", crop_r.to_string());
    meta.set("u_m_from", "height (nm) × 1e-9");
    meta.set("d_m_from", "-DFL (nA) × sensitivity");
    rec.meta = meta;
    check_recording(path, &rec)?;
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimal_commas() {
        assert_eq!(parse_decimal_comma("-7999,9482"), Some(-7999.9482));
        assert_eq!(parse_decimal_comma(" 1,5 "), Some(1.5));
        assert_eq!(parse_decimal_comma("1.5"), Some(1.5));
        assert_eq!(parse_decimal_comma("1,5,3"), None);
        assert_eq!(parse_decimal_comma("NaN"), None);
        assert_eq!(parse_decimal_comma(""), None);
    }

    #[test]
    fn padding() {
        assert_eq!(padding_end(&[1.0, 1.0, 1.0, 2.0]), 2);
        assert_eq!(padding_end(&[1.0, 2.0]), 0);
        assert_eq!(padding_end(&[]), 0);
    }
}
