//! Helpers shared by the `recording_*` integration tests.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use visco::recording::import::{import_all, ImportOptions};
use visco::recording::Recording;

/// The shared real-data folder (`shared/` sits beside the repository).
pub const REAL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/real/");

pub const SPOT3: &str = "fmt-jpk-fd_spot3-0192.jpk-force";
pub const SR: &str = "fmt-jpk-sr_cell1-0008.jpk-force";
pub const CC: &str = "fmt-jpk-cc_pr14-polymergel-2021.06.30.jpk-force";
pub const MAP: &str = "fmt-jpk-fd_map2x2_extracted.jpk-force-map";
pub const WORKSHOP: &str = "fmt-afm-workshop-fd_single_2021-10-22_14.16.csv";
pub const NTMDT: &str = "fmt-ntmdt-txt-fd_2015_01_17_gel4-0,1_mQ_adh_6B_Curve_DFL_Height_51.txt";

/// A real file, looked for in: `$VISCO_SHARED_DIR/data/real/`, then the repository's sibling
/// `shared/` (as in CI: `concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/real/")`),
/// then `shared/` beside any ancestor (git worktrees that live deeper than the main clone).
/// A missing file fails the test: these tests never skip.
pub fn real(name: &str) -> PathBuf {
    let mut candidates: Vec<PathBuf> = Vec::new();
    if let Some(dir) = std::env::var_os("VISCO_SHARED_DIR") {
        candidates.push(Path::new(&dir).join("data/real"));
    }
    candidates.push(PathBuf::from(REAL));
    for anc in Path::new(env!("CARGO_MANIFEST_DIR")).ancestors() {
        candidates.push(anc.join("shared/data/real"));
    }
    for c in &candidates {
        let p = c.join(name);
        if p.is_file() {
            return p;
        }
    }
    panic!(
        "real data file {name} not found in {candidates:?}; set VISCO_SHARED_DIR to the shared/ folder"
    );
}

/// Options with only the tip radius (what every JPK file needs).
pub fn tip_only() -> ImportOptions {
    ImportOptions {
        tip_radius_m: Some(5e-6),
        ..ImportOptions::default()
    }
}

/// Options for files with no calibration or time base at all.
pub fn everything() -> ImportOptions {
    ImportOptions {
        spring_constant_n_per_m: Some(0.1),
        sensitivity_m_per_unit: Some(5e-8),
        tip_radius_m: Some(5e-6),
        sample_rate_hz: Some(1000.0),
    }
}

pub fn import_one(name: &str, opts: &ImportOptions) -> Recording {
    let mut all = import_all(&real(name), opts).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(all.len(), 1, "{name}: one curve expected");
    all.remove(0).1
}

/// Rows of one segment number.
pub fn segment_range(rec: &Recording, segment: f64) -> std::ops::Range<usize> {
    let seg = rec.extra_column("segment").expect("segment column");
    let start = seg
        .iter()
        .position(|&s| s == segment)
        .expect("segment present");
    let end = seg
        .iter()
        .rposition(|&s| s == segment)
        .expect("segment present")
        + 1;
    assert!(
        seg[start..end].iter().all(|&s| s == segment),
        "segment {segment} not contiguous"
    );
    start..end
}

/// Column-by-column, bit-for-bit equality.
pub fn assert_bit_exact(a: &Recording, b: &Recording) {
    assert_eq!(a.meta, b.meta);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.t_s), bits(&b.t_s), "t_s");
    assert_eq!(bits(&a.u_m), bits(&b.u_m), "u_m");
    assert_eq!(bits(&a.d_m), bits(&b.d_m), "d_m");
    assert_eq!(
        a.x_m.as_deref().map(bits),
        b.x_m.as_deref().map(bits),
        "x_m"
    );
    assert_eq!(
        a.y_m.as_deref().map(bits),
        b.y_m.as_deref().map(bits),
        "y_m"
    );
    assert_eq!(a.tap, b.tap, "tap");
    assert_eq!(a.extra.len(), b.extra.len());
    for (x, y) in a.extra.iter().zip(&b.extra) {
        assert_eq!(x.name, y.name);
        assert_eq!(bits(&x.values), bits(&y.values), "{}", x.name);
    }
}

/// Copies a real zip archive member by member (stored, uncompressed), letting `edit` change a
/// member's bytes or drop it (`None`).
pub fn rezip(src: &Path, dst: &Path, edit: impl Fn(&str, Vec<u8>) -> Option<Vec<u8>>) {
    let mut zin = zip::ZipArchive::new(std::fs::File::open(src).unwrap()).unwrap();
    let mut zout = zip::ZipWriter::new(std::fs::File::create(dst).unwrap());
    let opts =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for i in 0..zin.len() {
        let mut f = zin.by_index(i).unwrap();
        let name = f.name().to_string();
        if f.is_dir() {
            continue;
        }
        let mut bytes = Vec::new();
        f.read_to_end(&mut bytes).unwrap();
        if let Some(b) = edit(&name, bytes) {
            zout.start_file(name.as_str(), opts).unwrap();
            zout.write_all(&b).unwrap();
        }
    }
    zout.finish().unwrap();
}

/// Replaces one `key=value` line of a properties member.
pub fn set_property(bytes: Vec<u8>, key: &str, value: Option<&str>) -> Vec<u8> {
    let text = String::from_utf8(bytes).unwrap();
    let prefix = format!("{key}=");
    assert!(text.lines().any(|l| l.starts_with(&prefix)), "no {key}");
    let mut out = String::new();
    for line in text.lines() {
        if line.starts_with(&prefix) {
            if let Some(v) = value {
                out.push_str(&format!("{key}={v}\n"));
            }
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out.into_bytes()
}

/// The 1-based line of `key` in a properties member.
pub fn line_of(bytes: &[u8], key: &str) -> u64 {
    let text = String::from_utf8_lossy(bytes);
    let prefix = format!("{key}=");
    text.lines()
        .position(|l| l.starts_with(&prefix))
        .expect("key") as u64
        + 1
}

/// Names of the files in a directory.
pub fn dir_listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}
