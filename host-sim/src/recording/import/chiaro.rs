//! Optics11 Chiaro (and Piuma) nanoindenter text export of one indentation.
//!
//! A header of tab-separated `name<TAB>value` lines (`Date`, positions in µm, `k (N/m)`,
//! `Tip radius (um)`, `Calibration factor`, `Device:`, `Software version:`, the control mode
//! and the vendor's own Hertz fit), then the table `Time (s)`, `Load (uN)`, `Indentation (nm)`,
//! `Cantilever (nm)`, `Piezo (nm)`, `Auxiliary`, one row per sample. The cantilever's
//! deflection is positive when the sample pushes it up (Load = k·Cantilever), the piezo
//! position grows towards the sample. So U = −Piezo, D = −Cantilever, t as recorded; the
//! vendor's Load is kept as `force_vendor_n`. The export marks no segments: the rows up to the
//! piezo's deepest position are the `extend`, the rest the `retract`. The file carries k and
//! the tip radius, so only a flag that overrides them is needed.
//!
//! Metadata written: `source_file`, `source_format`, `instrument`, `vendor_software`,
//! `spring_constant_source`, `spring_constant_file_n_per_m`, `tip_radius_source`,
//! `chiaro_calibration_factor`, `chiaro_control_mode`, `position_x_m`, `position_y_m`,
//! `start_time`, `segments`, `segment_points`, `u_m_from`, `d_m_from`.

use std::path::Path;

use super::{
    check_recording, missing_error, num, resolve, set_spring_constant_source, ImportOptions,
    NEED_K, NEED_R,
};
use crate::recording::csv::read_text_limited;
use crate::recording::error::{ErrorKind, RecordingError, Result};
use crate::recording::{Column, Metadata, Mode, Recording};

const MAX_BYTES: u64 = 512 << 20;
/// The table's header, as the export writes it (the columns read by position after it).
const TABLE: [&str; 5] = [
    "Time (s)",
    "Load (uN)",
    "Indentation (nm)",
    "Cantilever (nm)",
    "Piezo (nm)",
];

/// Whether a text starts as a Chiaro export: its first line `Date<TAB>…` and the table's
/// header or the device's name further on.
pub fn looks_like(text: &str) -> bool {
    text.starts_with("Date\t")
        && [
            "Cantilever (nm)\tPiezo (nm)",
            "Device:\tChiaro",
            "Device:\tPiuma",
        ]
        .iter()
        .any(|s| text.contains(s))
}

/// The value after `key` on a header line (`key<TAB>value` or `key: value`).
fn header_value<'a>(lines: &[&'a str], key: &str) -> Option<&'a str> {
    lines.iter().find_map(|l| {
        let rest = l.strip_prefix(key)?;
        let rest = rest.strip_prefix(':').unwrap_or(rest);
        Some(
            rest.split('\t')
                .map(str::trim)
                .find(|s| !s.is_empty())
                .unwrap_or(""),
        )
    })
}

fn header_number(lines: &[&str], key: &str) -> Option<f64> {
    header_value(lines, key)
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite())
}

