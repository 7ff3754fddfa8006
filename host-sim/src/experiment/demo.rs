//! `visco demo`: the paper's simulation study (section 5) on the embedded cell phantom, with
//! the core in the loop — a DIVE image of 20 × 20 taps and an SVE image of 20 lines — and
//! everything a lab would look at: maps like Figs. 4–7 (PNG, Gwyddion `.gsf`, CSV), the
//! convergence along a cross-section (Fig. 8), the force–depth curve with its power-law fit
//! (Fig. 9), `report.json` and a summary table.
//!
//! Errors are in percent of each property's maximum (h_max = 0.3 µm, c_max = 8×10⁻⁷ N·s/m,
//! k_max = 5×10⁻³ N/m) as in Fig. 7, against the given values averaged over the tip's
//! footprint — the elements actually in contact while the estimate was averaged (see
//! [`super`]). The per-element estimates are given two ways: the paper's scaling by the number
//! of elements in contact n = |W| (which the simulation knows, as the paper's did), and the
//! instrument's, which estimates n from measured quantities only; `report.json` holds both.

use super::metrics::{self, ImageErrors, PAPER_MAX};
use super::{run_dive, run_sve, DiveOutcome, ExperimentError, Observer, Props, Setup, SveOutcome};
use crate::output::figure::{
    self, Colormap, LinePanel, LinePlot, MapStyle, Quantity, ScatterFit, Series,
};
use crate::output::gsf::{write_gsf, NanPolicy};
use crate::output::progress::Progress;
use crate::output::{csv as map_csv, Grid, Map, OutputError};
use crate::plant::Plant;
use crate::sample::Sample;
use schemars::JsonSchema;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
use visco_core::geometry::contact_radius;
use visco_core::{Controller, Phase, StepOut};

/// What `visco demo` runs.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// Output directory (created).
    pub out: PathBuf,
    /// Loop rate of the core (Hz).
    pub sample_rate_hz: f64,
    /// Noise seed.
    pub seed: u64,
    /// A user sample instead of the embedded phantom.
    pub sample: Option<PathBuf>,
    /// A reduced run (fewer taps and lines, shorter times) for tests and a quick look.
    pub reduced: bool,
    /// Draw a progress bar / progress lines.
    pub progress: bool,
}

/// Why the demo failed.
#[derive(Debug)]
pub enum DemoError {
    /// The experiment could not run.
    Experiment(ExperimentError),
    /// An output could not be written.
    Output(OutputError),
    /// The sample could not be loaded.
    Sample(crate::sample::SampleError),
}

impl std::fmt::Display for DemoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DemoError::Experiment(e) => write!(f, "{e}"),
            DemoError::Output(e) => write!(f, "{e}"),
            DemoError::Sample(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DemoError {}

impl From<ExperimentError> for DemoError {
    fn from(e: ExperimentError) -> Self {
        DemoError::Experiment(e)
    }
}
impl From<OutputError> for DemoError {
    fn from(e: OutputError) -> Self {
        DemoError::Output(e)
    }
}

/// Error figures of one property in percent of its maximum.
#[derive(Clone, Copy, Debug, Default, Serialize, JsonSchema)]
pub struct Hck {
    /// Topography.
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "Option<f64>")]
    pub h: f64,
    /// Damping.
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "Option<f64>")]
    pub c: f64,
    /// Spring constant.
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "Option<f64>")]
    pub k: f64,
}

/// The errors of one image under one scaling.
#[derive(Clone, Copy, Debug, Default, Serialize, JsonSchema)]
pub struct ErrorBlock {
    /// RMS over all pixels (% of max).
    pub rms_error_pct: Hck,
    /// Largest |error| over all pixels (% of max).
    pub max_error_pct: Hck,
    /// Largest |error| over the pixels whose footprint is not steep (% of max).
    pub max_error_not_steep_pct: Hck,
    /// Mean error (% of max).
    pub mean_error_pct: Hck,
}

impl From<ImageErrors> for ErrorBlock {
    fn from(e: ImageErrors) -> Self {
        let f = |g: fn(&metrics::ErrorStats) -> f64| Hck {
            h: g(&e.h),
            c: g(&e.c),
            k: g(&e.k),
        };
        ErrorBlock {
            rms_error_pct: f(|s| s.rms_pct),
            max_error_pct: f(|s| s.max_pct),
            max_error_not_steep_pct: f(|s| s.max_not_steep_pct),
            mean_error_pct: f(|s| s.mean_pct),
        }
    }
}

