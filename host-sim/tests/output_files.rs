//! Gwyddion Simple Field and CSV grids: round trips, the exact byte layout, NaN handling and
//! errors that name the file.

mod output_support;

use std::path::Path;

use output_support::{cell, noise};
use visco::output::gsf::{self, NanPolicy};
use visco::output::{csv, Grid, Map};

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// A 7 × 5 map (non-square, so a transposition would show) with distinct values.
fn small(name: &str) -> Map {
    let g = Grid::over(7, 5, -1.5e-6, 2.0e-6, 0.25e-6, 2.75e-6);
    Map::from_fn(g, name, "N·s/m", |x, y| {
        4e-7 + 1e-7 * (x * 1e6) + 3e-8 * (y * 1e6)
    })
}

fn header_text(bytes: &[u8]) -> &str {
    let nul = bytes.iter().position(|&b| b == 0).unwrap();
    std::str::from_utf8(&bytes[..nul]).unwrap()
}

#[test]
fn gsf_round_trip_is_bit_exact_in_f32() {
    let dir = tmp();
    let p = dir.path().join("c.gsf");
    let mut m = small("c (DIVE)");
    // Include awkward values: tiny, huge, negative, subnormal in f32.
    m.set(0, 0, -3.25e-7);
    m.set(1, 0, 1.0e-40);
    m.set(2, 0, 3.0e38);
    gsf::write_gsf(&p, &m, NanPolicy::default()).unwrap();
    let back = gsf::read_gsf(&p).unwrap();
    assert_eq!(back.map.grid.nx, 7);
    assert_eq!(back.map.grid.ny, 5);
    for j in 0..5 {
        for i in 0..7 {
            let want = (m.get(i, j) as f32).to_bits();
            assert_eq!(
                (back.map.get(i, j) as f32).to_bits(),
                want,
                "pixel ({i}, {j})"
            );
        }
    }
    // Extents are written with full f64 precision.
    assert!(
        back.map.grid.same_as(&m.grid),
        "{:?} vs {:?}",
        back.map.grid,
        m.grid
    );
    assert_eq!(back.map.grid.x0, -1.5e-6);
    assert_eq!(back.map.name, "c (DIVE)");
    assert_eq!(back.map.unit, "N·s/m");
}

#[test]
fn gsf_header_fields_padding_and_size() {
    let dir = tmp();
    let mut paddings = std::collections::BTreeSet::new();
    // Titles of 4 consecutive lengths hit all four padding cases (1 to 4 NULs).
    for extra in 0..4 {
        let name = format!("h{}", "x".repeat(extra));
        let m = Map::from_fn(
            Grid::over(3, 2, 0.0, 5e-6, 0.0, 5e-6),
            name.clone(),
            "m",
            |x, _| x,
        );
        let p = dir.path().join(format!("h{extra}.gsf"));
        gsf::write_gsf(&p, &m, NanPolicy::Keep).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert!(bytes.starts_with(b"Gwyddion Simple Field 1.0\n"));
        let text = header_text(&bytes);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            &lines[1..],
            &[
                "XRes = 3",
                "YRes = 2",
                "XReal = 5e-6",
                "YReal = 5e-6",
                "XOffset = 0e0",
                "YOffset = 0e0",
                "XYUnits = m",
                "ZUnits = m",
                &format!("Title = {name}"),
            ]
        );
        let header_len = text.len();
        let data_start = bytes.len() - 4 * 3 * 2;
        let nuls = data_start - header_len;
        assert_eq!(data_start % 4, 0, "data start aligned to 4");
        assert!((1..=4).contains(&nuls), "{nuls} NULs");
        assert_eq!(nuls, 4 - header_len % 4, "Gwyddion's rule: 4 − (len mod 4)");
        assert!(bytes[header_len..data_start].iter().all(|&b| b == 0));
        assert_eq!(
            bytes.len(),
            data_start + 4 * 3 * 2,
            "file = header + padding + 4·nx·ny"
        );
        paddings.insert(nuls);
        let back = gsf::read_gsf(&p).unwrap();
        assert_eq!(back.data_offset, data_start);
        assert_eq!(back.field("XYUnits"), Some("m"));
    }
    assert_eq!(
        paddings.len(),
        4,
        "all padding cases exercised: {paddings:?}"
    );
}

#[test]
fn gsf_rows_are_stored_top_row_first_little_endian() {
    let g = Grid::over(2, 2, 0.0, 2.0, 0.0, 2.0);
    let m = Map::from_vec(g, "v", "", vec![1.0, 2.0, 3.0, 4.0]); // bottom row 1 2, top row 3 4
    let bytes = gsf::gsf_bytes(&m, NanPolicy::Keep);
    let data = &bytes[bytes.len() - 16..];
    let vals: Vec<f32> = data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(vals, [3.0, 4.0, 1.0, 2.0]);
    let back = gsf::parse_gsf(&bytes).unwrap();
    assert_eq!(back.map.data, m.data);
    // Gwyddion's unit syntax for compound units.
    assert_eq!(gsf::gwyddion_unit("N·s/m"), "N s/m");
}

