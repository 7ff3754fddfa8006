//! Asylum Research force curves (Igor binary waves, `.ibw`), end to end: the two of
//! afmformats' test data (`tests/data/afmformats/`, MIT licence beside them), an MFP-3D on a
//! stiff silicon-nitride sample and on a soft one with a pull-off. What is checked is what a
//! reader of the file must get right: the calibrations the note carries, the time base the
//! wave's step gives, the segments its `Indexes` mark, and the signs (the sample pushes the
//! lever up at the end of the approach: D below its free level; a pull-off on the retract:
//! above it), then identify on the result.

use std::path::PathBuf;
use visco::identify::{identify, Options, Outcome};
use visco::recording::import::{import_all, ImportOptions};
use visco::recording::ErrorKind;
use visco::recording::Recording;

fn data(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/afmformats"
    ))
    .join(name)
}

fn tip() -> ImportOptions {
    ImportOptions {
        tip_radius_m: Some(5e-6),
        ..Default::default()
    }
}

fn import_one(name: &str) -> Recording {
    let mut all = import_all(&data(name), &tip()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(all.len(), 1, "{name}: one curve per wave");
    all.remove(0).1
}

/// Rows of segment `s`.
fn rows_of(rec: &Recording, s: f64) -> Vec<usize> {
    let seg = &rec
        .extra
        .iter()
        .find(|c| c.name == "segment")
        .unwrap()
        .values;
    (0..rec.len()).filter(|&i| seg[i] == s).collect()
}

/// Median and robust σ (MAD) of D over rows.
fn level(rec: &Recording, rows: &[usize]) -> (f64, f64) {
    let mut v: Vec<f64> = rows.iter().map(|&i| rec.d_m[i]).collect();
    v.sort_by(f64::total_cmp);
    let med = v[v.len() / 2];
    let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
    dev.sort_by(f64::total_cmp);
    (med, 1.4826 * dev[dev.len() / 2])
}

#[test]
fn asylum_waves_import_with_their_calibrations_segments_and_signs() {
    // (file, k N/m, InvOLS m/V, rows per segment, thermal f₀ Hz)
    let cases = [
        (
            "fmt-igor-fd_SiN_FD_plot.ibw",
            1.1841,
            4.499e-8,
            [1009, 1007],
            23251.0,
        ),
        (
            "fmt-igor-fd_U3_3_p10004.ibw",
            0.31451,
            2.0364e-7,
            [5058, 5039],
            75000.0,
        ),
    ];
    for (name, k, invols, points, f_th) in cases {
        let rec = import_one(name);
        let m = &rec.meta;
        assert_eq!(m.cantilever_k_n_per_m, k, "{name}: SpringConstant");
        assert_eq!(m.get("spring_constant_source"), Some("file"));
        assert_eq!(
            m.get("sensitivity_m_per_v")
                .map(|s| s.parse::<f64>().unwrap()),
            Some(invols),
            "{name}: InvOLS"
        );
        assert_eq!(m.sample_rate_hz, 2000.0, "{name}: the wave's step, 0.5 ms");
        assert_eq!(m.get("segments"), Some("0=extend,1=retract"));
        assert_eq!(
            m.get("segment_points"),
            Some(format!("{},{}", points[0], points[1]).as_str())
        );
        assert_eq!(
            m.get("asylum_thermal_frequency_hz")
                .map(|s| s.parse::<f64>().unwrap()),
            Some(f_th)
        );
        // The thermal tune (in air) is not the contract's f₀: left unset.
        assert_eq!(m.cantilever_f0_hz, None);
        assert!((rec.t_s[1] - rec.t_s[0] - 5e-4).abs() < 1e-15);
        // U is z up: it falls while the piezo extends towards the sample.
        let ext = rows_of(&rec, 0.0);
        let ret = rows_of(&rec, 1.0);
        assert_eq!((ext.len(), ret.len()), (points[0], points[1]));
        let (first, turn) = (ext[0], *ext.last().unwrap());
        assert!(
            rec.u_m[turn] < rec.u_m[first] - 1e-7,
            "{name}: U falls on the approach"
        );
        // The free approach's first fifth sets the level; at the turn the sample pushes the
        // lever up: D far below it (the contract's sign).
        let (free, sigma) = level(&rec, &ext[..ext.len() / 5]);
        let pushed = (free - rec.d_m[turn]) / sigma;
        println!(
            "{name}: free level {:.2} nm, σ {:.3} nm, D at the turn {:.1} nm ({pushed:.0}σ below)",
            free * 1e9,
            sigma * 1e9,
            rec.d_m[turn] * 1e9
        );
        assert!(pushed > 100.0, "{name}: pushed up at the turn");
        // identify on it: the contact inside the approach, before its threshold crossing.
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("curve.csv");
        rec.write(&csv).unwrap();
        let report = identify(&csv, &Options::new(dir.path().join("curve.json")))
            .unwrap_or_else(|e| panic!("{e}"));
        let Outcome::ForceCurve(fit) = report.outcome else {
            panic!("{name}: not a force curve")
        };
        println!(
            "{name}: contact row {}, threshold row {}, k_a {:.3e} N/m³, δ_max {:.1} nm",
            fit.contact_row + 1,
            fit.threshold_row + 1,
            fit.k_a_n_per_m3,
            fit.max_depth_m * 1e9
        );
        assert!(fit.k_a_n_per_m3 > 0.0);
        assert!(
            fit.contact_row > fit.baseline.free_rows.end
                && fit.contact_row <= fit.threshold_row
                && fit.threshold_row < turn,
            "{name}: the contact inside the approach"
        );
    }
    // The soft sample holds the tip on the retract: a pull-off, D above the free level
    // (the lever bent towards the sample) before it snaps free.
    let rec = import_one("fmt-igor-fd_U3_3_p10004.ibw");
    let ext = rows_of(&rec, 0.0);
    let (free, sigma) = level(&rec, &ext[..ext.len() / 5]);
    let pull = rows_of(&rec, 1.0)
        .iter()
        .map(|&i| rec.d_m[i] - free)
        .fold(f64::NEG_INFINITY, f64::max);
    println!(
        "pull-off on the retract: {:.1} nm above the free level",
        pull * 1e9
    );
    assert!(pull > 100.0 * sigma, "the pull-off's sign");
}

#[test]
fn broken_waves_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(data("fmt-igor-fd_SiN_FD_plot.ibw")).unwrap();
    let refused = |name: &str, b: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, b).unwrap();
        match import_all(&p, &tip()) {
            Ok(_) => panic!("{name} accepted"),
            Err(e) => e,
        }
    };
    let e = refused("cut.ibw", &bytes[..bytes.len() / 2]);
    assert_eq!(e.kind, ErrorKind::Vendor, "{e}");
    assert!(e.reason.contains("truncated"), "{e}");
    let mut v2 = bytes.clone();
    v2[0] = 2;
    let e = refused("v2.ibw", &v2);
    assert!(e.reason.contains("version 5"), "{e}");
    // Dimensions whose byte count overflows (type 4, 2³¹−2 × 2³⁰+1 points): refused, no
    // overflow (debug builds check it).
    let mut huge = bytes[..384].to_vec();
    huge[64 + 16..64 + 18].copy_from_slice(&4i16.to_le_bytes());
    huge[64 + 68..64 + 72].copy_from_slice(&2_147_483_646i32.to_le_bytes());
    huge[64 + 72..64 + 76].copy_from_slice(&1_073_741_825i32.to_le_bytes());
    let e = refused("huge.ibw", &huge);
    assert_eq!(e.kind, ErrorKind::Vendor, "{e}");
    let e = refused("empty.ibw", &[]);
    assert!(e.reason.contains("empty"), "{e}");
    // No spring constant in the note and none given: the flag is named.
    let key = b"SpringConstant:";
    let at = bytes.windows(key.len()).position(|w| w == key).unwrap();
    let mut nok = bytes.clone();
    nok[at..at + 6].copy_from_slice(b"Spring");
    nok[at + 6] = b'X';
    let e = refused("nok.ibw", &nok);
    assert!(
        e.fix.as_deref().unwrap_or("").contains("--spring-constant"),
        "{e}"
    );
    // Every byte of the headers, and a stretch of the note, set to other values: refused or
    // read, never a panic (a deterministic sweep; `cargo xtask fuzz` covers JPK and AFM Workshop).
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for i in (0..384).chain((bytes.len() - 2000..bytes.len()).step_by(7)) {
        for _ in 0..3 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let mut m = bytes.clone();
            m[i] = (x >> 24) as u8;
            let p = dir.path().join("m.ibw");
            std::fs::write(&p, &m).unwrap();
            let _ = import_all(&p, &tip());
        }
    }
}
