//! Malformed input of every kind is refused with the promised location and reason, and
//! nothing is written.

mod recording_support;

use std::path::{Path, PathBuf};

use recording_support::*;
use visco::recording::import::{import_all, ImportOptions};
use visco::recording::{
    Column, ErrorKind, Metadata, Mode, Recording, RecordingError, RecordingReader, Row,
};

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn read_err(path: &Path) -> RecordingError {
    match Recording::read(path) {
        Ok(_) => panic!("{} accepted", path.display()),
        Err(e) => e,
    }
}

const HEAD: &str = "# visco-recording: 1\n# mode: force-curve\n# sample_rate_hz: 2000\n\
                    # cantilever_k_n_per_m: 0.043\n# tip_radius_m: 5e-6\n";

#[test]
fn contract_violations_name_file_line_and_reason() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&str, String, u64, &str)] = &[
        ("empty.csv", String::new(), 1, "empty file"),
        (
            "nonnumeric.csv",
            format!("{HEAD}t_s,u_m,d_m\n0,1e-6,0\n0.0005,1e-6,abc\n"),
            8,
            "column `d_m`: `abc` is not a number",
        ),
        (
            "comma.csv",
            format!("{HEAD}t_s,u_m,d_m\n0,1e-6,0\n0.0005,1e-6,1,5\n"),
            8,
            "expected 3 cells (t_s,u_m,d_m), found 4",
        ),
        (
            "nan.csv",
            format!("{HEAD}t_s,u_m,d_m\n0,NaN,0\n"),
            7,
            "column `u_m`: NaN is not allowed",
        ),
        (
            "inf.csv",
            format!("{HEAD}t_s,u_m,d_m\n0,1,-inf\n"),
            7,
            "`-inf` is not a finite number",
        ),
        (
            "time.csv",
            format!("{HEAD}t_s,u_m,d_m\n0,1,0\n0.001,1,0\n0.0005,1,0\n"),
            9,
            "t_s = 0.0005 does not increase (previous row has 0.001)",
        ),
        (
            "short_row.csv",
            format!("{HEAD}t_s,u_m,d_m\n0,1,0\n0.001,1\n"),
            8,
            "expected 3 cells (t_s,u_m,d_m), found 2",
        ),
        (
            "no_k.csv",
            format!(
                "{}t_s,u_m,d_m\n0,1,0\n",
                HEAD.replace("# cantilever_k_n_per_m: 0.043\n", "")
            ),
            5,
            "missing required metadata key `cantilever_k_n_per_m` before the header",
        ),
        (
            "no_version.csv",
            format!(
                "{}t_s,u_m,d_m\n0,1,0\n",
                HEAD.replace("# visco-recording: 1\n", "")
            ),
            5,
            "missing required metadata key `visco-recording`",
        ),
        (
            "version.csv",
            format!(
                "{}t_s,u_m,d_m\n0,1,0\n",
                HEAD.replace("recording: 1", "recording: 7")
            ),
            1,
            "unknown format version `7`",
        ),
        (
            "mode.csv",
            format!(
                "{}t_s,u_m,d_m\n0,1,0\n",
                HEAD.replace("force-curve", "contact")
            ),
            2,
            "unknown mode `contact`",
        ),
        (
            "no_d.csv",
            format!("{HEAD}t_s,u_m,deflection\n0,1,0\n"),
            6,
            "missing required column `d_m`",
        ),
        (
            "dup.csv",
            format!("{HEAD}t_s,u_m,d_m,u_m\n0,1,0,1\n"),
            6,
            "column `u_m` appears twice in the header",
        ),
        (
            "no_rows.csv",
            format!("{HEAD}t_s,u_m,d_m\n"),
            7,
            "no data rows after the header",
        ),
        (
            "bad_rate.csv",
            format!("{}t_s,u_m,d_m\n0,1,0\n", HEAD.replace("2000", "fast")),
            3,
            "`sample_rate_hz`: `fast` is not a number",
        ),
    ];
    for (name, text, line, reason) in cases {
        let path = write(dir.path(), name, text);
        let e = read_err(&path);
        assert_eq!(e.kind, ErrorKind::Contract, "{name}: {e}");
        assert_eq!(e.line, Some(*line), "{name}: {e}");
        assert!(
            e.reason.contains(reason),
            "{name}: `{}` lacks `{reason}`",
            e.reason
        );
        let shown = e.to_string();
        assert!(
            shown.starts_with(&format!("{}:{line}: ", path.display())),
            "{name}: {shown}"
        );
    }
}