/// One mode's entry in `report.json`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct ModeReport {
    /// Pixels of the map (taps or pixels with both passes).
    pub pixels: usize,
    /// Imaging time (s): taps × tap time, or lines × line period.
    pub imaging_time_s: f64,
    /// Pixels per second of imaging time.
    pub pixels_per_s: f64,
    /// RMS error, instrument scaling (% of max).
    pub rms_error_pct: Hck,
    /// Largest error, instrument scaling (% of max).
    pub max_error_pct: Hck,
    /// Largest error away from steep topography (identified), instrument scaling (% of max).
    pub max_error_not_steep_pct: Hck,
    /// Mean error, instrument scaling (% of max).
    pub mean_error_pct: Hck,
    /// The same figures with the paper's scaling n = |W| — the paper's definition, which needs
    /// the simulator's contact count (an instrument does not have it).
    pub paper_scaling: ErrorBlock,
    /// Slope |∇ĥ| of the identified topography above which a footprint counts as steep.
    pub steep_slope: f64,
    /// Pixels whose footprint is steep (identified topography) or reaches over the border.
    pub steep_pixels: usize,
    /// Taps or pixels flagged (no contact, short dwell) and left out.
    pub failed_pixels: usize,
    /// Simulated time including approaches (s).
    pub simulated_s: f64,
    /// Exponent of the power law fitted to the spring force against depth (Fig. 9), DIVE only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub force_depth_exponent: Option<f64>,
    /// Prefactor of that law in nN and nm (the paper: 1.6e-3).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub force_depth_prefactor_nn_nm: Option<f64>,
    /// First and third quartile of the exponent over the taps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub force_depth_exponent_quartiles: Option<[f64; 2]>,
    /// Taps with a force–depth curve to fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub force_depth_taps: Option<usize>,
}

/// `report.json`'s `schema_version`.
pub const SCHEMA_VERSION: u32 = 1;

/// `report.json`.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct DemoReport {
    /// Version of this report's layout (1): raised when a field is removed or renamed or changes
    /// meaning or unit; adding a field keeps it.
    pub schema_version: u32,
    /// DIVE.
    pub dive: ModeReport,
    /// SVE.
    pub sve: ModeReport,
    /// Simulated seconds, both modes.
    pub simulated_s: f64,
    /// Wall-clock seconds of the simulations (outputs not included).
    pub wall_s: f64,
    /// Wall-clock seconds including writing the outputs.
    pub wall_total_s: f64,
    /// The core's loop rate (Hz).
    pub sample_rate_hz: f64,
    /// Noise seed.
    pub seed: u64,
    /// The sample ("embedded cell phantom" or the file).
    pub sample: String,
    /// How errors and scalings are defined.
    pub notes: Vec<String>,
}

/// (t, ĉ, k̂ (NaN outside a dwell), U min, U max over the block, tap index).
type TracePoint = (f64, f64, f64, f64, f64, u32);

/// Samples of the loop kept for Fig. 8 (DIVE: along the first row of taps, against time).
#[derive(Default)]
struct DiveTrace {
    row: u32,
    every: u32,
    count: u32,
    /// Samples while the row's taps run.
    points: Vec<TracePoint>,
    u_lo: f64,
    u_hi: f64,
    tap: u32,
    time: f64,
    dt: f64,
    /// Per tap, (depth below first contact, spring force) during its indentation, every
    /// `every_fd` samples.
    force_depth: Vec<Vec<(f64, f64)>>,
    every_fd: u32,
    count_fd: u32,
    nx: u32,
}

impl Observer for DiveTrace {
    fn sample(&mut self, ctrl: &Controller<f32>, out: &StepOut<f32>, plant: &Plant) {
        self.time += self.dt;
        // The tap index is counted from the records (see `record`).
        let iy = self.tap / self.nx.max(1);
        if iy == self.row {
            let u = out.u_m as f64;
            if self.count == 0 {
                self.u_lo = u;
                self.u_hi = u;
            }
            self.u_lo = self.u_lo.min(u);
            self.u_hi = self.u_hi.max(u);
            self.count += 1;
            if self.count >= self.every {
                self.count = 0;
                let (c, k) = if out.status & visco_core::status::ESTIMATING != 0 {
                    let (c, k, _) = ctrl.estimates();
                    (c as f64, k as f64)
                } else {
                    (f64::NAN, f64::NAN)
                };
                self.points
                    .push((self.time, c, k, self.u_lo, self.u_hi, self.tap));
            }
        }
        if ctrl.phase() == Phase::Indent {
            self.count_fd += 1;
            if self.count_fd >= self.every_fd {
                self.count_fd = 0;
                let t = self.tap as usize;
                if self.force_depth.len() <= t {
                    self.force_depth.resize(t + 1, Vec::new());
                }
                self.force_depth[t].push((plant.contact_depth_m(), plant.elastic_force_n()));
            }
        }
    }
    fn record(&mut self, _rec: &visco_core::Record<f32>, _plant: &Plant) {
        self.tap += 1;
    }
}

/// Samples kept for Fig. 8 (SVE: along the first line, forward pass, against x), as means
/// over blocks of `every` samples (the instantaneous ĥ swings with the excitation).
#[derive(Default)]
struct SveTrace {
    every: u32,
    count: u32,
    acc: [f64; 5],
    /// (x, ĉ, k̂, ĥ, U).
    points: Vec<(f64, f64, f64, f64, f64)>,
    done: bool,
}

