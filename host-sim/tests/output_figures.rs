//! PNG figures: they decode, have the expected size, are not blank, show their colour bars,
//! draw NaN grey, and refuse bad paths with an error that names the path.

mod output_support;

use output_support::{cell, decode_png};
use visco::output::figure::{
    self, Colormap, LinePanel, LinePlot, MapStyle, PowerLaw, Quantity, ScatterFit, Series, NO_DATA,
};
use visco::output::{Grid, Map};

const VIRIDIS_LOW: [u8; 3] = [68, 1, 84];
const VIRIDIS_HIGH: [u8; 3] = [253, 231, 37];
const BLUE_END: [u8; 3] = [5, 48, 97];
const RED_END: [u8; 3] = [103, 0, 31];

fn count(img: &output_support::Image, c: [u8; 3]) -> usize {
    img.rgb.chunks_exact(3).filter(|p| *p == c).count()
}

/// Pixels within a few levels of `c` (the ends of a colour bar, blended by its frame).
fn near(img: &output_support::Image, c: [u8; 3]) -> usize {
    img.rgb
        .chunks_exact(3)
        .filter(|p| {
            p.iter()
                .zip(c)
                .all(|(&a, b)| (a as i32 - b as i32).abs() <= 12)
        })
        .count()
}

#[test]
fn map_panels_decode_with_expected_size_and_colour_bar() {
    let dir = tempfile::tempdir().unwrap();
    let (h, c, _) = cell();
    let one = dir.path().join("one.png");
    let three = dir.path().join("three.png");
    let style = MapStyle {
        title: Some("Damping coefficient".into()),
        ..Default::default()
    };
    figure::map_panels(&one, &[(&c, "given")], &style).unwrap();
    figure::map_panels(&three, &[(&c, "given"), (&c, "DIVE"), (&c, "SVE")], &style).unwrap();
    let a = decode_png(&one);
    let b = decode_png(&three);
    // Same height; each extra panel adds its width (300 px) and a gap.
    assert_eq!(a.height, b.height);
    assert!(a.height >= 300 + 60 && a.height < 520, "{}", a.height);
    let extra = b.width - a.width;
    assert!((2 * 300..2 * 300 + 2 * 40).contains(&extra), "{extra}");
    // Not blank, and both ends of the colour bar are there.
    assert!(a.variance() > 500.0, "{}", a.variance());
    assert!(near(&a, VIRIDIS_LOW) > 50 && near(&a, VIRIDIS_HIGH) > 10);
    // Scale 2 doubles everything (within rounding).
    let big = dir.path().join("big.png");
    figure::map_panels(
        &big,
        &[(&h, "given")],
        &MapStyle {
            scale: 2.0,
            ..Default::default()
        },
    )
    .unwrap();
    let g = decode_png(&big);
    let small = decode_png(&{
        let p = dir.path().join("small.png");
        figure::map_panels(&p, &[(&h, "given")], &MapStyle::default()).unwrap();
        p
    });
    let ratio = g.width as f64 / small.width as f64;
    assert!((ratio - 2.0).abs() < 0.05, "{ratio}");
}

#[test]
fn nan_pixels_are_grey_and_errors_use_a_symmetric_diverging_bar() {
    let dir = tempfile::tempdir().unwrap();
    let g = Grid::over(10, 10, 0.0, 5e-6, 0.0, 5e-6);
    let mut e = Map::from_fn(g, "error", "%", |x, y| (x - 2.5e-6) * 1e6 + 0.3 * (y * 1e6));
    for i in 0..4 {
        e.set(i, 9, f64::NAN);
    }
    let p = dir.path().join("err.png");
    figure::map_panels(
        &p,
        &[(&e, "DIVE")],
        &MapStyle {
            colormap: Colormap::Diverging,
            ..Default::default()
        },
    )
    .unwrap();
    let img = decode_png(&p);
    // Four 30 × 30 px cells of no data (plus the legend swatch).
    assert!(
        count(&img, NO_DATA) > 4 * 25 * 25,
        "{}",
        count(&img, NO_DATA)
    );
    assert!(near(&img, BLUE_END) > 10 && near(&img, RED_END) > 10);
    // Without NaN there is no grey block (anti-aliased text may hit the grey by chance).
    let full = Map::from_fn(g, "error", "%", |x, _| x * 1e6);
    let p2 = dir.path().join("full.png");
    figure::map_panels(&p2, &[(&full, "SVE")], &MapStyle::default()).unwrap();
    assert!(count(&decode_png(&p2), NO_DATA) < 100);
    // An all-NaN map still draws (a grey panel), not a panic.
    let empty = Map::new(g, "h", "m");
    let p3 = dir.path().join("empty.png");
    figure::map_panels(&p3, &[(&empty, "none")], &MapStyle::default()).unwrap();
    assert!(count(&decode_png(&p3), NO_DATA) > 250 * 250);
}

#[test]
fn mask_overlay_hatches_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let (h, c, _) = cell();
    let steep = h.gradient_magnitude().threshold("steep", |s| s > 0.25);
    let with = dir.path().join("with.png");
    let without = dir.path().join("without.png");
    figure::map_panels(
        &with,
        &[(&c, "c")],
        &MapStyle {
            mask: Some(&steep),
            ..Default::default()
        },
    )
    .unwrap();
    figure::map_panels(&without, &[(&c, "c")], &MapStyle::default()).unwrap();
    let (a, b) = (decode_png(&with), decode_png(&without));
    let dark = |img: &output_support::Image| {
        img.rgb
            .chunks_exact(3)
            .filter(|p| p.iter().all(|&v| v < 40))
            .count()
    };
    assert!(dark(&a) > dark(&b) + 500, "{} vs {}", dark(&a), dark(&b));
}