#[test]
fn streaming_reader_stops_at_the_bad_row_after_yielding_the_good_ones() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        dir.path(),
        "late.csv",
        &format!("{HEAD}t_s,u_m,d_m\n0,1,0\n0.001,1,0\n0.002,1,x\n"),
    );
    let mut r = RecordingReader::open(&path).unwrap();
    let mut row = Row::default();
    assert!(r.read_row(&mut row).unwrap());
    assert!(r.read_row(&mut row).unwrap());
    let e = r.read_row(&mut row).unwrap_err();
    assert_eq!(e.line, Some(9));
    assert!(!r.read_row(&mut row).unwrap());
}

fn small_recording() -> Recording {
    let mut rec = Recording::new(Metadata::new(Mode::Dive, 1000.0, 0.18, 3e-7));
    rec.t_s = vec![0.0, 0.001, 0.002];
    rec.u_m = vec![1e-7, 0.0, -1e-7];
    rec.d_m = vec![0.0, -1e-9, -2e-9];
    rec.extra.push(Column {
        name: "note".into(),
        values: vec![1.0, 2.0, 3.0],
    });
    rec
}

#[test]
fn writer_refuses_bad_data_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.csv");
    let mut bad = small_recording();
    bad.d_m[2] = f64::NAN;
    let e = bad.write(&out).unwrap_err();
    assert_eq!(e.line, Some(9), "{e}");
    assert!(e.reason.contains("column `d_m` is NaN"), "{e}");
    let mut bad = small_recording();
    bad.t_s[2] = 0.001;
    let e = bad.write(&out).unwrap_err();
    assert!(e.reason.contains("does not increase"), "{e}");
    let mut bad = small_recording();
    bad.extra[0].values.pop();
    assert!(bad.write(&out).is_err());
    let mut bad = small_recording();
    bad.meta.set("bad:key", "x");
    assert!(bad.write(&out).is_err());
    let mut bad = small_recording();
    bad.meta.tip_radius_m = -1.0;
    assert!(bad.write(&out).is_err());
    let mut bad = small_recording();
    bad.meta.mode = Mode::Sve;
    assert!(bad.write(&out).is_err(), "sve without x_m/y_m");
    assert!(
        dir_listing(dir.path()).is_empty(),
        "{:?}",
        dir_listing(dir.path())
    );

    // A failed write leaves an existing file untouched.
    small_recording().write(&out).unwrap();
    let before = std::fs::read(&out).unwrap();
    let mut bad = small_recording();
    bad.u_m[1] = f64::INFINITY;
    assert!(bad.write(&out).is_err());
    assert_eq!(std::fs::read(&out).unwrap(), before);
    assert_eq!(dir_listing(dir.path()), vec!["out.csv"]);
}

#[test]
fn writer_and_reader_round_trip_all_column_kinds() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dive.csv");
    let mut rec = small_recording();
    rec.meta.cantilever_c_ns_per_m = Some(1.48e-8);
    rec.meta.cantilever_m_kg = Some(1.18e-11);
    rec.meta.cantilever_f0_hz = Some(2e4);
    rec.meta.cantilever_q = Some(100.0);
    rec.meta.deflection_noise_m = Some(1e-10);
    rec.meta.set("source", "any: free text, with commas");
    rec.meta.set("empty", "");
    rec.x_m = Some(vec![0.0, 1e-7, 2e-7]);
    rec.y_m = Some(vec![-0.0, 5e-324, f64::MAX]);
    rec.tap = Some(vec![0, 0, 1]);
    rec.write(&out).unwrap();
    let back = Recording::read(&out).unwrap();
    assert_bit_exact(&rec, &back);
}