impl Observer for SveTrace {
    fn sample(&mut self, ctrl: &Controller<f32>, out: &StepOut<f32>, _plant: &Plant) {
        if self.done {
            return;
        }
        match ctrl.phase() {
            Phase::Forward => {
                let (c, k, h) = ctrl.estimates();
                let v = [out.x_m as f64, c as f64, k as f64, h as f64, out.u_m as f64];
                for (a, x) in self.acc.iter_mut().zip(v) {
                    *a += x;
                }
                self.count += 1;
                if self.count >= self.every {
                    let n = self.count as f64;
                    let a = self.acc.map(|v| v / n);
                    self.points.push((a[0], a[1], a[2], a[3], a[4]));
                    self.count = 0;
                    self.acc = [0.0; 5];
                }
            }
            Phase::Backward if !self.points.is_empty() => self.done = true,
            _ => {}
        }
    }
}

fn hck(
    e: &metrics::ErrorStats,
    f: &metrics::ErrorStats,
    g: &metrics::ErrorStats,
    v: fn(&metrics::ErrorStats) -> f64,
) -> Hck {
    Hck {
        h: v(e),
        c: v(f),
        k: v(g),
    }
}

/// Run the demo: both experiments, all outputs. Returns the report (also written).
pub fn run(opts: &DemoOptions) -> Result<DemoReport, DemoError> {
    let wall0 = Instant::now();
    let (sample, sample_name) = match &opts.sample {
        Some(p) => (
            Sample::load(p).map_err(DemoError::Sample)?,
            p.display().to_string(),
        ),
        None => (Sample::cell_phantom(), "embedded cell phantom".to_string()),
    };
    let mut setup = Setup::paper(sample, opts.sample_rate_hz, opts.seed);
    if opts.reduced {
        reduce(&mut setup);
    }
    std::fs::create_dir_all(opts.out.join("maps"))
        .map_err(|e| DemoError::Output(OutputError::new(&opts.out, e.to_string())))?;
    let c = setup.config;
    let total_s = c.dive_imaging_s() + c.sve_imaging_s();

    // DIVE.
    let mut progress = opts
        .progress
        .then(|| Progress::new("DIVE", c.dive_imaging_s()));
    let mut dtrace = DiveTrace {
        row: 0,
        every: (c.sample_rate_hz * 50e-6).max(1.0) as u32,
        dt: 1.0 / c.sample_rate_hz,
        every_fd: (c.sample_rate_hz * 10e-6).max(1.0) as u32,
        nx: c.dive.nx,
        ..Default::default()
    };
    let t = Instant::now();
    let dive = run_dive(&setup, &mut dtrace, |s| {
        if let Some(p) = progress.as_mut() {
            p.update(s)
        }
    })?;
    if let Some(p) = progress.as_mut() {
        p.finish(dive.simulated_s)
    }
    let dive_wall = t.elapsed().as_secs_f64();

    // SVE.
    let mut progress = opts
        .progress
        .then(|| Progress::new("SVE", c.sve_imaging_s()));
    let mut strace = SveTrace {
        every: (c.sample_rate_hz * 1e-3).max(1.0) as u32,
        ..Default::default()
    };
    let t = Instant::now();
    let sve = run_sve(&setup, &mut strace, |s| {
        if let Some(p) = progress.as_mut() {
            p.update(s)
        }
    })?;
    if let Some(p) = progress.as_mut() {
        p.finish(sve.simulated_s)
    }
    let sve_wall = t.elapsed().as_secs_f64();

    // Errors.
    let r = c.tip_radius_m;
    let dive_steep = metrics::steep_slope(c.dive.indent_depth_m, r);
    let sve_steep = metrics::steep_slope(c.sve.depth_ref_m, contact_radius(r, c.sve.depth_ref_m));
    let ok_taps = || dive.taps.iter().filter(|t| !t.failed);
    let dive_paper = metrics::image_errors(
        ok_taps().map(|t| (&t.scaled.paper, &t.touched.reference, t.slope)),
        &PAPER_MAX,
        dive_steep,
    );
    let dive_instr = metrics::image_errors(
        ok_taps().map(|t| (&t.scaled.instrument, &t.touched.reference, t.slope)),
        &PAPER_MAX,
        dive_steep,
    );
    let sve_paper = metrics::image_errors(
        sve.pixels
            .iter()
            .map(|p| (&p.scaled.paper, &p.touched.reference, p.slope)),
        &PAPER_MAX,
        sve_steep,
    );
    let sve_instr = metrics::image_errors(
        sve.pixels
            .iter()
            .map(|p| (&p.scaled.instrument, &p.touched.reference, p.slope)),
        &PAPER_MAX,
        sve_steep,
    );

    // Fig. 9: spring force against depth up to 200 nm with a power law F = a·δ^b fitted by
    // least squares on F (as a curve-fitting tool fits a "power" model), started from the
    // log–log fit (which alone is dominated by the first nanometres, where a few elements give
    // a force near zero). Fitted at every tap; the image's exponent is the median over the
    // taps, and the figure shows the tap with that median exponent.
    let mut per_tap: Vec<(figure::PowerLaw, Vec<(f64, f64)>)> = Vec::new();
    for pts in &dtrace.force_depth {
        let q: Vec<(f64, f64)> = pts
            .iter()
            .copied()
            .filter(|(d, f)| *d > 0.0 && *d <= 200e-9 && *f > 0.0)
            .collect();
        if q.len() >= 20 {
            if let Some((law, _)) = figure::fit_power_law(&q) {
                per_tap.push((fit_power_law_least_squares(&q, law), q));
            }
        }
    }
    per_tap.sort_by(|a, b| a.0.b.total_cmp(&b.0.b));
    let quartile = |q: f64| {
        per_tap
            .get(((per_tap.len() as f64 - 1.0) * q).round() as usize)
            .map(|t| t.0.b)
    };
    let (fd, fit) = match per_tap.get(per_tap.len() / 2) {
        Some((law, q)) => (q.clone(), Some((*law, quartile(0.25), quartile(0.75)))),
        None => (Vec::new(), None),
    };

    let wall_s = dive_wall + sve_wall;
    let dive_imaging = c.dive_imaging_s();
    let sve_imaging = c.sve_imaging_s();
    let mode_report = |pixels: usize,
                       imaging: f64,
                       paper: &ImageErrors,
                       instr: &ImageErrors,
                       steep: f64,
                       failed: usize,
                       sim: f64| ModeReport {
        pixels,
        imaging_time_s: imaging,
        pixels_per_s: pixels as f64 / imaging,
        rms_error_pct: hck(&instr.h, &instr.c, &instr.k, |s| s.rms_pct),
        max_error_pct: hck(&instr.h, &instr.c, &instr.k, |s| s.max_pct),
        max_error_not_steep_pct: hck(&instr.h, &instr.c, &instr.k, |s| s.max_not_steep_pct),
        mean_error_pct: hck(&instr.h, &instr.c, &instr.k, |s| s.mean_pct),
        paper_scaling: ErrorBlock::from(*paper),
        steep_slope: steep,
        steep_pixels: instr.h.steep,
        failed_pixels: failed,
        simulated_s: sim,
        force_depth_exponent: None,
        force_depth_prefactor_nn_nm: None,
        force_depth_exponent_quartiles: None,
        force_depth_taps: None,
    };
    let mut dive_report = mode_report(
        dive.taps.len(),
        dive_imaging,
        &dive_paper,
        &dive_instr,
        dive_steep,
        dive.taps.iter().filter(|t| t.failed).count(),
        dive.simulated_s,
    );
    if let Some((law, q1, q3)) = fit {
        dive_report.force_depth_exponent = Some(law.b);
        dive_report.force_depth_exponent_quartiles = q1.zip(q3).map(|(a, b)| [a, b]);
        dive_report.force_depth_taps = Some(per_tap.len());
        // F = a·δ^b in SI; in nN and nm: F_nN = a·1e9·(δ_nm·1e-9)^b.
        dive_report.force_depth_prefactor_nn_nm = Some(law.a * 1e9 * 1e-9f64.powf(law.b));
    }
    let sve_report = mode_report(
        sve.pixels.len(),
        sve_imaging,
        &sve_paper,
        &sve_instr,
        sve_steep,
        setup.config.sve.pixels as usize * setup.config.sve.lines as usize - sve.pixels.len(),
        sve.simulated_s,
    );

    let mut report = DemoReport {
        schema_version: SCHEMA_VERSION,
        dive: dive_report,
        sve: sve_report,
        simulated_s: dive.simulated_s + sve.simulated_s,
        wall_s,
        wall_total_s: 0.0,
        sample_rate_hz: c.sample_rate_hz,
        seed: opts.seed,
        sample: sample_name,
        notes: vec![
            "errors in percent of h_max = 0.3 µm, c_max = 8e-7 N·s/m, k_max = 5e-3 N/m (the paper's Fig. 7)".into(),
            "reference: the given h, c, k averaged over the elements in contact (the active set W), each weighted by its time in contact while the estimate was averaged (DIVE read-out window, SVE pixel pass, forward and backward)".into(),
            "headline figures (rms/max/mean_error_pct): instrument scaling — n and the mean sag estimated from the measured effective depth, the identified topography around the pixel (gradient; for SVE also its curvature) and the element lattice (pitch, extent: a stated assumption about the bed) only (experiment::scaling)".into(),
            "paper_scaling: the paper's definition, needs the simulator's contact count: per-element values = aggregate / n with n = |W| from the simulation (30)-(31); h = identified bed height + the mean sag of the sphere over W".into(),
            format!("steep: a footprint where the identified topography's slope |∇ĥ| exceeds depth/(4·contact radius) (DIVE {:.3}, SVE {:.3}), or reaching beyond the sample's border", dive_steep, sve_steep),
            format!("planned imaging time {total_s:.1} s; simulated time includes the first approach and settle"),
        ],
    };

    write_outputs(
        opts,
        &setup,
        &dive,
        &sve,
        &dtrace,
        &strace,
        &thin(&fd, 1500),
        fit.map(|f| f.0),
    )?;
    report.wall_total_s = wall0.elapsed().as_secs_f64();
    let json = crate::report::to_pretty(&report);
    crate::output::write_atomic(&opts.out.join("report.json"), json.as_bytes())?;
    Ok(report)
}

