//! SVE recordings: a scan at constant depth, identified continuously and binned into maps.
//!
//! Three streaming passes, memory bounded by the number of scan passes and map pixels:
//!
//! 1. **Survey.** The first contact (the core's detector, as in DIVE), the free deflection D₀,
//!    the release at the end (if any), the typical regressor size, and the scan: a *pass* is a
//!    run of samples in contact where x moves steadily in one direction (x over 1 ms changes,
//!    y does not, by more than a tenth of it) — the controller's forward and backward lines;
//!    its y is the line's. Lines are the distinct y of the passes (or `--lines` equal bins).
//! 2. **Estimation.** [`visco_core::observer::Observer`] replays every sample with the
//!    controller's decoupled regression (both sides of (16) high-passed, θ = [c, k], memory
//!    2 ms) from the contact on; ĥ = Z/Λ + F/k̂ with F = −K·G_lp·(D − D₀). Each sample of a pass
//!    (after 20 ms of convergence) goes to its pixel (`--pixels` equal bins over the scanned x)
//!    of its line and direction; forward and backward means are averaged per pixel, which
//!    cancels the estimator's lag as the paper's resampling does.
//! 3. **Fit.** The plant on an element bed built from the maps (per-element c, k and the
//!    surface height, bilinearly interpolated onto the lattice) is driven by the recorded U, X,
//!    Y; its D plus D₀ against the recorded D gives the misfit.
//!
//! The maps: aggregate c and k; the bed height ĥ (the k-weighted mean of hᵢ − sᵢ under the
//! tip); the apex depth δ (from the effective depth F/k̂ = δ − s̄(δ)); the surface height
//! ĥ + s̄(δ); per element c/n and k/n with n = π a(δ)²/pitch² (continuum: a pixel averages
//! over many lattice positions). The paper leaves SVE's spring constant uncorrected (shallow,
//! constant depth); k/n is the bed's tangent stiffness per element, since dV/dδ = A.

use std::path::Path;

use visco_core::geometry::mean_sag;
use visco_core::observer::{Observer, ObserverConfig};
use visco_core::Cantilever;

use super::error::{IdentifyError, Result};
use super::files::{push_num, Staged};
use super::replay::{self, FoundContact, FreeContact, PhiProbe, PhiTypical, Smoother};
use super::report as rep;
use super::signal::{apex_depth_from_effective, contact_area, Summary};
use super::{Options, Outputs};
use crate::output::csv as output_csv;
use crate::output::figure::{self, MapStyle, Quantity};
use crate::output::gsf::{self, NanPolicy};
use crate::output::map::{Grid, Map};
use crate::recording::{RecordingReader, Row};
use crate::report::nums;
use crate::sample::Sample;

/// Rows of the series CSV at most.
const SERIES_ROWS: u64 = 100_000;
/// Samples of a pass skipped after the estimation starts (10 memories of 2 ms).
const CONVERGE_S: f64 = 20e-3;
/// A pass shorter than this is a turn or a jitter, not a line (s).
const MIN_PASS_S: f64 = 5e-3;

/// One scan pass (a line in one direction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    /// First and end row.
    pub rows: (u64, u64),
    /// +1 forward (x increasing), −1 backward.
    pub dir: i8,
    /// Mean y (m).
    pub y_m: f64,
    /// x extent (m).
    pub x_range_m: (f64, f64),
    /// Line index assigned.
    pub line: usize,
}

/// What an SVE recording gives.
#[derive(Debug, Clone)]
pub struct SveResult {
    /// The mode-specific part of the report.
    pub json: rep::SveReport,
    /// RMS misfit over the whole recording (m).
    pub rms_misfit_m: f64,
    /// The contact that started the scan.
    pub contact: FoundContact,
    /// The passes found.
    pub passes: Vec<Pass>,
    /// Pixel centres along x (m).
    pub x_m: Vec<f64>,
    /// Line positions (m).
    pub y_m: Vec<f64>,
    /// The maps, row-major (line, pixel), NaN where empty: name, unit, values.
    pub maps: Vec<(String, String, Vec<f64>)>,
    /// The observer configuration.
    pub observer: ObserverConfig,
}

