//! Optics11 Chiaro text exports, end to end: afmformats' test file (`tests/data/afmformats/`,
//! zipped as afmformats ships it; MIT licence beside it), one indentation of a soft sample
//! with a 27.5 µm probe. Checked: the calibrations and the time base the export carries, the
//! segments split at the piezo's deepest position, the signs (pushed up at the turn), the
//! vendor's load against −k·D, and identify on the result.

use std::io::Read;
use std::path::PathBuf;
use visco::identify::{identify, Options, Outcome};
use visco::recording::import::{import_all, ImportOptions};

const ZIP: &str = "fmt-chiaro-txt_AEBP1_Indentation_002.zip";
const TXT: &str = "fmt-chiaro-txt_AEBP1_Indentation_002.txt";

/// The export, unzipped into `dir`.
fn unzipped(dir: &std::path::Path) -> PathBuf {
    let zip = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/afmformats"
    ))
    .join(ZIP);
    let mut arc = zip::ZipArchive::new(std::fs::File::open(zip).unwrap()).unwrap();
    let mut bytes = Vec::new();
    arc.by_name(TXT).unwrap().read_to_end(&mut bytes).unwrap();
    let p = dir.join(TXT);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn chiaro_export_imports_with_its_calibrations_and_identifies() {
    let dir = tempfile::tempdir().unwrap();
    let txt = unzipped(dir.path());
    let mut all = import_all(&txt, &ImportOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(all.len(), 1);
    let rec = all.remove(0).1;
    let m = &rec.meta;
    assert_eq!(m.get("source_format"), Some("chiaro-txt"));
    assert_eq!(m.cantilever_k_n_per_m, 0.019, "k (N/m) from the file");
    assert_eq!(m.tip_radius_m, 27.5e-6, "Tip radius (um) from the file");
    assert_eq!(m.get("tip_radius_source"), Some("file"));
    assert_eq!(m.sample_rate_hz, 1000.0, "1 ms rows");
    assert_eq!(rec.len(), 13_827, "every data row");
    assert_eq!(m.get("segment_points"), Some("12665,1162"));
    // The piezo's deepest position ends the extend: U is z up, lowest there.
    let turn = 12_664;
    let u_min = rec.u_m.iter().copied().fold(f64::INFINITY, f64::min);
    assert_eq!(rec.u_m[turn], u_min);
    // Pushed up at the turn: D far below its free level (the first second's median).
    let mut free: Vec<f64> = rec.d_m[..1000].to_vec();
    free.sort_by(f64::total_cmp);
    let level = free[500];
    println!(
        "free level {:.1} nm, D at the turn {:.1} nm",
        level * 1e9,
        rec.d_m[turn] * 1e9
    );
    assert!(
        rec.d_m[turn] < level - 1e-6,
        "pushed up by over a micrometre"
    );
    // The vendor's load is k times its deflection (printed to 1 pN): −k·D here.
    let load = &rec
        .extra
        .iter()
        .find(|c| c.name == "force_vendor_n")
        .unwrap()
        .values;
    let worst = (0..rec.len())
        .map(|i| (load[i] + 0.019 * rec.d_m[i]).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-12,
        "Load = −k·D within its printed digits ({worst:e} N)"
    );
    // identify: the contact inside the approach, before the threshold crossing.
    let csv = dir.path().join("chiaro.csv");
    rec.write(&csv).unwrap();
    let report = identify(&csv, &Options::new(dir.path().join("chiaro.json")))
        .unwrap_or_else(|e| panic!("{e}"));
    let Outcome::ForceCurve(fit) = report.outcome else {
        panic!("not a force curve")
    };
    println!(
        "contact row {}, threshold row {}, k_a {:.3e} N/m³, δ_max {:.2} µm",
        fit.contact_row + 1,
        fit.threshold_row + 1,
        fit.k_a_n_per_m3,
        fit.max_depth_m * 1e6
    );
    assert!(fit.k_a_n_per_m3 > 0.0);
    assert!(
        fit.contact_row > fit.baseline.free_rows.end
            && fit.contact_row <= fit.threshold_row
            && fit.threshold_row < turn
    );
}

#[test]
fn a_chiaro_export_without_its_table_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let txt = unzipped(dir.path());
    let text = std::fs::read(&txt).unwrap();
    let cut = text.windows(8).position(|w| w == b"Time (s)").unwrap();
    let p = dir.path().join("header-only.txt");
    std::fs::write(&p, &text[..cut]).unwrap();
    let e = match import_all(&p, &ImportOptions::default()) {
        Ok(_) => panic!("accepted"),
        Err(e) => e,
    };
    // Known by its device line, refused for the missing table (not read as another format).
    assert!(e.reason.contains("no data table"), "{e}");
    // A bad number in the table names the line and the column.
    let mut bad = text.clone();
    let row = cut + text[cut..].iter().position(|b| *b == b'\n').unwrap() + 1;
    bad[row] = b'x';
    let p = dir.path().join("bad.txt");
    std::fs::write(&p, &bad).unwrap();
    let e = match import_all(&p, &ImportOptions::default()) {
        Ok(_) => panic!("accepted"),
        Err(e) => e,
    };
    assert!(
        e.reason.contains("Time (s)") && e.reason.contains("not a number"),
        "{e}"
    );
    assert_eq!(e.line, Some(38), "{e}");
}