/// A reduced demo (tests, `--quick`): 5 × 5 taps of 0.1 s over the whole sample, 5 SVE lines of
/// 1 s through the cell's middle at the full demo's 250 nm spacing (the instrument scaling needs
/// lines closer than the contact's diameter, see [`super::run_sve`]), the rest as the paper's.
pub fn reduce(setup: &mut Setup) {
    let c = &mut setup.config;
    let n = 5u32;
    c.dive.nx = n;
    c.dive.ny = n;
    c.dive.dx_m = 5e-6 / n as f64;
    c.dive.dy_m = 5e-6 / n as f64;
    c.dive.x0_m = 2.5e-6 / n as f64;
    c.dive.y0_m = 2.5e-6 / n as f64;
    c.dive.tap_s = 0.1;
    c.sve.lines = n;
    c.sve.dy_m = 250e-9;
    c.sve.y0_m = 2.5e-6 - 2.0 * c.sve.dy_m;
    c.sve.line_period_s = 1.0;
}

/// Least squares of `F − a·δ^b` over `points` by Gauss–Newton on (ln a, b), from `start`.
pub fn fit_power_law_least_squares(
    points: &[(f64, f64)],
    start: figure::PowerLaw,
) -> figure::PowerLaw {
    // Work in nm and nN so that the numbers are of order one.
    let pts: Vec<(f64, f64)> = points.iter().map(|(d, f)| (d * 1e9, f * 1e9)).collect();
    let (mut la, mut b) = ((start.a * 1e9 * 1e-9f64.powf(start.b)).ln(), start.b);
    for _ in 0..50 {
        let (mut jtj, mut jtr) = ([[0.0f64; 2]; 2], [0.0f64; 2]);
        for &(x, y) in &pts {
            let m = (la + b * x.ln()).exp();
            let j = [m, m * x.ln()];
            let r = y - m;
            for i in 0..2 {
                jtr[i] += j[i] * r;
                for k in 0..2 {
                    jtj[i][k] += j[i] * j[k];
                }
            }
        }
        let det = jtj[0][0] * jtj[1][1] - jtj[0][1] * jtj[1][0];
        if !(det.abs() > 0.0) {
            break;
        }
        let d0 = (jtj[1][1] * jtr[0] - jtj[0][1] * jtr[1]) / det;
        let d1 = (jtj[0][0] * jtr[1] - jtj[1][0] * jtr[0]) / det;
        la += d0;
        b += d1;
        if d0.abs() < 1e-12 && d1.abs() < 1e-12 {
            break;
        }
    }
    // Back to SI: F_N = a_nn·1e-9·(δ_m·1e9)^b.
    figure::PowerLaw {
        a: la.exp() * 1e-9 * 1e9f64.powf(b),
        b,
    }
}