#[test]
fn streaming_handles_many_rows_without_collecting() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("long.csv");
    let header = small_recording().header();
    let mut w = visco::recording::RecordingWriter::create(&out, &header).unwrap();
    let n = 200_000u64;
    let mut sum = 0.0;
    for i in 0..n {
        let d = -((i % 977) as f64) * 1e-12;
        sum += d;
        w.write_row(&Row {
            t_s: i as f64 * 2e-6,
            u_m: (i as f64 * 1e-3).sin() * 1e-7,
            d_m: d,
            x_m: None,
            y_m: None,
            tap: None,
            extra: vec![i as f64],
        })
        .unwrap();
    }
    assert!(!out.exists(), "published before finish");
    w.finish().unwrap();
    let mut r = RecordingReader::open(&out).unwrap();
    let mut row = Row::default();
    let mut back = 0.0;
    let mut rows = 0;
    while r.read_row(&mut row).unwrap() {
        back += row.d_m;
        rows += 1;
    }
    assert_eq!(rows, n);
    assert_eq!(back, sum);
}

// ---------------------------------------------------------------- JPK archives

fn broken_jpk(dir: &Path, name: &str, edit: impl Fn(&str, Vec<u8>) -> Option<Vec<u8>>) -> PathBuf {
    let p = dir.join(name);
    rezip(&real(SPOT3), &p, edit);
    p
}

fn import_err(path: &Path, opts: &ImportOptions) -> RecordingError {
    match import_all(path, opts) {
        Ok(_) => panic!("{} accepted", path.display()),
        Err(e) => e,
    }
}

#[test]
fn truncated_zip_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(real(SPOT3)).unwrap();
    for cut in [bytes.len() / 2, bytes.len() - 10, 30, 4] {
        let p = dir.path().join(format!("cut{cut}.jpk-force"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let e = import_err(&p, &tip_only());
        assert_eq!(e.kind, ErrorKind::Vendor, "{e}");
        assert!(e.reason.contains("not a readable zip archive"), "{e}");
        assert!(e.fix.as_deref().unwrap_or("").contains("truncated"), "{e}");
    }
    let p = dir.path().join("empty.jpk-force");
    std::fs::write(&p, b"").unwrap();
    assert!(import_err(&p, &tip_only()).reason.contains("empty file"));
    let p = dir.path().join("text.jpk-force");
    std::fs::write(&p, b"hello").unwrap();
    assert!(import_err(&p, &tip_only())
        .reason
        .contains("not a zip archive"));
}

/// Writes a zip of `members` (name, bytes) at `p`.
fn write_zip(p: &Path, members: &[(String, Vec<u8>)]) {
    use std::io::Write;
    let mut zw = zip::ZipWriter::new(std::fs::File::create(p).unwrap());
    for (name, bytes) in members {
        zw.start_file(name.as_str(), zip::write::SimpleFileOptions::default())
            .unwrap();
        zw.write_all(bytes).unwrap();
    }
    zw.finish().unwrap();
}

/// A zip of another vendor's text exports (Optics11 ships its examples so) is named for what
/// it holds, with the way out, not called an incomplete JPK file.
#[test]
fn a_zip_of_other_exports_says_what_it_holds() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("exports.zip");
    let members: Vec<(String, Vec<u8>)> = (0..4)
        .map(|i| {
            (
                format!("indentation_{i:02}.txt"),
                b"Date\t1/1/2025\n".to_vec(),
            )
        })
        .collect();
    write_zip(&p, &members);
    let e = import_err(&p, &tip_only());
    assert_eq!(e.kind, ErrorKind::Vendor, "{e}");
    assert!(
        e.reason.contains("without JPK's header.properties")
            && e.reason.contains(
                "4 file(s): indentation_00.txt, indentation_01.txt, indentation_02.txt, …"
            ),
        "{e}"
    );
    assert!(e.fix.as_deref().unwrap_or("").contains("unzip"), "{e}");
}

/// An HDF5 file is named as such, with the way to a format import reads.
#[test]
fn an_hdf5_file_is_named_with_the_way_out() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("curves.h5");
    let mut bytes = b"\x89HDF\r\n\x1a\n".to_vec();
    bytes.extend([0u8; 56]);
    std::fs::write(&p, bytes).unwrap();
    let e = import_err(&p, &tip_only());
    assert!(e.reason.contains("HDF5"), "{e}");
    assert!(e.fix.as_deref().unwrap_or("").contains(".tab"), "{e}");
}