#[test]
fn line_and_scatter_figures_decode() {
    let dir = tempfile::tempdir().unwrap();
    let xs: Vec<f64> = (0..500).map(|i| i as f64 * 1e-8).collect();
    let plot = LinePlot {
        title: Some("Convergence".into()),
        x: Quantity::new("x", "m"),
        panels: vec![
            LinePanel {
                y: Quantity::new("h", "m"),
                series: vec![
                    Series::dashed("given", xs.iter().map(|&x| (x, 1e-7 + x * 0.02)).collect()),
                    Series::line("SVE", xs.iter().map(|&x| (x, 1.1e-7 + x * 0.02)).collect()),
                ],
                ..Default::default()
            },
            LinePanel {
                y: Quantity::new("c", "N·s/m"),
                series: vec![Series::line(
                    "DIVE",
                    xs.iter().map(|&x| (x, 5e-7 + x * 1e-2)).collect(),
                )],
                ..Default::default()
            },
        ],
        width: 600,
        panel_height: 150,
        ..Default::default()
    };
    let p = dir.path().join("lines.png");
    figure::lines(&p, &plot).unwrap();
    let img = decode_png(&p);
    assert!(img.width > 600 && img.width < 760, "{}", img.width);
    assert!(img.height > 300 && img.height < 460, "{}", img.height);
    assert!(img.variance() > 50.0);
    // The first two palette colours are drawn (anti-aliased lines keep full colour at centre).
    assert!(count(&img, figure::PALETTE[0]) > 100);

    let pts: Vec<(f64, f64)> = (1..80)
        .map(|i| (i as f64 * 2.5e-9, 1.6e-12 * (i as f64 * 2.5).powf(1.72)))
        .collect();
    let (law, r2) = figure::fit_power_law(&pts).unwrap();
    assert!((law.b - 1.72).abs() < 1e-9 && r2 > 0.999);
    for log_log in [false, true] {
        let p = dir.path().join(format!("fd{log_log}.png"));
        figure::scatter_fit(
            &p,
            &ScatterFit {
                points: pts.clone(),
                fit: Some(law),
                log_log,
                ..Default::default()
            },
        )
        .unwrap();
        let img = decode_png(&p);
        assert!(img.width > 520 && img.height > 380);
        assert!(
            count(&img, figure::PALETTE[1]) > 50,
            "the fit line is drawn"
        );
    }
    // A power law with a non-positive x on log axes is an error, not a panic.
    let bad = dir.path().join("bad.png");
    let e = figure::scatter_fit(
        &bad,
        &ScatterFit {
            points: vec![(-1.0, 1.0), (0.0, 2.0)],
            fit: Some(PowerLaw { a: 1.0, b: 1.5 }),
            log_log: true,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("bad.png"), "{e}");
    assert!(!bad.exists());
}

/// A long title (identify's and diagnose's name the file and the findings) is set smaller and
/// kept inside the canvas: it was centred on the panels and cut at both edges.
#[test]
fn a_long_title_stays_inside_the_figure() {
    let dir = tempfile::tempdir().unwrap();
    let xs: Vec<f64> = (0..100).map(|i| i as f64).collect();
    let title = "fmt-jpk-cc-pr14-brain-2021-0.csv: left out: adhesion, thermal-drift, \
                 nonlinear-stiffness; yet the held-out RMS is 116.60× the noise";
    let plot = LinePlot {
        title: Some(title.into()),
        x: Quantity::new("t", "s"),
        panels: vec![LinePanel {
            y: Quantity::new("D", "m"),
            series: vec![Series::line(
                "D",
                xs.iter().map(|&x| (x, 1e-9 * x)).collect(),
            )],
            ..Default::default()
        }],
        width: 600,
        panel_height: 150,
        ..Default::default()
    };
    let p = dir.path().join("long.png");
    figure::lines(&p, &plot).unwrap();
    let img = decode_png(&p);
    // The title's band: the rows above the panel's frame.
    let band = 0..40u32;
    let dark = |x: u32| {
        band.clone()
            .any(|y| img.pixel(x, y).iter().all(|&v| v < 128))
    };
    assert!((0..img.width).any(dark), "the title is drawn");
    for x in (0..4).chain(img.width - 4..img.width) {
        assert!(
            !dark(x),
            "column {x} of {}: the title reaches the edge",
            img.width
        );
    }
}

#[test]
fn bad_paths_and_empty_inputs_name_the_path_and_leave_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let (h, _, _) = cell();
    let p = dir.path().join("missing-dir").join("h.png");
    let e = figure::map_panels(&p, &[(&h, "given")], &MapStyle::default()).unwrap_err();
    assert!(e.to_string().contains("missing-dir/h.png"), "{e}");
    let p = dir.path().join("none.png");
    let e = figure::map_panels(&p, &[], &MapStyle::default()).unwrap_err();
    assert!(e.to_string().contains("none.png"), "{e}");
    let e = figure::lines(&p, &LinePlot::default()).unwrap_err();
    assert!(e.to_string().contains("none.png"), "{e}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "nothing left behind"
    );
}