/// Every k-th point, so that at most `max` remain.
fn thin<T: Copy>(v: &[T], max: usize) -> Vec<T> {
    let k = v.len().div_ceil(max.max(1)).max(1);
    v.iter().step_by(k).copied().collect()
}

fn maps_of(grid: Grid, prefix: &str, props: &[Props]) -> [Map; 3] {
    let col = |f: fn(&Props) -> f64| props.iter().map(f).collect::<Vec<f64>>();
    [
        Map::from_vec(grid, format!("{prefix} h"), "m", col(|p| p.h_m)),
        Map::from_vec(grid, format!("{prefix} c"), "N·s/m", col(|p| p.c_ns_per_m)),
        Map::from_vec(grid, format!("{prefix} k"), "N/m", col(|p| p.k_n_per_m)),
    ]
}

fn error_maps(grid: Grid, prefix: &str, est: &[Props], reference: &[Props]) -> [Map; 3] {
    let col = |i: usize| {
        est.iter()
            .zip(reference)
            .map(|(e, r)| metrics::percent_errors(e, r, &PAPER_MAX)[i])
            .collect::<Vec<f64>>()
    };
    [
        Map::from_vec(grid, format!("{prefix} h error"), "%", col(0)),
        Map::from_vec(grid, format!("{prefix} c error"), "%", col(1)),
        Map::from_vec(grid, format!("{prefix} k error"), "%", col(2)),
    ]
}

fn save_map(dir: &Path, stem: &str, map: &Map) -> Result<(), OutputError> {
    write_gsf(&dir.join(format!("{stem}.gsf")), map, NanPolicy::FillMean)?;
    map_csv::write_csv(&dir.join(format!("{stem}.csv")), map)
}

