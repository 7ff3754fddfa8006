//! A JPK QI map's curves, end to end: `tests/data/afmformats/` holds a `.jpk-qi-data` file
//! from afmformats' test data (MIT licence beside it), a file outside `shared/data/real/`.
//! QI curves are fast: 600 rows at 10.7 kHz, 28 ms of approach, of which the tip touches the
//! sample for the last ~1.5 ms (15 rows, ~3.6 nm of deflection at 0.1 nN). identify refused
//! all four ("no positive stiffness") while its filters kept a 10 ms memory and skipped their
//! first 30 ms: the contact fell inside the skip. The checks are physical: the contact inside
//! the approach before the force passes the threshold, the approach's contact rows fitted to
//! the deflection noise, and one sample's four neighbouring pixels (78 nm apart) alike.

use std::path::PathBuf;
use visco::identify::force_curve::ForceCurveFit;
use visco::identify::{identify, Options, Outcome};
use visco::recording::import::{import_all, ImportOptions};

const QI: &str = "fmt-jpk-fd_2020.02.07-16.29.05.036.jpk-qi-data";

fn qi_file() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/afmformats"
    ))
    .join(QI)
}

fn identify_all() -> Vec<ForceCurveFit> {
    let opts = ImportOptions {
        tip_radius_m: Some(5e-6),
        ..Default::default()
    };
    let curves = import_all(&qi_file(), &opts).unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    curves
        .into_iter()
        .map(|(curve, rec)| {
            let path = dir.path().join(format!("qi{curve}.csv"));
            rec.write(&path).unwrap();
            let json = dir.path().join(format!("qi{curve}.json"));
            let report = identify(&path, &Options::new(&json))
                .unwrap_or_else(|e| panic!("QI curve {curve}: {e}"));
            let Outcome::ForceCurve(fit) = report.outcome else {
                panic!("QI curve {curve}: not a force curve")
            };
            *fit
        })
        .collect()
}

#[test]
fn jpk_qi_curves_touch_briefly_and_are_fitted_to_the_noise() {
    let fits = identify_all();
    assert_eq!(fits.len(), 4, "the file holds four curves");
    let d_rec: Vec<Vec<f64>> = {
        let opts = ImportOptions {
            tip_radius_m: Some(5e-6),
            ..Default::default()
        };
        import_all(&qi_file(), &opts)
            .unwrap()
            .into_iter()
            .map(|(_, r)| r.d_m)
            .collect()
    };
    for (i, (f, d)) in fits.iter().zip(&d_rec).enumerate() {
        let sigma = f.baseline.noise_m;
        println!(
            "QI curve {i}: contact row {} (threshold {}, approach ends {}), k_a {:.3e} N/m³, \
             δ_max {:.1} nm, λ {:.3} ms, noise {:.3} nm",
            f.contact_row + 1,
            f.threshold_row + 1,
            f.approach.end,
            f.k_a_n_per_m3,
            f.max_depth_m * 1e9,
            f.lambda_s * 1e3,
            sigma * 1e9
        );
        assert!(f.k_a_n_per_m3 > 0.0, "curve {i}: a positive stiffness");
        assert!(
            f.contact_row >= f.baseline.free_rows.end && f.contact_row <= f.threshold_row,
            "curve {i}: the contact between the free part and the threshold crossing"
        );
        // The approach's rows in contact, recorded against simulated: ~15 rows of noise σ,
        // whose RMS has a standard error of σ/√30 (18 %); 2σ is 5 of them. Left unfitted
        // (k_a = 0), the 3.6 nm of deflection there is ~6σ.
        let rows = f.contact_row..f.approach.end;
        let n = rows.len() as f64;
        let rms = (rows
            .map(|r| (d[r] - f.simulated_d_m[r]).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        println!(
            "QI curve {i}: approach in contact, {n} rows: RMS misfit {:.3} nm = {:.2}σ",
            rms * 1e9,
            rms / sigma
        );
        assert!(
            rms <= 2.0 * sigma,
            "curve {i}: the contact fitted to the noise ({rms:e} m against σ {sigma:e} m)"
        );
    }
    // Four pixels 78 nm apart on one sample: the same stiffness within a factor of two.
    let log_mean = fits.iter().map(|f| f.k_a_n_per_m3.ln()).sum::<f64>() / fits.len() as f64;
    for (i, f) in fits.iter().enumerate() {
        let ratio = f.k_a_n_per_m3 / log_mean.exp();
        assert!(
            (0.5..=2.0).contains(&ratio),
            "curve {i}: k_a {:e} is {ratio:.2}× the four's geometric mean",
            f.k_a_n_per_m3
        );
    }
}