/// AFM Workshop writes a map as one CSV per point; a zip of them imports as a map, each curve
/// as its CSV alone would, in the members' name order, and a bad member is named.
#[test]
fn an_afm_workshop_zip_imports_as_a_map() {
    let dir = tempfile::tempdir().unwrap();
    let csv = std::fs::read(real(WORKSHOP)).unwrap();
    let opts = ImportOptions {
        spring_constant_n_per_m: Some(0.1),
        sample_rate_hz: Some(1000.0),
        ..tip_only()
    };
    let single = import_all(&real(WORKSHOP), &opts).unwrap().remove(0).1;
    let p = dir.path().join("map.zip");
    let members: Vec<(String, Vec<u8>)> = ["p2.csv", "p0.csv", "p1.csv"]
        .iter()
        .map(|n| (n.to_string(), csv.clone()))
        .collect();
    // As zipped by macOS's Finder: its resource forks are not curves.
    let mut zipped = members.clone();
    zipped.push(("__MACOSX/._p0.csv".into(), vec![0, 5, 22, 7]));
    zipped.push(("._p1.csv".into(), vec![0, 5, 22, 7]));
    write_zip(&p, &zipped);
    let all = import_all(&p, &opts).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(all.iter().map(|c| c.0).collect::<Vec<_>>(), [0, 1, 2]);
    for (i, (_, rec)) in all.iter().enumerate() {
        assert_eq!(
            rec.meta.get("archive_entry"),
            Some(format!("p{i}.csv").as_str())
        );
        assert_eq!(rec.meta.get("source_format"), Some("afm-workshop-zip"));
        assert_eq!(
            (&rec.t_s, &rec.u_m, &rec.d_m),
            (&single.t_s, &single.u_m, &single.d_m)
        );
    }
    let mut bad = members.clone();
    bad[1].1 = b"Force-Distance Curve\nno table\n".to_vec();
    write_zip(&p, &bad);
    let e = import_err(&p, &opts);
    assert_eq!(e.entry.as_deref(), Some("p0.csv"), "{e}");
}