#[allow(clippy::too_many_arguments)]
fn write_outputs(
    opts: &DemoOptions,
    setup: &Setup,
    dive: &DiveOutcome,
    sve: &SveOutcome,
    dtrace: &DiveTrace,
    strace: &SveTrace,
    fd: &[(f64, f64)],
    fit: Option<figure::PowerLaw>,
) -> Result<(), OutputError> {
    let c = &setup.config;
    let out = &opts.out;
    let maps_dir = out.join("maps");
    let s = &setup.sample;
    let o = s.origin_m();
    let p = s.pitch_m();
    let given_grid = Grid::covering(s.nx(), s.ny(), o[0], o[1], p, p);
    let given: Vec<Props> = (0..s.len())
        .map(|i| Props {
            h_m: s.h_m()[i],
            c_ns_per_m: s.c_n_s_per_m()[i],
            k_n_per_m: s.k_n_per_m()[i],
        })
        .collect();
    let given_maps = maps_of(given_grid, "given", &given);

    // DIVE maps on the tap grid (NaN where a tap failed).
    let dgrid = Grid::covering(
        dive.nx,
        dive.ny,
        c.dive.x0_m,
        c.dive.y0_m,
        c.dive.dx_m.max(1e-12),
        c.dive.dy_m.max(1e-12),
    );
    let nan = Props {
        h_m: f64::NAN,
        c_ns_per_m: f64::NAN,
        k_n_per_m: f64::NAN,
    };
    let mut d_est = vec![nan; dive.nx * dive.ny];
    let mut d_instr = d_est.clone();
    let mut d_ref = d_est.clone();
    let mut d_slope = vec![f64::NAN; dive.nx * dive.ny];
    for t in &dive.taps {
        let i = t.record.iy as usize * dive.nx + t.record.ix as usize;
        if i < d_est.len() && !t.failed {
            d_est[i] = t.scaled.instrument;
            d_instr[i] = t.scaled.paper;
            d_ref[i] = t.touched.reference;
            d_slope[i] = t.slope;
        }
    }
    // SVE maps: pixel centres along each line.
    let w = (c.sve.x1_m - c.sve.x0_m) / sve.nx as f64;
    let sgrid = Grid::covering(
        sve.nx,
        sve.ny,
        c.sve.x0_m + 0.5 * w,
        c.sve.y0_m,
        w,
        c.sve.dy_m.max(1e-12),
    );
    let mut s_est = vec![nan; sve.nx * sve.ny];
    let mut s_instr = s_est.clone();
    let mut s_ref = s_est.clone();
    let mut s_slope = vec![f64::NAN; sve.nx * sve.ny];
    for px in &sve.pixels {
        let i = px.line * sve.nx + px.pixel;
        s_est[i] = px.scaled.instrument;
        s_instr[i] = px.scaled.paper;
        s_ref[i] = px.touched.reference;
        s_slope[i] = px.slope;
    }
    let dive_maps = maps_of(dgrid, "DIVE", &d_est);
    let dive_instr_maps = maps_of(dgrid, "DIVE (paper scaling, n = |W|)", &d_instr);
    let dive_ref_maps = maps_of(dgrid, "given over the DIVE footprints", &d_ref);
    let dive_err = error_maps(dgrid, "DIVE", &d_est, &d_ref);
    let sve_maps = maps_of(sgrid, "SVE", &s_est);
    let sve_instr_maps = maps_of(sgrid, "SVE (paper scaling, n = |W|)", &s_instr);
    let sve_ref_maps = maps_of(sgrid, "given over the SVE footprints", &s_ref);
    let sve_err = error_maps(sgrid, "SVE", &s_est, &s_ref);
    let r = c.tip_radius_m;
    let dive_steep = metrics::steep_slope(c.dive.indent_depth_m, r);
    let sve_steep = metrics::steep_slope(c.sve.depth_ref_m, contact_radius(r, c.sve.depth_ref_m));
    let mask = |grid: Grid, slopes: &[f64], thr: f64, name: &str| {
        // Infinite slope = footprint over the border; NaN = no data, not masked.
        Map::from_vec(
            grid,
            name.to_string(),
            "",
            slopes
                .iter()
                .map(|v| if *v > thr { 1.0 } else { 0.0 })
                .collect(),
        )
    };
    let dive_mask = mask(dgrid, &d_slope, dive_steep, "steep or border footprint");
    let sve_mask = mask(sgrid, &s_slope, sve_steep, "steep or border footprint");

    let names = ["h", "c", "k"];
    for q in 0..3 {
        save_map(&maps_dir, &format!("given_{}", names[q]), &given_maps[q])?;
        save_map(&maps_dir, &format!("dive_{}", names[q]), &dive_maps[q])?;
        save_map(
            &maps_dir,
            &format!("dive_{}_paper", names[q]),
            &dive_instr_maps[q],
        )?;
        save_map(
            &maps_dir,
            &format!("dive_{}_reference", names[q]),
            &dive_ref_maps[q],
        )?;
        save_map(
            &maps_dir,
            &format!("dive_{}_error_pct", names[q]),
            &dive_err[q],
        )?;
        save_map(&maps_dir, &format!("sve_{}", names[q]), &sve_maps[q])?;
        save_map(
            &maps_dir,
            &format!("sve_{}_paper", names[q]),
            &sve_instr_maps[q],
        )?;
        save_map(
            &maps_dir,
            &format!("sve_{}_reference", names[q]),
            &sve_ref_maps[q],
        )?;
        save_map(
            &maps_dir,
            &format!("sve_{}_error_pct", names[q]),
            &sve_err[q],
        )?;
    }
    save_map(&maps_dir, "dive_steep_mask", &dive_mask)?;
    save_map(&maps_dir, "sve_steep_mask", &sve_mask)?;

    // Figs. 4–6: given, DIVE, SVE with a shared colour scale.
    let titles = [
        (
            "fig4_topography.png",
            "Topography h: given, DIVE, SVE",
            true,
        ),
        (
            "fig5_damping.png",
            "Damping coefficient c: given, DIVE, SVE",
            false,
        ),
        (
            "fig6_spring.png",
            "Spring constant k: given, DIVE, SVE",
            false,
        ),
    ];
    for q in 0..3 {
        let (file, title, relief) = titles[q];
        figure::map_panels(
            &out.join(file),
            &[
                (&given_maps[q], "given"),
                (&dive_maps[q], "DIVE"),
                (&sve_maps[q], "SVE"),
            ],
            &MapStyle {
                title: Some(title.into()),
                quantity: Some(Quantity::new(names[q], given_maps[q].unit.clone())),
                relief,
                ..Default::default()
            },
        )?;
    }
    // Fig. 7: errors, steep footprints hatched.
    for (file, mode, errs, m) in [
        ("fig7_errors_dive.png", "DIVE", &dive_err, &dive_mask),
        ("fig7_errors_sve.png", "SVE", &sve_err, &sve_mask),
    ] {
        figure::map_panels(
            &out.join(file),
            &[
                (&errs[0], "h − given"),
                (&errs[1], "c − given"),
                (&errs[2], "k − given"),
            ],
            &MapStyle {
                title: Some(format!("{mode} errors, % of h_max, c_max, k_max")),
                quantity: Some(Quantity::new("error", "%")),
                colormap: Colormap::Diverging,
                mask: Some(m),
                ..Default::default()
            },
        )?;
    }

    // Fig. 8a: DIVE, the first row of taps against time, per element (paper scaling of each tap).
    let first_row_n: Vec<f64> = dive
        .taps
        .iter()
        .map(|t| t.scaled.n_estimated.max(1.0))
        .collect();
    let t0 = dtrace.points.first().map(|p| p.0).unwrap_or(0.0);
    let per_tap = |f: fn(&TracePoint, f64) -> f64| -> Vec<(f64, f64)> {
        dtrace
            .points
            .iter()
            .map(|p| {
                (
                    p.0 - t0,
                    f(p, first_row_n.get(p.5 as usize).copied().unwrap_or(1.0)),
                )
            })
            .collect()
    };
    let given_row = |f: fn(&Props) -> f64| -> Vec<(f64, f64)> {
        let mut v = Vec::new();
        for t in dive.taps.iter().filter(|t| t.record.iy == 0) {
            // A flat segment over the tap's time slot.
            let i = t.record.ix as f64;
            v.push((i * c.dive.tap_s, f(&t.touched.reference)));
            v.push(((i + 1.0) * c.dive.tap_s, f(&t.touched.reference)));
            v.push(((i + 1.0) * c.dive.tap_s, f64::NAN));
        }
        v
    };
    figure::lines(
        &out.join("fig8_convergence_dive.png"),
        &LinePlot {
            title: Some(format!(
                "DIVE: estimates during the taps of the row at y = {:.3} µm",
                c.dive.y0_m * 1e6
            )),
            x: Quantity::new("t − t₁", "s"),
            panels: vec![
                LinePanel {
                    y: Quantity::new("c", "N·s/m"),
                    series: vec![
                        Series::line("ĉ/n", per_tap(|p, n| p.1 / n)),
                        Series::dashed("given", given_row(|p| p.c_ns_per_m)),
                    ],
                    ..Default::default()
                },
                LinePanel {
                    y: Quantity::new("k", "N/m"),
                    series: vec![
                        Series::line("k̂/n", per_tap(|p, n| p.2 / n)),
                        Series::dashed("given", given_row(|p| p.k_n_per_m)),
                    ],
                    ..Default::default()
                },
                LinePanel {
                    y: Quantity::new("U", "m"),
                    series: vec![
                        Series::line("U, highest in 50 µs", per_tap(|p, _| p.4)),
                        Series::line("U, lowest in 50 µs", per_tap(|p, _| p.3)),
                    ],
                    ..Default::default()
                },
            ],
            ..Default::default()
        },
    )?;

    // Fig. 8b: SVE, the first line's forward pass against x.
    let sve_n = |x: f64| -> f64 {
        let px = ((x - c.sve.x0_m) / w)
            .floor()
            .clamp(0.0, (sve.nx - 1) as f64) as usize;
        sve.pixels
            .get(px)
            .map(|p| p.scaled.n_estimated.max(1.0))
            .unwrap_or(1.0)
    };
    let y_line = c.sve.y0_m;
    let given_line = |f: fn(&Props) -> f64| -> Vec<(f64, f64)> {
        sve.pixels
            .iter()
            .filter(|p| p.line == 0)
            .map(|p| (p.x_m, f(&p.touched.reference)))
            .collect()
    };
    let sag = sve
        .pixels
        .first()
        .map(|p| p.touched.mean_sag_m)
        .unwrap_or(0.0);
    figure::lines(
        &out.join("fig8_convergence_sve.png"),
        &LinePlot {
            title: Some(format!(
                "SVE: estimates along the line at y = {:.3} µm (forward pass)",
                y_line * 1e6
            )),
            x: Quantity::new("x", "m"),
            panels: vec![
                LinePanel {
                    y: Quantity::new("h", "m"),
                    series: vec![
                        Series::line(
                            "ĥ (1 ms means)",
                            strace.points.iter().map(|p| (p.0, p.3 + sag)).collect(),
                        ),
                        Series::dashed("given", given_line(|p| p.h_m)),
                    ],
                    ..Default::default()
                },
                LinePanel {
                    y: Quantity::new("c", "N·s/m"),
                    series: vec![
                        Series::line(
                            "ĉ/n",
                            strace
                                .points
                                .iter()
                                .map(|p| (p.0, p.1 / sve_n(p.0)))
                                .collect(),
                        ),
                        Series::dashed("given", given_line(|p| p.c_ns_per_m)),
                    ],
                    ..Default::default()
                },
                LinePanel {
                    y: Quantity::new("k", "N/m"),
                    series: vec![
                        Series::line(
                            "k̂/n",
                            strace
                                .points
                                .iter()
                                .map(|p| (p.0, p.2 / sve_n(p.0)))
                                .collect(),
                        ),
                        Series::dashed("given", given_line(|p| p.k_n_per_m)),
                    ],
                    ..Default::default()
                },
                LinePanel {
                    y: Quantity::new("U", "m"),
                    series: vec![Series::line(
                        "U (1 ms means)",
                        strace.points.iter().map(|p| (p.0, p.4)).collect(),
                    )],
                    ..Default::default()
                },
            ],
            ..Default::default()
        },
    )?;

    // Fig. 9.
    figure::scatter_fit(
        &out.join("fig9_force_depth.png"),
        &ScatterFit {
            title: Some("Spring force against depth during an indentation (median tap)".into()),
            x: Quantity::new("δ", "m"),
            y: Quantity::new("F_k", "N"),
            points: fd.to_vec(),
            points_label: "simulation".into(),
            fit,
            ..Default::default()
        },
    )?;
    Ok(())
}

