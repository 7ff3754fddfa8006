//! `visco import` end to end: summaries, one-line errors, no partial output.

mod recording_support;

use std::path::Path;
use std::process::{Command, Output};

use recording_support::*;
use visco::recording::Recording;

fn visco(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_visco"))
        .args(args)
        .output()
        .expect("run visco")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn imports_a_jpk_curve_and_prints_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("spot3.csv");
    let src = real(SPOT3);
    let o = visco(&["import", s(&src), "--out", s(&out), "--tip-radius", "5e-6"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let stdout = text(&o.stdout);
    assert!(stdout.contains("1 curve"), "{stdout}");
    assert!(stdout.contains("4000 points"), "{stdout}");
    assert!(
        stdout.contains("k = 0.043493666407368466 N/m (file)"),
        "{stdout}"
    );
    assert!(stdout.contains("rates 2000,2000 Hz"), "{stdout}");
    // The file's odd segment count is reported, not hidden.
    assert!(text(&o.stderr).contains("warning: "), "{}", text(&o.stderr));
    let rec = Recording::read(&out).unwrap();
    assert_bit_exact(&rec, &import_one(SPOT3, &tip_only()));
    assert_eq!(dir_listing(dir.path()), vec!["spot3.csv"]);
}

#[test]
fn missing_values_give_one_error_line_and_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.csv");
    let src = real(WORKSHOP);
    let o = visco(&["import", s(&src), "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert_eq!(
        err.trim_end(),
        format!(
            "error: {}: the file holds no spring constant, no sampling rate, no tip radius \
             (fix: pass --spring-constant 0.1 --sample-rate 2000 --tip-radius 5e-6)",
            src.display()
        )
    );
    assert!(dir_listing(dir.path()).is_empty());

    let o = visco(&["import", s(&real(SPOT3)), "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("(fix: pass --tip-radius 5e-6)"));
    assert!(dir_listing(dir.path()).is_empty());

    // Bad flag values are refused by the parser (exit 2), before any work.
    let o = visco(&[
        "import",
        s(&real(SPOT3)),
        "--out",
        s(&out),
        "--tip-radius",
        "-1",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(dir_listing(dir.path()).is_empty());
}

#[test]
fn maps_need_a_curve_or_a_pattern() {
    let dir = tempfile::tempdir().unwrap();
    let src = real(MAP);
    let single = dir.path().join("one.csv");
    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&single),
        "--tip-radius",
        "5e-6",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert!(err.contains("the map holds 4 curves"), "{err}");
    assert!(
        err.contains("--curve INDEX") && err.contains("{curve}"),
        "{err}"
    );
    assert!(dir_listing(dir.path()).is_empty());

    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&single),
        "--tip-radius",
        "5e-6",
        "--curve",
        "7",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        text(&o.stderr).contains("there is no curve 7"),
        "{}",
        text(&o.stderr)
    );

    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&single),
        "--tip-radius",
        "5e-6",
        "--curve",
        "2",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(Recording::read(&single).unwrap().len(), 3226);

    let pattern = dir.path().join("map-{curve}.csv");
    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&pattern),
        "--tip-radius",
        "5e-6",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("4 curves"));
    assert_eq!(
        dir_listing(dir.path()),
        vec![
            "map-0.csv",
            "map-1.csv",
            "map-2.csv",
            "map-3.csv",
            "one.csv"
        ]
    );
    let rec = Recording::read(&dir.path().join("map-3.csv")).unwrap();
    assert_eq!(rec.meta.get("curve_index"), Some("3"));
}

#[test]
fn a_failing_curve_of_a_map_leaves_no_file_at_all() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("bad.jpk-force-map");
    // Curve 2's deflection data is cut short; curves 0 and 1 are fine.
    rezip(&real(MAP), &src, |name, mut b| {
        if name == "index/2/segments/1/channels/vDeflection.dat" {
            b.truncate(100);
        }
        Some(b)
    });
    let outdir = dir.path().join("out");
    std::fs::create_dir(&outdir).unwrap();
    let pattern = outdir.join("c{curve}.csv");
    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&pattern),
        "--tip-radius",
        "5e-6",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert!(
        err.starts_with(&format!(
            "error: {}:index/2/segments/1/channels/vDeflection.dat: holds 100 bytes",
            src.display()
        )),
        "{err}"
    );
    assert!(
        dir_listing(&outdir).is_empty(),
        "{:?}",
        dir_listing(&outdir)
    );
}

#[test]
fn malformed_text_input_reports_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let nt = std::fs::read_to_string(real(NTMDT)).unwrap();
    let mut lines: Vec<&str> = nt.split('\n').collect();
    lines[41] = "-7671,8224\tx\t1,4711\r";
    let src = dir.path().join("nt.txt");
    std::fs::write(&src, lines.join("\n")).unwrap();
    let out = dir.path().join("nt.csv");
    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&out),
        "--spring-constant",
        "0.1",
        "--sensitivity",
        "5e-8",
        "--sample-rate",
        "1000",
        "--tip-radius",
        "5e-6",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        text(&o.stderr).trim_end(),
        format!("error: {}:42: cell 2 `x` is not a number", src.display())
    );
    assert!(!out.exists());
}

