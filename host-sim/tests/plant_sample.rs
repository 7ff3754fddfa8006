//! Samples: the embedded phantom, file formats (round trips and errors), geometry helpers.

use std::fs;
use std::path::PathBuf;
use visco::sample::{GridSpec, Sample, SampleError};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("visco_plant_sample_{name}_{}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn phantom_is_in_the_papers_ranges() {
    let s = Sample::cell_phantom();
    assert_eq!((s.nx(), s.ny()), (50, 50));
    assert_eq!(s.pitch_m(), 100e-9);
    assert_eq!(s.origin_m(), [50e-9, 50e-9]);
    assert_eq!(s.extent_m(), [0.0, 5e-6, 0.0, 5e-6]);
    let minmax = |v: &[f64]| {
        v.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            })
    };
    let (hmin, hmax) = minmax(s.h_m());
    let (cmin, cmax) = minmax(s.c_n_s_per_m());
    let (kmin, kmax) = minmax(s.k_n_per_m());
    println!(
        "h {:.1}..{:.1} nm, c {:.2}..{:.2} e-7 N·s/m, k {:.2}..{:.2} e-3 N/m",
        hmin * 1e9,
        hmax * 1e9,
        cmin * 1e7,
        cmax * 1e7,
        kmin * 1e3,
        kmax * 1e3
    );
    assert!(
        (hmax - 0.3e-6).abs() < 1e-15,
        "the highest element is 0.3 µm"
    );
    assert!((0.0..10e-9).contains(&hmin), "substrate near 0");
    // The paper's ranges, and most of each used.
    assert!(cmin >= 4e-7 && cmax <= 8e-7 && cmax - cmin > 3e-7);
    assert!(kmin >= 2e-3 && kmax <= 5e-3 && kmax - kmin > 2.2e-3);
    // Steep edges: somewhere neighbours differ by more than half a pitch in height.
    let slope = s.slope_map();
    let steep = slope.iter().filter(|v| **v > 0.5).count();
    println!(
        "max slope {:.2}, {steep} elements steeper than 0.5",
        slope.iter().cloned().fold(0.0, f64::max)
    );
    assert!(steep > 10);
    // Deterministic.
    assert_eq!(s, Sample::cell_phantom());
    // Features: the nucleus region is high and viscous; the corner is bare substrate.
    let nucleus = s.footprint_mean(2.75e-6, 2.7e-6, 300e-9).unwrap();
    let corner = s.footprint_mean(0.2e-6, 0.2e-6, 300e-9).unwrap();
    assert!(nucleus.h_m > 0.25e-6 && nucleus.c_n_s_per_m > 6.5e-7);
    assert!(corner.h_m < 10e-9 && corner.k_n_per_m > 4.5e-3);
}

#[test]
fn element_csv_round_trip() {
    let d = tmpdir("csv");
    let s = Sample::cell_phantom();
    let p = d.join("cell.csv");
    s.save_element_csv(&p).unwrap();
    let back = Sample::load(&p).unwrap();
    assert_eq!((back.nx(), back.ny()), (50, 50));
    assert!((back.pitch_m() - s.pitch_m()).abs() < 1e-21);
    for (a, b) in [
        (s.h_m(), back.h_m()),
        (s.c_n_s_per_m(), back.c_n_s_per_m()),
        (s.k_n_per_m(), back.k_n_per_m()),
    ] {
        assert_eq!(a, b, "values are written exactly");
    }
    // Row order does not matter.
    let text = fs::read_to_string(&p).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    let header = lines.drain(..2).collect::<Vec<_>>();
    lines.reverse();
    let shuffled = d.join("shuffled.csv");
    fs::write(
        &shuffled,
        format!("{}\n{}\n", header.join("\n"), lines.join("\n")),
    )
    .unwrap();
    assert_eq!(Sample::load(&shuffled).unwrap().h_m(), s.h_m());
}

#[test]
fn png_manifest_round_trip() {
    let d = tmpdir("png");
    let s = Sample::cell_phantom();
    let manifest = s.save_grids(&d, "cell").unwrap();
    let back = Sample::load(&manifest).unwrap();
    assert_eq!(
        (back.nx(), back.ny(), back.pitch_m(), back.origin_m()),
        (50, 50, s.pitch_m(), s.origin_m())
    );
    for (a, b) in [
        (s.h_m(), back.h_m()),
        (s.c_n_s_per_m(), back.c_n_s_per_m()),
        (s.k_n_per_m(), back.k_n_per_m()),
    ] {
        let range = a.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - a.iter().cloned().fold(f64::INFINITY, f64::min);
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 0.5 * range / 65535.0 * (1.0 + 1e-9));
        }
    }
}