/// The summary table printed on the terminal.
pub fn summary_table(r: &DemoReport) -> String {
    let mut s = String::new();
    s += &format!(
        "simulated {:.1} s in {:.2} s of wall time ({:.1}× real time) at a {:.0} kHz loop; outputs written in {:.2} s more\n\n",
        r.simulated_s,
        r.wall_s,
        r.simulated_s / r.wall_s.max(1e-9),
        r.sample_rate_hz / 1e3,
        r.wall_total_s - r.wall_s
    );
    s += "mode  pixels  time (s)  px/s   RMS error h / c / k (% of max)   max error h / c / k   max away from steep\n";
    for (name, m) in [("DIVE", &r.dive), ("SVE", &r.sve)] {
        s += &format!(
            "{:<5} {:>6}  {:>8.1}  {:>5.1}   {:>5.2} / {:>5.2} / {:>5.2}            {:>5.2} / {:>5.2} / {:>5.2}   {:>5.2} / {:>5.2} / {:>5.2}\n",
            name,
            m.pixels,
            m.imaging_time_s,
            m.pixels_per_s,
            m.rms_error_pct.h,
            m.rms_error_pct.c,
            m.rms_error_pct.k,
            m.max_error_pct.h,
            m.max_error_pct.c,
            m.max_error_pct.k,
            m.max_error_not_steep_pct.h,
            m.max_error_not_steep_pct.c,
            m.max_error_not_steep_pct.k
        );
    }
    s += "(instrument scaling; steep from the identified topography. The paper's n = |W| scaling, which needs the simulator's contact count, is in report.json's paper_scaling)\n";
    if let Some(b) = r.dive.force_depth_exponent {
        let q = r
            .dive
            .force_depth_exponent_quartiles
            .unwrap_or([f64::NAN; 2]);
        s += &format!(
            "Fig. 9: F_k = {:.3e}·δ^{:.3} (nN, nm), exponent median over {} taps, quartiles {:.3}–{:.3}\n",
            r.dive.force_depth_prefactor_nn_nm.unwrap_or(f64::NAN),
            b,
            r.dive.force_depth_taps.unwrap_or(0),
            q[0],
            q[1]
        );
    }
    s
}

impl DiveOutcome {
    /// Per-element estimates of the taps that did not fail (paper scaling).
    pub fn estimates(&self) -> impl Iterator<Item = (&Props, &Props)> {
        self.taps
            .iter()
            .filter(|t| !t.failed)
            .map(|t| (&t.scaled.paper, &t.touched.reference))
    }
}