#[test]
fn gsf_nan_policies() {
    let mut m = small("k");
    m.unit = "N/m".into();
    m.set(3, 2, f64::NAN);
    m.set(4, 2, f64::NAN);
    let mean = m.stats().mean;

    let filled = gsf::parse_gsf(&gsf::gsf_bytes(&m, NanPolicy::FillMean)).unwrap();
    assert_eq!(filled.field("NoDataPixels"), Some("2"));
    let fill: f64 = filled.field("NoDataFill").unwrap().parse().unwrap();
    assert_eq!(fill, mean);
    assert_eq!(filled.map.get(3, 2), mean as f32 as f64);
    assert!(filled.map.data.iter().all(|v| v.is_finite()));

    let kept = gsf::parse_gsf(&gsf::gsf_bytes(&m, NanPolicy::Keep)).unwrap();
    assert!(kept.map.get(3, 2).is_nan() && kept.map.get(4, 2).is_nan());
    assert_eq!(kept.field("NoDataFill"), None);
    assert_eq!(kept.map.data.iter().filter(|v| v.is_nan()).count(), 2);

    let fixed = gsf::parse_gsf(&gsf::gsf_bytes(&m, NanPolicy::Fill(0.0))).unwrap();
    assert_eq!(fixed.map.get(4, 2), 0.0);

    // The mask file marks exactly the NaN pixels.
    let dir = tmp();
    let p = dir.path().join("k_nodata.gsf");
    gsf::write_gsf_mask(&p, &m).unwrap();
    let mask = gsf::read_gsf(&p).unwrap().map;
    for j in 0..5 {
        for i in 0..7 {
            assert_eq!(mask.get(i, j) == 1.0, m.get(i, j).is_nan());
        }
    }
    // No NaN: no NoData fields.
    let clean = gsf::parse_gsf(&gsf::gsf_bytes(&small("c"), NanPolicy::FillMean)).unwrap();
    assert_eq!(clean.field("NoDataPixels"), None);
}

#[test]
fn gsf_reader_refuses_malformed_files_naming_them() {
    let dir = tmp();
    let good = gsf::gsf_bytes(&small("c"), NanPolicy::Keep);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "magic.gsf",
            b"Gwyddion Simple Field 2.0\nXRes = 1\n\0\0".to_vec(),
            "not a Gwyddion",
        ),
        (
            "nonul.gsf",
            b"Gwyddion Simple Field 1.0\nXRes = 1\n".to_vec(),
            "truncated",
        ),
        ("short.gsf", good[..good.len() - 4].to_vec(), "bytes"),
        ("long.gsf", [good.clone(), vec![0; 4]].concat(), "bytes"),
        (
            "nores.gsf",
            b"Gwyddion Simple Field 1.0\nYRes = 1\n\0\0\0\0\0\0\0\0".to_vec(),
            "XRes",
        ),
    ];
    for (name, bytes, why) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let e = gsf::read_gsf(&p).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains(name), "{msg}");
        assert!(msg.contains(why), "{name}: {msg}");
    }
    let missing = dir.path().join("absent.gsf");
    assert!(gsf::read_gsf(&missing)
        .unwrap_err()
        .to_string()
        .contains("absent.gsf"));
}

#[test]
fn csv_round_trip_is_exact_with_nan() {
    let dir = tmp();
    let (h, _, _) = cell();
    let mut m = h.resample_mean(Grid::over(20, 12, 0.0, 5e-6, 0.0, 3e-6));
    m.name = "h (DIVE)".into();
    for i in 0..20 {
        let v = m.get(i, 3) * (1.0 + 1e-3 * noise(1, i, 3));
        m.set(i, 3, v);
    }
    m.set(5, 5, f64::NAN);
    let p = dir.path().join("h.csv");
    csv::write_csv(&p, &m).unwrap();
    let back = csv::read_csv(&p).unwrap();
    assert_eq!(back.grid, m.grid);
    assert_eq!((back.name.as_str(), back.unit.as_str()), ("h (DIVE)", "m"));
    for (a, b) in back.data.iter().zip(&m.data) {
        assert!(
            a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
            "{a} vs {b}"
        );
    }
    // The layout: comment header, then ny lines of nx fields, bottom row first, `nan`.
    let text = std::fs::read_to_string(&p).unwrap();
    let header: Vec<&str> = text.lines().take_while(|l| l.starts_with('#')).collect();
    for key in [
        "# name = h (DIVE)",
        "# unit = m",
        "# nx = 20",
        "# ny = 12",
        "# x0_m = 0e0",
        "# dy_m = 2.5e-7",
    ] {
        assert!(header.contains(&key), "missing {key:?} in {header:?}");
    }
    let dx_line = header.iter().find(|l| l.starts_with("# dx_m = ")).unwrap();
    assert_eq!(dx_line[9..].parse::<f64>().unwrap(), m.grid.dx);
    let rows: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows.len(), 12);
    assert!(rows.iter().all(|r| r.split(',').count() == 20));
    assert_eq!(rows[5].split(',').nth(5), Some("nan"));
    assert_eq!(
        rows[0].split(',').next().unwrap().parse::<f64>().unwrap(),
        m.get(0, 0)
    );
}