#[test]
fn zip_without_header_properties_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = broken_jpk(dir.path(), "nohead.jpk-force", |name, b| {
        (name != "header.properties").then_some(b)
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(e.reason, "the archive has no header.properties");
    let p = broken_jpk(dir.path(), "noseg.jpk-force", |name, b| {
        (!name.starts_with("segments/")).then_some(b)
    });
    assert!(import_err(&p, &tip_only())
        .reason
        .contains("holds no segments"));
    let p = broken_jpk(dir.path(), "gap.jpk-force", |name, b| {
        (!name.starts_with("segments/0/")).then_some(b)
    });
    let e = import_err(&p, &tip_only());
    assert!(
        e.reason
            .contains("segment 0 is missing while segment 1 exists"),
        "{e}"
    );
}

const SEG0: &str = "segments/0/segment-header.properties";

#[test]
fn missing_or_garbage_properties_name_the_member_and_line() {
    let dir = tempfile::tempdir().unwrap();
    // A missing property: named, with the member.
    let p = broken_jpk(dir.path(), "nopoints.jpk-force", |name, b| {
        Some(if name == SEG0 {
            set_property(b, "force-segment-header.num-points", None)
        } else {
            b
        })
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(e.entry.as_deref(), Some(SEG0));
    assert_eq!(
        e.reason,
        "missing property `force-segment-header.num-points`"
    );

    let key = "channel.height.data.encoder.scaling.multiplier";
    let p = broken_jpk(dir.path(), "nomult.jpk-force", |name, b| {
        Some(if name == SEG0 {
            set_property(b, key, None)
        } else {
            b
        })
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(e.reason, format!("missing property `{key}`"));

    // A non-numeric property: member and line.
    let key = "force-segment-header.duration";
    let original = {
        let mut z = zip::ZipArchive::new(std::fs::File::open(real(SPOT3)).unwrap()).unwrap();
        let mut f = z.by_name(SEG0).unwrap();
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut f, &mut v).unwrap();
        v
    };
    let line = line_of(&original, key);
    let p = broken_jpk(dir.path(), "baddur.jpk-force", |name, b| {
        Some(if name == SEG0 {
            set_property(b, key, Some("soon"))
        } else {
            b
        })
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(
        (e.entry.as_deref(), e.line),
        (Some(SEG0), Some(line)),
        "{e}"
    );
    assert_eq!(
        e.reason,
        format!("property `{key}` = `soon` is not a number")
    );
    assert!(e.to_string().contains(&format!("{SEG0}:{line}: ")), "{e}");

    // NaN where a number is needed.
    let key = "channel.vDeflection.data.encoder.scaling.offset";
    let p = broken_jpk(dir.path(), "nanoff.jpk-force", |name, b| {
        Some(if name == SEG0 {
            set_property(b, key, Some("NaN"))
        } else {
            b
        })
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(
        e.reason,
        format!("property `{key}` is NaN, not a finite number")
    );

    // Without the deflection calibration, the sensitivity flag is asked for.
    let p = broken_jpk(dir.path(), "nosens.jpk-force", |name, b| {
        Some(if name.ends_with("segment-header.properties") {
            set_property(
                b,
                "channel.vDeflection.conversion-set.conversion.distance.defined",
                Some("false"),
            )
        } else {
            b
        })
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(e.kind, ErrorKind::MissingValue, "{e}");
    assert!(e.fix.unwrap().contains("--sensitivity"));
}

#[test]
fn short_or_missing_channel_data_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let member = "segments/1/channels/vDeflection.dat";
    let p = broken_jpk(dir.path(), "short.jpk-force", |name, mut b| {
        if name == member {
            b.truncate(b.len() - 3);
        }
        Some(b)
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(e.entry.as_deref(), Some(member));
    assert_eq!(
        e.reason,
        "holds 3997 bytes, the header says 2000 points of 2 bytes"
    );
    let p = broken_jpk(dir.path(), "gone.jpk-force", |name, b| {
        (name != member).then_some(b)
    });
    let e = import_err(&p, &tip_only());
    assert_eq!(e.reason, "the data file named in the header is missing");
}

#[test]
fn jpk_needs_the_tip_radius() {
    let e = import_err(&real(SPOT3), &ImportOptions::default());
    assert_eq!(e.kind, ErrorKind::MissingValue);
    assert_eq!(e.reason, "the file holds no tip radius");
    assert_eq!(e.fix.as_deref(), Some("pass --tip-radius 5e-6"));
}

// ---------------------------------------------------------------- text exports

#[test]
fn text_exports_report_line_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let ws = std::fs::read_to_string(real(WORKSHOP)).unwrap();
    let opts = everything();
    // Line 13 of the file is its second data row.
    let mut lines: Vec<&str> = ws.split('\n').collect();
    lines[12] = "4130.0327,abc,5344.0327,0.0707\r";
    let p = write(dir.path(), "ws.csv", &lines.join("\n"));
    let e = import_err(&p, &opts);
    assert_eq!(e.line, Some(13), "{e}");
    assert_eq!(e.reason, "cell 2 `abc` is not a finite number");
    lines[12] = "4130.0327,nan,5344.0327,0.0707\r";
    let p = write(dir.path(), "ws_nan.csv", &lines.join("\n"));
    assert_eq!(import_err(&p, &opts).line, Some(13));
    lines[12] = "4130.0327,0.0531,5344.0327\r";
    let p = write(dir.path(), "ws_cols.csv", &lines.join("\n"));
    let e = import_err(&p, &opts);
    assert_eq!(
        (e.line, e.reason.as_str()),
        (Some(13), "expected 4 cells, found 3")
    );
    let p = write(dir.path(), "ws_empty.csv", "");
    assert_eq!(import_err(&p, &opts).reason, "empty file");
    let p = write(
        dir.path(),
        "ws_head.csv",
        &ws.split('\n').take(11).collect::<Vec<_>>().join("\n"),
    );
    assert!(import_err(&p, &opts).reason.contains("no data rows"));

    let nt = std::fs::read_to_string(real(NTMDT)).unwrap();
    let mut lines: Vec<&str> = nt.split('\n').collect();
    lines[499] = "-4000,1\t1,2.5\t1,3\r";
    let p = write(dir.path(), "nt.txt", &lines.join("\n"));
    let e = import_err(&p, &opts);
    assert_eq!(
        (e.line, e.reason.as_str()),
        (Some(500), "cell 2 `1,2.5` is not a number")
    );
    lines[499] = "-4000,1\t1,2\r";
    let p = write(dir.path(), "nt_cols.txt", &lines.join("\n"));
    let e = import_err(&p, &opts);
    assert_eq!(e.line, Some(500));
    assert!(e.reason.contains("expected 3 tab-separated cells"), "{e}");
    let p = write(dir.path(), "nt_empty.txt", "");
    assert_eq!(import_err(&p, &opts).reason, "empty file");
}
