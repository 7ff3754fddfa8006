//! Renders the sample figures and files of the output layer from synthetic data (a cell
//! dome with a nucleus) into `target/output-samples/`, and checks each PNG decodes, has the
//! expected size and is not blank. Look at them to judge the figures.

mod output_support;

use std::path::PathBuf;

use output_support::{cell, decode_png, noise};
use visco::output::figure::{
    self, fit_power_law, Colormap, LinePanel, LinePlot, MapStyle, Quantity, ScatterFit, Series,
};
use visco::output::{csv, gsf, Grid, Map};

fn samples_dir() -> PathBuf {
    // CARGO_TARGET_TMPDIR is <target>/tmp for integration tests.
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .unwrap()
        .join("output-samples");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// An "estimate": the given map averaged onto `grid`, with noise and a bias at steep pixels.
fn estimate(given: &Map, steep: &Map, grid: Grid, noise_frac: f64, seed: u64, name: &str) -> Map {
    let mut m = given.resample_mean(grid).renamed(name);
    let full = given.stats().max;
    for j in 0..grid.ny {
        for i in 0..grid.nx {
            let (x, y) = grid.centre(i, j);
            let st = steep.sample_bilinear(x, y);
            let bias = if st > 0.25 {
                0.06 * full * noise(seed + 7, i, j).signum()
            } else {
                0.0
            };
            let v = m.get(i, j) + noise_frac * full * noise(seed, i, j) + bias;
            m.set(i, j, v);
        }
    }
    m
}

#[test]
fn render_sample_figures() {
    let dir = samples_dir();
    let (h, c, k) = cell();
    let slope = h.gradient_magnitude();
    let steep = slope.threshold("steep: |∇h| > 0.25", |s| s > 0.25);
    let dive_grid = Grid::over(20, 20, 0.0, 5e-6, 0.0, 5e-6);
    let sve_grid = Grid::over(50, 20, 0.0, 5e-6, 0.0, 5e-6);
    let mut out = Vec::new();

    let maps = [
        (&h, "h", "Topography h", 0.3e-6),
        (&c, "c", "Damping coefficient c", 8e-7),
        (&k, "k", "Spring constant k", 5e-3),
    ];
    for (n, (given, sym, title, full)) in maps.iter().enumerate() {
        let dive = estimate(given, &slope, dive_grid, 0.01, 10 + n as u64, "DIVE");
        let mut sve = estimate(given, &slope, sve_grid, 0.015, 20 + n as u64, "SVE");
        // A few missing SVE pixels (a lost line segment) to show "no data".
        for i in 3..9 {
            sve.set(i, 17, f64::NAN);
        }
        let p = dir.join(format!("map_{sym}.png"));
        figure::map_panels(
            &p,
            &[(given, "given"), (&dive, "DIVE"), (&sve, "SVE")],
            &MapStyle {
                title: Some(title.to_string()),
                quantity: Some(Quantity::new(*sym, given.unit.clone())),
                ..Default::default()
            },
        )
        .unwrap();
        out.push(p);
        if n == 1 {
            // The same figure at print resolution (every size doubled).
            let p = dir.join("map_c_print.png");
            figure::map_panels(
                &p,
                &[(given, "given"), (&dive, "DIVE"), (&sve, "SVE")],
                &MapStyle {
                    title: Some(title.to_string()),
                    quantity: Some(Quantity::new(*sym, given.unit.clone())),
                    scale: 2.0,
                    ..Default::default()
                },
            )
            .unwrap();
            out.push(p);
        }
        // Errors in % of the property's maximum, on each estimate's grid, steep pixels hatched.
        let e_dive = Map::error_percent(&dive, &given.resample_mean(dive_grid), *full).unwrap();
        let e_sve = Map::error_percent(&sve, &given.resample_mean(sve_grid), *full).unwrap();
        let p = dir.join(format!("error_{sym}.png"));
        figure::map_panels(
            &p,
            &[(&e_dive, "DIVE"), (&e_sve, "SVE")],
            &MapStyle {
                title: Some(format!("Error of {sym} in % of {sym}_max")),
                quantity: Some(Quantity::new(format!("error of {sym}"), "%")),
                colormap: Colormap::Diverging,
                mask: Some(&steep),
                ..Default::default()
            },
        )
        .unwrap();
        out.push(p);
        if n == 0 {
            gsf::write_gsf(&dir.join("h_given.gsf"), given, Default::default()).unwrap();
            gsf::write_gsf(&dir.join("h_sve.gsf"), &sve, Default::default()).unwrap();
            gsf::write_gsf_mask(&dir.join("h_sve_nodata.gsf"), &sve).unwrap();
            csv::write_csv(&dir.join("h_dive.csv"), &dive).unwrap();
        }
    }

    // Shaded relief of the topography.
    let p = dir.join("relief_h.png");
    figure::map_panels(
        &p,
        &[(&h, "given")],
        &MapStyle {
            title: Some("Topography (shaded relief)".into()),
            quantity: Some(Quantity::new("h", "m")),
            relief: true,
            panel_px: 380,
            letters: false,
            ..Default::default()
        },
    )
    .unwrap();
    out.push(p);

    // Fig. 8-like convergence along the cross-section y = 2.5 µm (SVE, spatial domain).
    let y = 2.5e-6;
    let xs: Vec<f64> = (0..=2000).map(|i| i as f64 * 5e-6 / 2000.0).collect();
    let given_line =
        |m: &Map| -> Vec<(f64, f64)> { xs.iter().map(|&x| (x, m.sample_bilinear(x, y))).collect() };
    let est_line = |m: &Map, tau: f64, amp: f64| -> Vec<(f64, f64)> {
        // A first-order tracker with ripple: converges to the given profile from 0.
        let mut v = 0.0;
        let mut out = Vec::new();
        let dx = xs[1] - xs[0];
        for (i, &x) in xs.iter().enumerate() {
            let target = m.sample_bilinear(x, y);
            if target.is_finite() {
                v += (target - v) * (dx / tau).min(1.0);
            }
            out.push((x, v * (1.0 + amp * (i as f64 * 0.9).sin())));
        }
        out
    };
    let mut panels = Vec::new();
    for (m, sym) in [(&h, "h"), (&c, "c"), (&k, "k")] {
        panels.push(LinePanel {
            y: Quantity::new(sym, m.unit.clone()),
            series: vec![
                Series::dashed("given", given_line(m)).with_color([0, 0, 0]),
                Series::line("SVE estimate", est_line(m, 0.08e-6, 0.01)),
            ],
            ..Default::default()
        });
    }
    panels.push(LinePanel {
        y: Quantity::new("U", "m"),
        series: vec![Series::line(
            "",
            xs.iter()
                .enumerate()
                .map(|(i, &x)| {
                    (
                        x,
                        h.sample_bilinear(x, y) - 150e-9 + 10e-9 * (i as f64 * 0.9).sin(),
                    )
                })
                .collect(),
        )
        .with_color([90, 90, 90])],
        ..Default::default()
    });
    let p = dir.join("convergence_sve.png");
    figure::lines(
        &p,
        &LinePlot {
            title: Some("Convergence along the cross-section y = 2.5 µm (SVE)".into()),
            x: Quantity::new("x", "m"),
            panels,
            ..Default::default()
        },
    )
    .unwrap();
    out.push(p);

    // Fig. 8a-like: DIVE in the time domain, 4 taps of 0.2 s.
    let t: Vec<f64> = (0..40_000).map(|i| i as f64 * 20e-6).collect();
    let tap_c: Vec<(f64, f64)> = t
        .iter()
        .map(|&t| {
            let tap = (t / 0.2).floor();
            let target = 5e-7 + 0.6e-7 * tap;
            let tt = t - tap * 0.2;
            (
                t,
                if tt < 0.01 {
                    f64::NAN
                } else {
                    target * (1.0 - (-(tt - 0.01) / 0.02).exp())
                },
            )
        })
        .collect();
    let tap_given: Vec<(f64, f64)> = t
        .iter()
        .map(|&t| (t, 5e-7 + 0.6e-7 * (t / 0.2).floor()))
        .collect();
    let p = dir.join("convergence_dive_time.png");
    figure::lines(
        &p,
        &LinePlot {
            title: Some("DIVE: damping estimate during four taps".into()),
            x: Quantity::new("t", "s"),
            panels: vec![LinePanel {
                y: Quantity::new("c", "N·s/m"),
                series: vec![
                    Series::dashed("given", tap_given).with_color([0, 0, 0]),
                    Series::line("DIVE estimate", tap_c),
                ],
                ..Default::default()
            }],
            panel_height: 260,
            ..Default::default()
        },
    )
    .unwrap();
    out.push(p);

    // Fig. 9-like: spring force against depth with the power-law fit.
    let pts: Vec<(f64, f64)> = (1..=100)
        .map(|i| {
            let d = i as f64 * 2e-9;
            let f = 1.6e-3 * (d / 1e-9).powf(1.72) * 1e-9 * (1.0 + 0.02 * noise(3, i, 0));
            (d, f)
        })
        .collect();
    let (law, _) = fit_power_law(&pts).unwrap();
    for (name, log_log) in [("force_depth.png", false), ("force_depth_loglog.png", true)] {
        let p = dir.join(name);
        figure::scatter_fit(
            &p,
            &ScatterFit {
                title: Some("Spring force against indentation depth".into()),
                x: Quantity::new("δ", "m"),
                y: Quantity::new("F_k", "N"),
                points: pts.clone(),
                points_label: "simulation".into(),
                fit: Some(law),
                log_log,
                ..Default::default()
            },
        )
        .unwrap();
        out.push(p);
    }

    for p in &out {
        let img = decode_png(p);
        assert!(img.width > 300 && img.height > 200, "{}", p.display());
        assert!(img.distinct_colors() > 20, "{} looks blank", p.display());
    }
    eprintln!("sample figures in {}", dir.display());
}