/// Imports one Chiaro indentation.
pub fn import(path: &Path, opts: &ImportOptions, warnings: &mut Vec<String>) -> Result<Recording> {
    let bytes = read_text_limited(path, MAX_BYTES)?;
    // The header's units carry a Latin-1 µ: read byte for byte.
    let text: String = bytes.iter().map(|b| *b as char).collect();
    // Line ends are `\r\n`, with a stray `\n\r` here and there: a carriage return either side.
    let lines: Vec<&str> = text.split('\n').map(|l| l.trim_matches('\r')).collect();
    let Some(table_at) = lines.iter().position(|l| {
        let cells: Vec<&str> = l.split('\t').map(str::trim).collect();
        cells.len() >= TABLE.len() && cells[..TABLE.len()] == TABLE
    }) else {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            format!(
                "no data table: the header line `{}` was not found",
                TABLE.join("<TAB>")
            ),
        ));
    };
    let header = &lines[..table_at];
    let mut missing = Vec::new();
    let k_file = header_number(header, "k (N/m)").filter(|k| *k > 0.0);
    let r_file = header_number(header, "Tip radius (um)")
        .filter(|r| *r > 0.0)
        .map(|r| r / 1e6);
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
        r_file,
        "m",
        warnings,
        &mut missing,
    );
    let (Some((k, k_src)), Some((r, r_src))) = (k, r) else {
        return Err(missing_error(path, &missing));
    };
    if opts.sensitivity_m_per_unit.is_some() {
        warnings.push(
            "--sensitivity is not used: a Chiaro export gives the deflection in nm".to_string(),
        );
    }
    if opts.sample_rate_hz.is_some() {
        warnings
            .push("--sample-rate is not used: a Chiaro export gives each row's time".to_string());
    }

    let (mut t, mut load, mut defl, mut piezo) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (i, line) in lines.iter().enumerate().skip(table_at + 1) {
        let line_no = i as u64 + 1;
        if line.trim().is_empty() {
            if let Some(j) = lines[i..].iter().position(|l| !l.trim().is_empty()) {
                return Err(RecordingError::new(
                    path,
                    ErrorKind::Vendor,
                    format!("data continues after the blank line {line_no}"),
                )
                .at_line((i + j) as u64 + 1));
            }
            break;
        }
        let cells: Vec<&str> = line.split('\t').map(str::trim).collect();
        if cells.len() < TABLE.len() {
            return Err(RecordingError::new(
                path,
                ErrorKind::Vendor,
                format!(
                    "expected at least {} tab-separated cells ({}), found {}",
                    TABLE.len(),
                    TABLE.join(", "),
                    cells.len()
                ),
            )
            .at_line(line_no));
        }
        let mut v = [0.0; 5];
        for (j, slot) in v.iter_mut().enumerate() {
            *slot = cells[j]
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    RecordingError::new(
                        path,
                        ErrorKind::Vendor,
                        format!("{} `{}` is not a number", TABLE[j], cells[j]),
                    )
                    .at_line(line_no)
                })?;
        }
        t.push(v[0]);
        load.push(v[1]);
        defl.push(v[3]);
        piezo.push(v[4]);
    }
    let n = t.len();
    if n < 2 {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "fewer than two data rows",
        ));
    }
    let mut dts: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let dt = dts[dts.len() / 2];
    if !(dt > 0.0) {
        return Err(RecordingError::new(
            path,
            ErrorKind::Vendor,
            "the Time (s) column does not increase",
        ));
    }
    // The deepest piezo position ends the extend (the first such row, should it dwell there).
    let turn = (0..n)
        .reduce(|a, b| if piezo[b] > piezo[a] { b } else { a })
        .unwrap_or(0);

    // The rate the times were written at: their rounding leaves 1 kHz as 1000.0000000001.
    let rate = 1.0 / dt;
    let rate = match (rate * 1e3).round() / 1e3 {
        r3 if ((r3 - rate) / rate).abs() < 1e-9 => r3,
        _ => rate,
    };
    let mut meta = Metadata::new(Mode::ForceCurve, rate, k, r);
    let mut rec = Recording::new(meta.clone());
    rec.t_s = t.iter().map(|x| x - t[0]).collect();
    rec.u_m = piezo.iter().map(|p| -p * 1e-9).collect();
    rec.d_m = defl.iter().map(|d| -d * 1e-9).collect();
    rec.extra.push(Column {
        name: "segment".into(),
        values: (0..n).map(|i| if i <= turn { 0.0 } else { 1.0 }).collect(),
    });
    rec.extra.push(Column {
        name: "force_vendor_n".into(),
        values: load.iter().map(|l| l * 1e-6).collect(),
    });
    meta.set("source_file", path.display().to_string());
    meta.set("source_format", "chiaro-txt");
    meta.set(
        "instrument",
        format!(
            "Optics11 {}",
            header_value(header, "Device").unwrap_or("Chiaro")
        ),
    );
    if let Some(v) = header_value(header, "Software version") {
        meta.set("vendor_software", v);
    }
    set_spring_constant_source(&mut meta, k_src, k_file);
    meta.set(
        "tip_radius_source",
        if r_src == "flag" {
            "--tip-radius"
        } else {
            "file"
        },
    );
    if let Some(c) = header_number(header, "Calibration factor") {
        meta.set("chiaro_calibration_factor", num(c));
    }
    if let Some(m) = header_value(header, "Control mode") {
        meta.set("chiaro_control_mode", m);
    }
    for (key, name) in [
        ("X-position (um)", "position_x_m"),
        ("Y-position (um)", "position_y_m"),
    ] {
        if let Some(v) = header_number(header, key) {
            meta.set(name, num(v / 1e6));
        }
    }
    if let (Some(d), Some(tm)) = (
        header_value(header, "Date"),
        lines
            .first()
            .and_then(|l| l.split('\t').skip_while(|c| *c != "Time").nth(1)),
    ) {
        meta.set("start_time", format!("{d} {tm}"));
    }
    meta.set("segments", "0=extend,1=retract");
    meta.set("segment_points", format!("{},{}", turn + 1, n - turn - 1));
    meta.set("u_m_from", "-Piezo (nm) × 1e-9");
    meta.set("d_m_from", "-Cantilever (nm) × 1e-9");
    rec.meta = meta;
    check_recording(path, &rec)?;
    Ok(rec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_lines() {
        let lines = [
            "Date\t12/05/2025\tTime\t11:20:38",
            "k (N/m)\t0.019",
            "Tip radius (um)\t27.500",
            "Device:\tChiaro",
            "Software version: V3.5.0",
        ];
        assert_eq!(header_number(&lines, "k (N/m)"), Some(0.019));
        assert_eq!(header_number(&lines, "Tip radius (um)"), Some(27.5));
        assert_eq!(header_value(&lines, "Device"), Some("Chiaro"));
        assert_eq!(header_value(&lines, "Software version"), Some("V3.5.0"));
        assert_eq!(header_value(&lines, "Date"), Some("12/05/2025"));
        assert_eq!(header_number(&lines, "Missing"), None);
    }
}