impl SveResult {
    /// One line for the terminal.
    pub fn summary(&self) -> String {
        let mean = |name: &str| {
            self.map(name).map_or(f64::NAN, |v| {
                let mut s = Summary::default();
                v.iter().for_each(|x| s.add(*x));
                s.mean()
            })
        };
        format!(
            "{} lines x {} pixels from {} passes: mean c = {:.4e} N*s/m, k = {:.4e} N/m, \
             depth {:.1} nm; misfit {:.3e} m",
            self.y_m.len(),
            self.x_m.len(),
            self.passes.len(),
            mean("c_ns_per_m"),
            mean("k_n_per_m"),
            mean("depth_m") * 1e9,
            self.rms_misfit_m
        )
    }

    /// A map by name.
    pub fn map(&self, name: &str) -> Option<&[f64]> {
        self.maps
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, _, v)| v.as_slice())
    }
}

struct Survey {
    rows: u64,
    fs: f64,
    contact: Option<FoundContact>,
    release: Option<u64>,
    phi: PhiTypical,
    passes: Vec<Pass>,
    u_span: f64,
}

fn survey(path: &Path, cant: &Cantilever) -> Result<Survey> {
    let mut reader = RecordingReader::open(path)?;
    let meta_fs = reader.header().meta.sample_rate_hz;
    let w = ((1e-3 * meta_fs).round() as usize).max(3);
    let converge = (CONVERGE_S * meta_fs).round() as u64;
    let min_pass = (MIN_PASS_S * meta_fs).round() as u64;
    let mut sd = Smoother::new(w);
    let mut probe = PhiProbe::new(cant, replay::lambda_s(cant), meta_fs);
    let mut phi = PhiTypical::default();
    let mut det = FreeContact::new(meta_fs);
    let mut contact: Option<FoundContact> = None;
    let (mut engaged, mut release) = (false, None);
    let mut dt = Summary::default();
    let (mut u_min, mut u_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut ring: Vec<(f64, f64)> = vec![(0.0, 0.0); w];
    let mut passes: Vec<Pass> = Vec::new();
    // The pass being built: (start, dir, y sum, n, x min, x max).
    let mut open: Option<(u64, i8, f64, u64, f64, f64)> = None;
    let mut row = Row::default();
    let mut i: u64 = 0;
    let mut t_prev = f64::NAN;
    let close =
        |open: &mut Option<(u64, i8, f64, u64, f64, f64)>, passes: &mut Vec<Pass>, end: u64| {
            if let Some((start, dir, ys, n, x0, x1)) = open.take() {
                if end - start >= min_pass {
                    passes.push(Pass {
                        rows: (start, end),
                        dir,
                        y_m: ys / n as f64,
                        x_range_m: (x0, x1),
                        line: 0,
                    });
                }
            }
        };
    while reader.read_row(&mut row)? {
        if i > 0 {
            dt.add(row.t_s - t_prev);
        }
        t_prev = row.t_s;
        u_min = u_min.min(row.u_m);
        u_max = u_max.max(row.u_m);
        let (x, y) = (row.x_m.unwrap_or(0.0), row.y_m.unwrap_or(0.0));
        if contact.is_none() {
            contact = det.step(i, row.u_m, row.d_m);
        }
        let (v, p) = probe.step(row.u_m, row.d_m);
        let in_contact = contact.is_some() && release.is_none();
        if in_contact {
            phi.add(v, p);
        }
        if let (Some((j, ds)), Some(c)) = (sd.push(i, row.d_m), contact) {
            if j >= c.row && release.is_none() {
                let rel = ds - c.d0_m;
                if rel < -c.gamma_plus_m {
                    engaged = true;
                } else if engaged && rel > -c.gamma_m {
                    release = Some(j);
                }
            }
        }
        // Scanning: x moved over the last window, y (nearly) did not.
        let slot = (i % w as u64) as usize;
        let (xw, yw) = ring[slot];
        ring[slot] = (x, y);
        let scanning =
            i >= w as u64 && in_contact && contact.is_some_and(|c| i >= c.row + converge);
        let dx = x - xw;
        let dy = y - yw;
        let dir: i8 = if dx > 0.0 { 1 } else { -1 };
        if scanning && dx != 0.0 && dy.abs() <= 0.1 * dx.abs() {
            match &mut open {
                Some(o) if o.1 == dir => {
                    o.2 += y;
                    o.3 += 1;
                    o.4 = o.4.min(x);
                    o.5 = o.5.max(x);
                }
                _ => {
                    close(&mut open, &mut passes, i);
                    open = Some((i, dir, y, 1, x, x));
                }
            }
        } else {
            close(&mut open, &mut passes, i);
        }
        i += 1;
    }
    close(&mut open, &mut passes, i);
    let fs = replay::check_rate(path, meta_fs, &dt)?;
    Ok(Survey {
        rows: i,
        fs,
        contact,
        release,
        phi,
        passes,
        u_span: u_max - u_min,
    })
}

/// Distinct values within `tol` of each other, merged (sorted).
fn cluster(mut v: Vec<f64>, tol: f64) -> Vec<f64> {
    v.sort_by(|a, b| a.total_cmp(b));
    let mut out: Vec<(f64, usize)> = Vec::new();
    for x in v {
        match out.last_mut() {
            Some((m, n)) if (x - *m / *n as f64).abs() <= tol => {
                *m += x;
                *n += 1;
            }
            _ => out.push((x, 1)),
        }
    }
    out.into_iter().map(|(m, n)| m / n as f64).collect()
}

/// Identifies an SVE recording (three passes) and stages the maps and the fit.
pub(crate) fn identify(
    path: &Path,
    opts: &Options,
    out: &Outputs,
    staged: &mut Staged,
) -> Result<SveResult> {
    let header = RecordingReader::open(path)?.header().clone();
    let meta = &header.meta;
    let (cant, cant_source) = replay::cantilever(meta, path)?;
    if cant.f0_hz() >= 0.25 * meta.sample_rate_hz {
        return Err(IdentifyError::new(
            path,
            format!(
                "the cantilever's resonance ({:.0} Hz) is not below a quarter of the sampling \
                 rate ({} Hz): the dynamic model cannot be replayed at this rate",
                cant.f0_hz(),
                meta.sample_rate_hz
            ),
        ));
    }
    let r = meta.tip_radius_m;
    let sv = survey(path, &cant)?;
    let fs = sv.fs;
    let Some(contact) = sv.contact else {
        return Err(IdentifyError::new(
            path,
            format!(
                "no contact in the sve recording: over {} rows the deflection never passes the \
                 contact threshold",
                sv.rows
            ),
        )
        .with_fix("an SVE scan runs in contact: check the recording's sign of D (D < 0 when the sample pushes the tip up)"));
    };
    if sv.passes.is_empty() {
        return Err(IdentifyError::new(
            path,
            "no scan line in the sve recording: in contact, x never moves steadily in one \
             direction for 5 ms",
        )
        .with_fix("an SVE recording scans x along lines (x_m, y_m columns)"));
    }

    // The grid.
    let mut passes = sv.passes.clone();
    let x_lo = passes
        .iter()
        .map(|p| p.x_range_m.0)
        .fold(f64::INFINITY, f64::min);
    let x_hi = passes
        .iter()
        .map(|p| p.x_range_m.1)
        .fold(f64::NEG_INFINITY, f64::max);
    let nx = opts.pixels;
    let dx = (x_hi - x_lo) / nx as f64;
    let x_centres: Vec<f64> = (0..nx).map(|i| x_lo + (i as f64 + 0.5) * dx).collect();
    let ys: Vec<f64> = passes.iter().map(|p| p.y_m).collect();
    let (y_lo, y_hi) = ys
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
            (a.min(y), b.max(y))
        });
    let y_lines: Vec<f64> = match opts.lines {
        Some(n) if n > 1 => (0..n)
            .map(|j| y_lo + (y_hi - y_lo) * j as f64 / (n - 1) as f64)
            .collect(),
        Some(_) => vec![0.5 * (y_lo + y_hi)],
        None => cluster(ys, (1e-3 * (y_hi - y_lo)).max(0.5e-9)),
    };
    for p in passes.iter_mut() {
        p.line = y_lines
            .iter()
            .enumerate()
            .fold((0, f64::INFINITY), |best, (j, &y)| {
                let d = (y - p.y_m).abs();
                if d < best.1 {
                    (j, d)
                } else {
                    best
                }
            })
            .0;
    }
    let ny = y_lines.len();

    // Pass 2: the observer, binned.
    let phi = sv.phi.rms([0.05, 2.0]);
    let ocfg = replay::observer_config(fs, &cant, r, opts.regressor, phi, phi, sv.u_span + 2e-6);
    let mut obs = Observer::<f64>::new(&ocfg)
        .map_err(|e| IdentifyError::new(path, format!("cannot replay: {e}")))?;
    obs.set_deflection_offset(contact.d0_m);
    obs.set_contact_thresholds(contact.gamma_m, contact.gamma_plus_m);
    const Q: usize = 5; // c, k, bed, depth, count
    let mut bins = vec![[0.0f64; Q]; ny * nx * 2];
    let nominal = replay::nominal_contact(r);
    {
        let mut reader = RecordingReader::open(path)?;
        let mut row = Row::default();
        let mut i: u64 = 0;
        let mut k = 0usize;
        while reader.read_row(&mut row)? {
            if i == 0 {
                obs.reset(row.u_m, row.d_m);
            }
            let o = obs.step(row.u_m, row.d_m);
            if i == contact.row {
                obs.start_sve(
                    Some(contact.h_m),
                    0.0,
                    [nominal.c_ns_per_m, nominal.k_n_per_m],
                );
            }
            while k < passes.len() && i >= passes[k].rows.1 {
                k += 1;
            }
            if k < passes.len() && i >= passes[k].rows.0 {
                let p = &passes[k];
                let x = row.x_m.unwrap_or(0.0);
                let ix = (((x - x_lo) / dx).floor().max(0.0) as usize).min(nx - 1);
                let b = &mut bins[(p.line * nx + ix) * 2 + usize::from(p.dir < 0)];
                b[0] += o.c_ns_per_m;
                b[1] += o.k_n_per_m;
                b[2] += o.bed_height_m;
                b[3] += o.depth_m;
                b[4] += 1.0;
            }
            i += 1;
        }
    }
    // Forward and backward means, averaged.
    let mut agg = vec![[f64::NAN; 4]; ny * nx];
    for (cell, a) in agg.iter_mut().enumerate() {
        let (f, b) = (&bins[cell * 2], &bins[cell * 2 + 1]);
        for q in 0..4 {
            let mut s = Summary::default();
            for d in [f, b] {
                if d[4] > 0.0 {
                    s.add(d[q] / d[4]);
                }
            }
            a[q] = s.mean();
        }
    }
    let p2 = opts.element_pitch_m * opts.element_pitch_m;
    let mut maps: Vec<(String, String, Vec<f64>)> = Vec::new();
    let col = |q: usize| agg.iter().map(|a| a[q]).collect::<Vec<f64>>();
    let depth_apex: Vec<f64> = agg
        .iter()
        .map(|a| apex_depth_from_effective(r, a[3]))
        .collect();
    let n_el: Vec<f64> = depth_apex
        .iter()
        .map(|&d| contact_area(r, d) / p2)
        .collect();
    let surface: Vec<f64> = agg
        .iter()
        .zip(&depth_apex)
        .map(|(a, &d)| a[2] + mean_sag(r, d))
        .collect();
    maps.push(("c_ns_per_m".into(), "N·s/m (aggregate)".into(), col(0)));
    maps.push(("k_n_per_m".into(), "N/m (aggregate)".into(), col(1)));
    maps.push((
        "height_m".into(),
        "m (surface: bed height + mean sag)".into(),
        surface,
    ));
    maps.push(("bed_height_m".into(), "m (ĥ = Z/Λ + F/k̂)".into(), col(2)));
    maps.push(("depth_m".into(), "m (apex depth)".into(), depth_apex));
    maps.push((
        "c_element_ns_per_m".into(),
        "N·s/m per element (c/n)".into(),
        agg.iter().zip(&n_el).map(|(a, n)| a[0] / n).collect(),
    ));
    maps.push((
        "k_element_n_per_m".into(),
        "N/m per element (k/n)".into(),
        agg.iter().zip(&n_el).map(|(a, n)| a[1] / n).collect(),
    ));
    // The maps through the output layer: CSV grid, Gwyddion file and figure per quantity.
    let grid = map_grid(&x_centres, &y_lines, dx);
    let regular = lines_regular(&y_lines);
    let mut map_json = crate::report::Ordered::default();
    let title = path
        .file_name()
        .map_or(String::new(), |n| n.to_string_lossy().into_owned());
    for (name, unit, v) in &maps {
        let stem = name
            .trim_end_matches("_ns_per_m")
            .trim_end_matches("_n_per_m")
            .trim_end_matches("_m");
        let si = unit.split(' ').next().unwrap_or("").to_string();
        let map = Map::from_vec(grid, name.as_str(), si.as_str(), v.clone());
        let csv_path = out.path(&format!("{stem}.csv"));
        staged.write(&csv_path, &output_csv::csv_string(&map))?;
        let gsf_path = out.path(&format!("{stem}.gsf"));
        staged.write_bytes(&gsf_path, &gsf::gsf_bytes(&map, NanPolicy::FillMean))?;
        let png_path = out.path(&format!("{stem}.png"));
        let (what, symbol) = describe(name);
        let style = MapStyle {
            title: Some(super::figures::plain(&format!(
                "{title}: SVE, {what} (forward and backward averaged)"
            ))),
            quantity: Some(Quantity::new(symbol, si.as_str())),
            letters: false,
            ..Default::default()
        };
        staged.render(&png_path, |tmp| {
            figure::map_panels(tmp, &[(&map, "")], &style)
        })?;
        let st = map.stats();
        let mut sm = Summary::default();
        v.iter().for_each(|x| sm.add(*x));
        map_json.0.push((
            name.clone(),
            rep::MapJson {
                file: csv_path.display().to_string(),
                gsf: gsf_path.display().to_string(),
                png: png_path.display().to_string(),
                unit: unit.clone(),
                valid_pixels: st.count as u64,
                mean: st.mean.into(),
                std: sm.std().into(),
                min: st.min.into(),
                max: st.max.into(),
            },
        ));
    }
    let empty = agg.iter().filter(|a| !a[1].is_finite()).count();

    // Pass 3: the fit on a bed built from the maps.
    let sample = bed_from_maps(
        &x_centres,
        &y_lines,
        &maps,
        opts,
        r,
        (x_lo, x_hi, y_lo, y_hi),
    )?;
    let mut plant = replay::fit_plant(&cant, r, fs, sample)?;
    let stride = sv.rows.div_ceil(SERIES_ROWS).max(1);
    let mut series = staged.create(&out.path("fit.csv"))?;
    series.write_str(&format!(
        "# visco identify: sve fit, recorded vs simulated deflection, every {stride} row(s)\n\
         t_s,u_m,d_recorded_m,d_simulated_m,residual_m,x_m,y_m\n"
    ))?;
    let mut detail = staged.create(&out.path("fit_detail.csv"))?;
    detail.write_str(
        "# visco identify: sve fit over 20 ms in the middle of the first line, every row\n\
         t_s,u_m,d_recorded_m,d_simulated_m,residual_m,x_m,y_m\n",
    )?;
    let first = passes[0].rows;
    let mid = (first.0 + first.1) / 2;
    let span = ((10e-3 * fs) as u64).min((first.1 - first.0) / 2);
    let detail_rows = mid.saturating_sub(span)..mid + span;
    let (mut total, mut scan) = (Summary::default(), Summary::default());
    let mut env = super::figures::Envelope::new(sv.rows);
    let mut detail_pts: Vec<(f64, f64, f64)> = Vec::new();
    {
        let mut reader = RecordingReader::open(path)?;
        let mut row = Row::default();
        let mut i: u64 = 0;
        let mut k = 0usize;
        let (mut buf, mut dbuf, mut line) = (String::new(), String::new(), String::new());
        while reader.read_row(&mut row)? {
            let (x, y) = (row.x_m.unwrap_or(0.0), row.y_m.unwrap_or(0.0));
            if i == 0 {
                plant.settle(row.u_m, x, y);
            }
            let sim = plant.step(row.u_m, x, y) + contact.d0_m;
            let resid = row.d_m - sim;
            total.add(resid);
            env.push(row.t_s, row.d_m, sim);
            while k < passes.len() && i >= passes[k].rows.1 {
                k += 1;
            }
            if k < passes.len() && i >= passes[k].rows.0 {
                scan.add(resid);
            }
            let in_detail = detail_rows.contains(&i);
            if in_detail {
                detail_pts.push((row.t_s, row.d_m, sim));
            }
            if i % stride == 0 || in_detail {
                line.clear();
                for v in [row.t_s, row.u_m, row.d_m, sim, resid, x] {
                    push_num(&mut line, v);
                    line.push(',');
                }
                push_num(&mut line, y);
                line.push('\n');
                if i % stride == 0 {
                    buf.push_str(&line);
                }
                if in_detail {
                    dbuf.push_str(&line);
                }
                if buf.len() > 1 << 16 {
                    series.write_str(&buf)?;
                    buf.clear();
                }
                if dbuf.len() > 1 << 16 {
                    detail.write_str(&dbuf)?;
                    dbuf.clear();
                }
            }
            i += 1;
        }
        series.write_str(&buf)?;
        detail.write_str(&dbuf)?;
    }
    let series_path = series.path().to_path_buf();
    let detail_path = detail.path().to_path_buf();
    staged.finish(series)?;
    staged.finish(detail)?;
    let png = out.path("fit.png");
    super::figures::stage_overview(
        staged,
        &png,
        &format!("{title}: SVE, the plant on the identified bed"),
        &env,
    )?;
    let detail_png = out.path("fit_detail.png");
    super::figures::stage_detail(
        staged,
        &detail_png,
        &format!("{title}: 20 ms of the first line, every sample"),
        &detail_pts,
    )?;

    let t0 = 0.0;
    let forward = passes.iter().filter(|p| p.dir > 0).count();
    let j = rep::SveReport {
        model: "cantilever first mode (2) on an aggregate Kelvin–Voigt contact (10), identified \
                continuously with the decoupled SVE regression"
            .into(),
        cantilever: rep::CantileverJson::new(meta).used_from(cant_source),
        tip_radius_m: r,
        sample_rate_hz: fs,
        regressor: "decoupled (16): w and φ = [−sZ/Λ, −Z/Λ] high-passed at f0/32, θ = [c, k]; \
                    ĥ = Z/Λ + F/k̂"
            .into(),
        contact: rep::SveContact {
            row: contact.row + 1,
            t_s: t0 + contact.row as f64 / fs,
            height_m: contact.h_m.into(),
            free_deflection_m: contact.d0_m.into(),
            released_row: sv.release.map(|r| r + 1),
        },
        scan: rep::Scan {
            passes: passes.len() as u64,
            forward: forward as u64,
            backward: (passes.len() - forward) as u64,
            x_range_m: [x_lo.into(), x_hi.into()],
            y_range_m: [y_lo.into(), y_hi.into()],
            lines_from: if opts.lines.is_some() {
                "--lines (equal bins)"
            } else {
                "the distinct y of the passes"
            }
            .into(),
        },
        grid: rep::Grid {
            pixels: nx as u64,
            lines: ny as u64,
            x_m: nums(x_centres.iter().copied()),
            y_m: nums(y_lines.iter().copied()),
            empty_pixels: empty as u64,
            lines_equally_spaced: regular,
            layout: if regular {
                "the output layer's map CSV (bottom row first) and Gwyddion .gsf; nan \
                 where no sample fell"
            } else {
                "the output layer's map CSV and .gsf with one row per line in order; \
                 the lines are not equally spaced, their y are grid.y_m"
            }
            .into(),
        },
        per_element: rep::SvePerElement {
            element_pitch_m: opts.element_pitch_m,
            count: "continuum n = π a(δ)²/pitch² at the pixel's apex depth".into(),
            spring: "k/n (the bed's tangent stiffness per element; SVE needs no (32))".into(),
        },
        replay: rep::SveReplay {
            observer: replay::observer_json(&ocfg, replay::SVE_MEMORY_S, &ocfg.sve_estimator),
            sve_highpass_hz: ocfg.sve_highpass_hz,
            converge_s: CONVERGE_S,
        },
        maps: map_json,
        notes: {
            let mut notes: Vec<String> = vec![
                "per-element values and the surface height use the continuum count and mean \
                 sag at the apex depth; a coarse lattice between its rows differs by a few % \
                 and a few nm"
                    .to_string(),
            ];
            if !regular {
                notes.push("the scan lines are not equally spaced (see grid.y_m)".into());
            }
            if empty > 0 {
                notes.push(format!("{empty} pixel(s) without samples (nan)"));
            }
            notes
        },
        taps: Vec::new(),
        rms_misfit_m: total.rms().into(),
        fit: rep::SveFit {
            model: "the plant (cantilever, sphere, element bed) on a bed built from the maps \
                    (per-element c, k and the surface height, bilinear onto the lattice), \
                    driven by the recorded U, X, Y, plus the free deflection; noise and \
                    converters off"
                .into(),
            rms_misfit_m: total.rms().into(),
            rms_misfit_scan_m: scan.rms().into(),
            series_csv: series_path.display().to_string(),
            series_stride_rows: stride,
            detail_csv: detail_path.display().to_string(),
            figure_png: png.display().to_string(),
            detail_png: detail_png.display().to_string(),
        },
    };
    Ok(SveResult {
        json: j,
        rms_misfit_m: total.rms(),
        contact,
        passes,
        x_m: x_centres,
        y_m: y_lines,
        maps,
        observer: ocfg,
    })
}

