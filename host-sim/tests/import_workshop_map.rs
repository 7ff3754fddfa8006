//! An AFM Workshop map as the instrument writes it (one CSV per point), zipped: afmformats'
//! 16-point test map (`tests/data/afmformats/`, MIT licence beside it). It imports as a map of
//! 16 curves on a 4 × 4 grid, each pushed up at its turn, and identifies.

use std::path::PathBuf;
use visco::identify::{identify, Options, Outcome};
use visco::recording::import::{import_all, Import, ImportOptions};

const MAP: &str = "fmt-afm-workshop-fd_mapping_16_2018-08-01_13.07.zip";

#[test]
fn afm_workshop_zipped_map_imports_as_sixteen_curves_on_a_grid() {
    let path = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/afmformats"
    ))
    .join(MAP);
    // T-B(V) files: the sensitivity, k and rate are the user's (the files hold none).
    let opts = ImportOptions {
        spring_constant_n_per_m: Some(0.1),
        sensitivity_m_per_unit: Some(7e-8),
        sample_rate_hz: Some(2000.0),
        tip_radius_m: Some(5e-6),
    };
    assert!(Import::open(&path, &opts).unwrap().is_map());
    let all = import_all(&path, &opts).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(all.len(), 16);
    let pos = |r: &visco::recording::Recording, k: &str| -> f64 {
        r.meta.get(k).unwrap().parse().unwrap()
    };
    let mut xs: Vec<f64> = all.iter().map(|(_, r)| pos(r, "position_x_m")).collect();
    let mut ys: Vec<f64> = all.iter().map(|(_, r)| pos(r, "position_y_m")).collect();
    for v in [&mut xs, &mut ys] {
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    }
    assert_eq!((xs.len(), ys.len()), (4, 4), "a 4 × 4 grid: {xs:?} {ys:?}");
    let dir = tempfile::tempdir().unwrap();
    let mut identified = 0;
    for (c, rec) in &all {
        assert_eq!(
            rec.meta.get("point"),
            Some((c + 1).to_string().as_str()),
            "curve {c}: Point"
        );
        let n_ext: usize = rec
            .meta
            .get("segment_points")
            .unwrap()
            .split(',')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        let turn = n_ext - 1;
        let free = rec.d_m[..n_ext / 5].iter().sum::<f64>() / (n_ext / 5) as f64;
        assert!(
            rec.d_m[turn] < free - 5e-9,
            "curve {c}: pushed up at the turn"
        );
        let csv = dir.path().join(format!("c{c}.csv"));
        rec.write(&csv).unwrap();
        if let Ok(r) = identify(&csv, &Options::new(dir.path().join(format!("c{c}.json")))) {
            if let Outcome::ForceCurve(f) = r.outcome {
                identified += usize::from(f.k_a_n_per_m3 > 0.0 && f.contact_row < turn);
            }
        }
    }
    println!("identified {identified} of 16");
    assert_eq!(identified, 16, "every point identified");
}