#[test]
fn csv_grids_with_manifest() {
    let d = tmpdir("grids");
    // 3 columns (x) × 2 rows (y); row r of the file is y index j = r.
    fs::write(
        d.join("h.csv"),
        "# heights in m\n0,1e-8,2e-8\n3e-8,4e-8,5e-8\n",
    )
    .unwrap();
    fs::write(d.join("c.csv"), "5e-7,5e-7,5e-7\n6e-7,6e-7,6e-7\n").unwrap();
    fs::write(d.join("k.csv"), "3e-3,3e-3,3e-3\n\n4e-3,4e-3,4e-3\n").unwrap();
    fs::write(
        d.join("s.sample"),
        "pitch_m = 200e-9\norigin_x_m = 0\norigin_y_m = 1e-6  # offset\nh = h.csv\nc = c.csv\nk = k.csv\n",
    )
    .unwrap();
    let s = Sample::load(d.join("s.sample")).unwrap();
    assert_eq!((s.nx(), s.ny()), (3, 2));
    assert_eq!(s.element_xy_m(2, 1), [400e-9, 1.2e-6]);
    assert_eq!(s.h_m()[s.index(2, 1)], 5e-8);
    assert_eq!(s.k_n_per_m()[s.index(0, 1)], 4e-3);
    // The same through GridSpec (e.g. from command-line flags), default origin = pitch/2.
    let spec = GridSpec {
        pitch_m: 100e-9,
        origin_m: None,
        h_range_m: None,
        c_range_n_s_per_m: None,
        k_range_n_per_m: None,
    };
    let s2 =
        Sample::from_grid_files(d.join("h.csv"), d.join("c.csv"), d.join("k.csv"), &spec).unwrap();
    assert_eq!(s2.origin_m(), [50e-9, 50e-9]);
}

fn err_text(e: SampleError) -> String {
    e.to_string()
}