#[test]
fn csv_reader_errors_name_file_and_line() {
    let dir = tmp();
    let p = dir.path().join("bad.csv");
    let mut text = csv::csv_string(&small("c"));
    text = text.replacen("4.", "x4.", 1);
    std::fs::write(&p, &text).unwrap();
    let msg = csv::read_csv(&p).unwrap_err().to_string();
    assert!(
        msg.contains("bad.csv") && msg.contains("line 12, column 4"),
        "{msg}"
    );

    let short = csv::csv_string(&small("c"));
    let short: String = short.lines().take(14).map(|l| format!("{l}\n")).collect();
    std::fs::write(&p, short).unwrap();
    let msg = csv::read_csv(&p).unwrap_err().to_string();
    assert!(msg.contains("data lines"), "{msg}");
}

#[test]
fn writers_name_the_path_and_leave_nothing_behind() {
    let dir = tmp();
    let m = small("c");
    let missing = dir.path().join("no/such/dir/c.gsf");
    let e = gsf::write_gsf(&missing, &m, NanPolicy::default()).unwrap_err();
    assert!(e.to_string().contains("no/such/dir/c.gsf"), "{e}");
    assert_eq!(e.path, missing);
    let e = csv::write_csv(&dir.path().join("nope").join("c.csv"), &m).unwrap_err();
    assert!(e.to_string().contains("c.csv"), "{e}");
    // A directory in the way of the file: the error names it, no temporary file remains.
    let blocked = dir.path().join("taken");
    std::fs::create_dir(&blocked).unwrap();
    let e = gsf::write_gsf(&blocked, &m, NanPolicy::default()).unwrap_err();
    assert!(e.to_string().contains("taken"), "{e}");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("taken")], "{left:?}");
    // Overwriting replaces the file whole.
    let p = dir.path().join("c.csv");
    csv::write_csv(&p, &m).unwrap();
    let mut m2 = m.clone();
    m2.name = "second".into();
    csv::write_csv(&p, &m2).unwrap();
    assert_eq!(csv::read_csv(&p).unwrap().name, "second");
    assert!(Path::new(&p).exists());
}

/// Gwyddion itself opens our files, when it is installed (`apt-get install gwyddion`; CI does
/// not have it, and the test then only says so). `gwyddion-thumbnailer` loads a file with
/// Gwyddion's own GSF module and fails on anything it cannot read.
#[test]
fn gwyddion_opens_our_gsf_when_installed() {
    let ok = std::process::Command::new("gwyddion-thumbnailer")
        .arg("--version")
        .output()
        .is_ok();
    if !ok {
        eprintln!("gwyddion-thumbnailer not installed: skipping the check with Gwyddion");
        return;
    }
    let dir = tmp();
    let mut m = small("c (SVE)");
    m.set(2, 2, f64::NAN);
    for (name, policy) in [
        ("fill.gsf", NanPolicy::FillMean),
        ("keep.gsf", NanPolicy::Keep),
    ] {
        let p = dir.path().join(name);
        gsf::write_gsf(&p, &m, policy).unwrap();
        let thumb = dir.path().join(format!("{name}.png"));
        let out = std::process::Command::new("gwyddion-thumbnailer")
            .args(["gnome2", "64"])
            .arg(&p)
            .arg(&thumb)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(thumb.exists());
    }
    // And refuses a broken one, so the check above means something.
    let bad = dir.path().join("bad.gsf");
    let bytes = gsf::gsf_bytes(&m, NanPolicy::Keep);
    std::fs::write(&bad, &bytes[..bytes.len() - 1]).unwrap();
    let out = std::process::Command::new("gwyddion-thumbnailer")
        .args(["gnome2", "64"])
        .arg(&bad)
        .arg(dir.path().join("bad.png"))
        .output()
        .unwrap();
    assert!(!out.status.success());
}
