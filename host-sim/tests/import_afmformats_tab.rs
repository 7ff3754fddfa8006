//! The afmformats package's own `.tab` export (what nanite and PyJibe users save), end to end:
//! its test file of version 0.13.3 (`tests/data/afmformats/`, MIT licence beside it), a JPK
//! CellHesion curve. That version glued the first row to the line naming the columns; the row
//! is kept, in step with the others.

use std::path::PathBuf;
use visco::identify::{identify, Options, Outcome};
use visco::recording::import::{import_all, ImportOptions};

#[test]
fn afmformats_tab_export_imports_with_its_metadata_and_identifies() {
    let path = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/afmformats"
    ))
    .join("fmt-tab-fd_version_0.13.3.tab");
    let opts = ImportOptions {
        tip_radius_m: Some(5e-6),
        ..Default::default()
    };
    let rec = import_all(&path, &opts)
        .unwrap_or_else(|e| panic!("{e}"))
        .remove(0)
        .1;
    let m = &rec.meta;
    assert_eq!(m.get("source_format"), Some("afmformats-tab"));
    assert_eq!(
        m.cantilever_k_n_per_m, 0.02230065831827453,
        "the metadata's spring constant"
    );
    assert_eq!(m.sample_rate_hz, 2000.0);
    assert_eq!(m.get("instrument"), Some("JPK00758-CellHesion-200"));
    // 4028 rows below the names and the one glued to them, 0.5 ms apart throughout.
    assert_eq!(rec.len(), 4029);
    assert!(rec
        .t_s
        .windows(2)
        .all(|w| (w[1] - w[0] - 5e-4).abs() < 1e-9));
    assert_eq!(rec.u_m[0], 5.5198847e-05, "the glued row's height");
    assert_eq!(m.get("segment_points"), Some("3147,882"));
    // D = −force/k, and the force kept.
    let f = &rec
        .extra
        .iter()
        .find(|c| c.name == "force_vendor_n")
        .unwrap()
        .values;
    assert!((0..rec.len()).all(|i| (rec.d_m[i] + f[i] / 0.02230065831827453).abs() < 1e-18));
    // U falls towards the sample; at the turn the sample pushes the lever up.
    let turn = 3146;
    assert!(rec.u_m[turn] < rec.u_m[0] - 1e-6);
    let free = rec.d_m[..500].iter().sum::<f64>() / 500.0;
    assert!(rec.d_m[turn] < free - 1e-7, "pushed up at the turn");
    // A flag's k is the recording's; the deflection stays the force over the file's k, with
    // which the force was computed.
    let flagged = ImportOptions {
        spring_constant_n_per_m: Some(0.05),
        ..opts
    };
    let other = import_all(&path, &flagged).unwrap().remove(0).1;
    assert_eq!(other.meta.cantilever_k_n_per_m, 0.05);
    assert_eq!(other.d_m, rec.d_m);
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("tab.csv");
    rec.write(&csv).unwrap();
    let r = identify(&csv, &Options::new(dir.path().join("tab.json")))
        .unwrap_or_else(|e| panic!("{e}"));
    let Outcome::ForceCurve(fit) = r.outcome else {
        panic!("not a force curve")
    };
    println!(
        "contact row {}, k_a {:.3e} N/m³, δ_max {:.2} µm",
        fit.contact_row + 1,
        fit.k_a_n_per_m3,
        fit.max_depth_m * 1e6
    );
    // The contact inside the approach, after its free part (here at the threshold crossing:
    // the report's note says the bed's onset would prefer it later).
    assert!(fit.k_a_n_per_m3 > 0.0);
    assert!(fit.contact_row > fit.baseline.free_rows.end && fit.contact_row < turn);
}