#[test]
fn file_errors_name_file_line_and_reason() {
    let d = tmpdir("errors");
    let w = |name: &str, text: &str| {
        let p = d.join(name);
        fs::write(&p, text).unwrap();
        p
    };
    let hdr = "x_m,y_m,h_m,c_n_s_per_m,k_n_per_m\n";
    let cases: Vec<(PathBuf, &str)> = vec![
        (
            w(
                "bad_number.csv",
                &format!("{hdr}0,0,1e-8,5e-7,3e-3\n1e-7,0,abc,5e-7,3e-3\n"),
            ),
            "bad_number.csv:3: column 3: 'abc' is not a number",
        ),
        (
            w("no_col.csv", "x_m,y_m,h_m,c_n_s_per_m\n0,0,0,0\n"),
            "no_col.csv:1: header lacks column 'k_n_per_m'",
        ),
        (
            w(
                "dup.csv",
                &format!("{hdr}0,0,1e-8,5e-7,3e-3\n1e-7,0,1e-8,5e-7,3e-3\n0,0,1e-8,5e-7,3e-3\n"),
            ),
            "dup.csv:4: element (0, 0) nm appears twice",
        ),
        (
            w("short.csv", &format!("{hdr}0,0,1e-8,5e-7\n")),
            "short.csv:2: 4 fields, the header has 5",
        ),
        (
            w(
                "missing.csv",
                &format!("{hdr}0,0,1e-8,5e-7,3e-3\n1e-7,0,1e-8,5e-7,3e-3\n0,1e-7,1e-8,5e-7,3e-3\n"),
            ),
            "element at (100, 100) nm is missing: 3 rows for a 2 × 2 lattice",
        ),
        (
            w(
                "neg.csv",
                &format!("{hdr}0,0,1e-8,5e-7,-3e-3\n1e-7,0,1e-8,5e-7,3e-3\n"),
            ),
            "neg.csv: k of element (i=0, j=0) is negative",
        ),
        (
            w("one.csv", &format!("{hdr}0,0,1e-8,5e-7,3e-3\n")),
            "a single element cannot define the lattice pitch",
        ),
        (
            w("m1.sample", "pitch_m = 1e-7\nfoo = 3\n"),
            "m1.sample:2: unknown key 'foo'",
        ),
        (
            w("m2.sample", "h = a.png\nc = a.png\nk = a.png\n"),
            "m2.sample: missing 'pitch_m'",
        ),
        (
            w(
                "m3.sample",
                "pitch_m = 1e-7\nh = nothere.csv\nc = nothere.csv\nk = nothere.csv\n",
            ),
            "nothere.csv",
        ),
        (
            w("m4.sample", "pitch_m = x\n"),
            "m4.sample:1: pitch_m: 'x' is not a finite number",
        ),
        (
            w("m5.sample", "pitch_m = 1e-7\nh_min = 0\n"),
            "give both h_min and h_max",
        ),
    ];
    for (path, want) in cases {
        let got = err_text(Sample::load(&path).unwrap_err());
        assert!(
            got.contains(want),
            "{}: got «{got}», want «{want}»",
            path.display()
        );
    }
    // Grid problems.
    fs::write(d.join("g1.csv"), "1,2\n3\n").unwrap();
    let e = Sample::from_grid_files(
        d.join("g1.csv"),
        d.join("g1.csv"),
        d.join("g1.csv"),
        &GridSpec {
            pitch_m: 1e-7,
            origin_m: None,
            h_range_m: None,
            c_range_n_s_per_m: None,
            k_range_n_per_m: None,
        },
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("g1.csv:2: 1 values, the first row has 2"),
        "{e}"
    );
    let s = Sample::cell_phantom();
    let manifest = s.save_grids(&d, "pic").unwrap();
    let e = Sample::from_grid_files(
        d.join("pic_h.png"),
        d.join("pic_c.png"),
        d.join("pic_k.png"),
        &GridSpec {
            pitch_m: 1e-7,
            origin_m: None,
            h_range_m: None,
            c_range_n_s_per_m: None,
            k_range_n_per_m: None,
        },
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("pic_h.png: a PNG grid needs the range of h"),
        "{e}"
    );
    fs::write(d.join("small.csv"), "1,2\n3,4\n").unwrap();
    let text = fs::read_to_string(&manifest)
        .unwrap()
        .replace("pic_k.png", "small.csv");
    fs::write(&manifest, text).unwrap();
    let e = Sample::load(&manifest).unwrap_err();
    assert!(
        e.to_string()
            .contains("small.csv: grid is 2 × 2, the height grid"),
        "{e}"
    );
    fs::write(d.join("notpng.png"), "hello").unwrap();
    let spec = GridSpec {
        pitch_m: 1e-7,
        origin_m: None,
        h_range_m: Some((0.0, 1.0)),
        c_range_n_s_per_m: Some((0.0, 1.0)),
        k_range_n_per_m: Some((0.0, 1.0)),
    };
    let e = Sample::from_grid_files(
        d.join("notpng.png"),
        d.join("notpng.png"),
        d.join("notpng.png"),
        &spec,
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("notpng.png: not a readable PNG"),
        "{e}"
    );
}

#[test]
fn geometry_helpers() {
    let s = Sample::flat(20, 20, 100e-9, [50e-9, 50e-9], 100e-9, 5e-7, 3e-3).unwrap();
    let (x, y) = (1050.37e-9, 1050.21e-9); // near element (10, 10), no element exactly on the rim
    let under = s.elements_under_tip(x, y, 300e-9);
    assert_eq!(under.len(), 27);
    assert!(under.iter().all(|e| e.r_m < 300e-9));
    let m = s.footprint_mean(x, y, 300e-9).unwrap();
    assert_eq!(m.n, 27);
    assert!((m.h_m - 100e-9).abs() < 1e-20 && (m.k_n_per_m - 3e-3).abs() < 1e-18);
    // On a flat bed the sphere first touches at the highest threshold: h − R + √(R² − r_min²).
    let rmin = under.iter().map(|e| e.r_m).fold(f64::INFINITY, f64::min);
    let z = s.first_contact_z_m(x, y, 300e-9).unwrap();
    assert!((z - (100e-9 - 300e-9 + (300e-9f64.powi(2) - rmin * rmin).sqrt())).abs() < 1e-18);
    // Off the lattice.
    assert!(s.footprint_mean(-1e-6, -1e-6, 300e-9).is_none());
    assert!(s.first_contact_z_m(-1e-6, 5e-6, 300e-9).is_none());
    // Partly off: only the elements that exist.
    assert!(s.elements_under_tip(0.0, 0.0, 300e-9).len() < 10);
    // Invalid samples.
    assert!(Sample::flat(0, 3, 1e-7, [0.0, 0.0], 0.0, 1.0, 1.0).is_err());
    assert!(Sample::flat(3, 3, -1e-7, [0.0, 0.0], 0.0, 1.0, 1.0).is_err());
    assert!(Sample::flat(3, 3, 1e-7, [0.0, 0.0], f64::NAN, 1.0, 1.0).is_err());
}