#[test]
fn refuses_to_overwrite_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("in.csv");
    std::fs::copy(real(WORKSHOP), &src).unwrap();
    let before = std::fs::read(&src).unwrap();
    let o = visco(&[
        "import",
        s(&src),
        "--out",
        s(&src),
        "--spring-constant",
        "0.1",
        "--sample-rate",
        "1000",
        "--tip-radius",
        "5e-6",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("would overwrite the input"));
    assert_eq!(std::fs::read(&src).unwrap(), before);
}

#[test]
fn help_documents_the_map_pattern() {
    let o = visco(&["import", "--help"]);
    assert!(o.status.success());
    let h = text(&o.stdout);
    for needle in [
        "{curve}",
        "--spring-constant",
        "--sensitivity",
        "--tip-radius",
        "--sample-rate",
        "--curve",
    ] {
        assert!(h.contains(needle), "help lacks {needle}");
    }
}

#[test]
fn every_malformed_input_fails_cleanly_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = dir.path().join("in");
    let outdir = dir.path().join("out");
    std::fs::create_dir(&inputs).unwrap();
    std::fs::create_dir(&outdir).unwrap();
    let spot3 = std::fs::read(real(SPOT3)).unwrap();
    let ws = std::fs::read_to_string(real(WORKSHOP)).unwrap();
    let ws_line = |i: usize, row: &str| {
        let mut l: Vec<&str> = ws.split('\n').collect();
        l[i] = row;
        l.join("\n")
    };
    let mut cases: Vec<(&str, Vec<u8>, String)> = vec![
        (
            "cut.jpk-force",
            spot3[..spot3.len() / 2].to_vec(),
            "not a readable zip archive".into(),
        ),
        ("empty.jpk-force", Vec::new(), "empty file".into()),
        ("empty.csv", Vec::new(), ":1: empty file".into()),
        (
            "cell.csv",
            ws_line(20, "4138.0327,x,5336.0327,0.0701\r").into_bytes(),
            ":21: cell 2 `x` is not a finite number".into(),
        ),
        (
            "nan.csv",
            ws_line(20, "4138.0327,NaN,5336.0327,0.0701\r").into_bytes(),
            ":21: cell 2 `NaN` is not a finite number".into(),
        ),
        (
            "cols.csv",
            ws_line(20, "4138.0327,0.0530,5336.0327,0.0701,1\r").into_bytes(),
            ":21: expected 4 cells, found 5".into(),
        ),
    ];
    let nohead = inputs.join("nohead.jpk-force");
    rezip(&real(SPOT3), &nohead, |n, b| {
        (n != "header.properties").then_some(b)
    });
    cases.push((
        "nohead.jpk-force",
        std::fs::read(&nohead).unwrap(),
        "no header.properties".into(),
    ));
    let noprop = inputs.join("noprop.jpk-force");
    rezip(&real(SPOT3), &noprop, |n, b| {
        Some(if n == "segments/1/segment-header.properties" {
            set_property(b, "force-segment-header.duration", None)
        } else {
            b
        })
    });
    cases.push((
        "noprop.jpk-force",
        std::fs::read(&noprop).unwrap(),
        ":segments/1/segment-header.properties: missing property `force-segment-header.duration`"
            .into(),
    ));
    for (name, bytes, expected) in cases {
        let src = inputs.join(name);
        std::fs::write(&src, bytes).unwrap();
        let out = outdir.join(format!("{name}.rec.csv"));
        let o = visco(&[
            "import",
            s(&src),
            "--out",
            s(&out),
            "--spring-constant",
            "0.1",
            "--sample-rate",
            "1000",
            "--tip-radius",
            "5e-6",
        ]);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert_eq!(err.lines().count(), 1, "{name}: {err}");
        assert!(
            err.starts_with(&format!("error: {}", src.display())),
            "{name}: {err}"
        );
        assert!(
            err.contains(&expected),
            "{name}: `{err}` lacks `{expected}`"
        );
        assert!(
            dir_listing(&outdir).is_empty(),
            "{name}: {:?}",
            dir_listing(&outdir)
        );
    }
}

/// Output into a pipe its reader closed (`visco … | head`) ends quietly with the shell's
/// status for SIGPIPE, not in a panic. The read end is closed as soon as the child starts,
/// before it prints its 40 KB schema (should the child win that race, it exits normally, which
/// the test also accepts: only a panic fails it).
#[test]
fn a_closed_pipe_ends_the_output_without_a_panic() {
    use std::process::Stdio;
    let mut child = Command::new(env!("CARGO_BIN_EXE_visco"))
        .args(["schema", "identify"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run visco");
    drop(child.stdout.take());
    let o = child.wait_with_output().expect("wait for visco");
    let err = text(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        o.status.success() || o.status.code() == Some(141),
        "status {:?}: {err}",
        o.status
    );
}