/// An element bed on the lattice from the maps: surface height, per-element c and k,
/// bilinear between pixel centres and lines, constant beyond the edges, empty pixels filled
/// from the nearest filled one.
fn bed_from_maps(
    xc: &[f64],
    yc: &[f64],
    maps: &[(String, String, Vec<f64>)],
    opts: &Options,
    r: f64,
    extent: (f64, f64, f64, f64),
) -> Result<Sample> {
    let get = |name: &str| -> Vec<f64> {
        maps.iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, _, v)| v.clone())
            .unwrap_or_default()
    };
    let (nx, ny) = (xc.len(), yc.len());
    let fill = |mut v: Vec<f64>| -> Vec<f64> {
        let valid: Vec<usize> = (0..v.len()).filter(|&i| v[i].is_finite()).collect();
        if valid.is_empty() {
            return v;
        }
        for i in 0..v.len() {
            if !v[i].is_finite() {
                let (ix, iy) = (i % nx, i / nx);
                let near = valid
                    .iter()
                    .min_by_key(|&&j| {
                        let (jx, jy) = (j % nx, j / nx);
                        ix.abs_diff(jx).pow(2) + iy.abs_diff(jy).pow(2)
                    })
                    .copied()
                    .unwrap_or(0);
                v[i] = v[near];
            }
        }
        v
    };
    let h = fill(get("height_m"));
    let c = fill(get("c_element_ns_per_m"));
    let k = fill(get("k_element_n_per_m"));
    let interp = |v: &[f64], x: f64, y: f64| -> f64 {
        let pos = |c: &[f64], x: f64| -> (usize, usize, f64) {
            if c.len() == 1 || x <= c[0] {
                return (0, 0, 0.0);
            }
            if x >= c[c.len() - 1] {
                return (c.len() - 1, c.len() - 1, 0.0);
            }
            let i = c.partition_point(|&ci| ci <= x).max(1) - 1;
            (i, i + 1, (x - c[i]) / (c[i + 1] - c[i]))
        };
        let (i0, i1, fx) = pos(xc, x);
        let (j0, j1, fy) = pos(yc, y);
        let at = |i: usize, j: usize| v[j * nx + i];
        (1.0 - fy) * ((1.0 - fx) * at(i0, j0) + fx * at(i1, j0))
            + fy * ((1.0 - fx) * at(i0, j1) + fx * at(i1, j1))
    };
    let p = opts.element_pitch_m;
    let origin = opts.lattice_origin_m.unwrap_or([p / 2.0, p / 2.0]);
    let margin = r + 2.0 * p;
    let (x_lo, x_hi, y_lo, y_hi) = extent;
    let i0 = ((x_lo - margin - origin[0]) / p).floor();
    let j0 = ((y_lo - margin - origin[1]) / p).floor();
    let ex = ((x_hi - x_lo + 2.0 * margin) / p).ceil() as usize + 2;
    let ey = ((y_hi - y_lo + 2.0 * margin) / p).ceil() as usize + 2;
    if ex.saturating_mul(ey) > 4_000_000 {
        return Err(IdentifyError::new(
            Path::new("(nominal sample)"),
            format!("the fit's element bed would have {ex} × {ey} elements"),
        )
        .with_fix("pass a larger --element-pitch"));
    }
    let _ = ny;
    let org = [origin[0] + i0 * p, origin[1] + j0 * p];
    Sample::from_fn(ex, ey, p, org, |x, y| {
        (
            interp(&h, x, y),
            interp(&c, x, y).max(0.0),
            interp(&k, x, y).max(0.0),
        )
    })
    .map_err(|e| IdentifyError::new(Path::new("(nominal sample)"), e.to_string()))
}

/// The maps' grid: pixel centres along x, and the lines along y (a regular spacing from the
/// first to the last line; one line gets square pixels).
fn map_grid(xc: &[f64], yl: &[f64], dx: f64) -> Grid {
    let ny = yl.len();
    let dy = if ny > 1 {
        ((yl[ny - 1] - yl[0]) / (ny - 1) as f64).max(dx * 1e-6)
    } else {
        dx
    };
    Grid::covering(xc.len(), ny, xc[0], yl[0], dx, dy)
}

/// Whether the lines sit within 5 % of a regular spacing.
fn lines_regular(yl: &[f64]) -> bool {
    let ny = yl.len();
    if ny < 3 {
        return true;
    }
    let dy = (yl[ny - 1] - yl[0]) / (ny - 1) as f64;
    yl.iter()
        .enumerate()
        .all(|(j, &y)| (y - (yl[0] + j as f64 * dy)).abs() <= 0.05 * dy.abs())
}

/// A map's description and symbol for its figure.
fn describe(name: &str) -> (&'static str, &'static str) {
    match name {
        "c_ns_per_m" => ("damping, aggregate", "c"),
        "k_n_per_m" => ("spring constant, aggregate", "k"),
        "height_m" => ("surface height", "h"),
        "bed_height_m" => ("bed height under the tip", "ĥ"),
        "depth_m" => ("apex depth", "δ"),
        "c_element_ns_per_m" => ("damping per element", "c/n"),
        "k_element_n_per_m" => ("spring constant per element", "k/n"),
        _ => ("map", "v"),
    }
}
