//! The experiments of the paper's section 5 with the core in the loop: DIVE taps and SVE scans
//! of a simulated sample, their per-element estimates, the reference values they are compared
//! with, and the error figures.
//!
//! The simulation calls the same per-sample [`Controller::step`] the firmware's interrupt
//! calls, in f32, at the core's loop rate; the plant ([`crate::plant`]) is exact at that step,
//! so it needs no sub-stepping. Everything the core reports is an aggregate over the tip; the
//! per-element values and their references are formed here, outside the loop (the paper's
//! section 5.2 and Appendix A).
//!
//! # References: "the given values averaged over the tip footprint"
//! The footprint is the set of elements the tip actually touches — the paper's active set W —
//! while the estimate is being averaged (a DIVE tap's read-out window, an SVE pixel's pass):
//! [`FootprintCollector`] samples W 25 times per window and the reference is the plain mean of
//! hᵢ, cᵢ, kᵢ over those elements, each weighted by the time it spent in W (for SVE, over the
//! forward and the backward pass). For a submerged DIVE tip W is every element with r < R; for
//! SVE on flat ground, every element within the contact radius a = √(2Rδ − δ²).
//!
//! # Per-element estimates (what an instrument can compute: no knowledge of W)
//! * n is the number of elements of the sample's lattice under the tip on a locally flat
//!   surface: within R of the axis for DIVE; for SVE within the contact radius at the apex
//!   depth δ that makes the measured effective depth F/k̂ = δ − s̄(δ), averaged along the
//!   pixel's pass. s̄ is the exact mean sag R − √(R² − r²) over those sites (Appendix A's R/3 is
//!   its continuum limit, off by up to ±9 % on a 100 nm lattice).
//! * c = ĉ/n and k = k̂/n (30)–(31). The paper's DIVE regressor also needs (32),
//!   k = (k̂/n)·δ/(δ − s̄); the offset regressor identifies k̂ without that bias.
//! * h: DIVE paper — the contact height; DIVE offset and SVE — the identified bed height plus
//!   the mean sag (the bed height is the k-weighted mean of hᵢ − sᵢ).
//!
//! * SVE's bed under the tip is the identified topography to second order: the gradient and the
//!   curvature of the map of identified bed heights (second differences over ±200 nm along the
//!   line, ±1 line across). A curved bed changes the contact at a given effective depth as an
//!   effective radius 1/(1/R + κ) does in Hertz contact: on the nucleus cap (κ ≈ 0.5/µm against
//!   1/R = 3.3/µm) the flat-bed count is ≈ 10 % too large. Across lines farther apart than the
//!   contact's diameter the topography is unresolved and taken as level; pixels whose footprint
//!   reaches over the lattice's border take no part in the derivatives.
//!
//! On steep topography the local model fails (Appendix B); "steep" is judged on the identified
//! topography (largest |∇ĥ| over the footprint), see [`metrics::steep_slope`].

pub mod concealed;
pub mod demo;
pub mod excitation_study;
pub mod faults;
pub mod fixed_point;
pub mod metrics;
pub mod scaling;
pub mod sweep;

use crate::plant::{Plant, PlantConfig, PlantError};
use crate::sample::Sample;
use visco_core::geometry::{contact_radius, Lattice};
use visco_core::{
    status, Command, Config, ConfigError, Controller, DiveRegressor, Mode, Phase, PixelRecord,
    Record, TapRecord,
};

/// Per-element properties at one place: height (m), damping (N·s/m), spring constant (N/m).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Props {
    /// Height h (m).
    pub h_m: f64,
    /// Damping c (N·s/m).
    pub c_ns_per_m: f64,
    /// Spring constant k (N/m).
    pub k_n_per_m: f64,
}

/// Everything an experiment needs: the core's configuration, the plant's, the sample, a seed.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The core (loop rate, cantilever, tuning, sequences).
    pub config: Config,
    /// The simulated instrument.
    pub plant: PlantConfig,
    /// The sample under the tip.
    pub sample: Sample,
    /// Noise seed.
    pub seed: u64,
}

/// Why an experiment could not run.
#[derive(Debug)]
pub enum ExperimentError {
    /// The core refused its configuration.
    Config(ConfigError),
    /// The plant refused its configuration.
    Plant(PlantError),
}

impl std::fmt::Display for ExperimentError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ExperimentError::Config(e) => write!(f, "{e}"),
            ExperimentError::Plant(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for ExperimentError {}

impl From<ConfigError> for ExperimentError {
    fn from(e: ConfigError) -> Self {
        ExperimentError::Config(e)
    }
}

impl From<PlantError> for ExperimentError {
    fn from(e: PlantError) -> Self {
        ExperimentError::Plant(e)
    }
}

impl Setup {
    /// The paper's simulation study on `sample` at `sample_rate_hz`, with the instrument's
    /// converters matched to the core's ranges (the core puts U on its DAC grid; the plant's DAC
    /// is the same grid, so nothing is quantised twice differently).
    pub fn paper(sample: Sample, sample_rate_hz: f64, seed: u64) -> Self {
        let config = Config::paper(sample_rate_hz);
        let mut plant = PlantConfig::paper();
        let l = &config.limits;
        plant.cantilever = config.cantilever;
        plant.tip_radius_m = config.tip_radius_m;
        plant.time_step_s = 1.0 / sample_rate_hz;
        plant.adc_deflection.min_m = -l.d_full_scale_m;
        plant.adc_deflection.max_m = l.d_full_scale_m;
        plant.dac_z.min_m = l.u_min_m;
        plant.dac_z.max_m = l.u_max_m;
        plant.dac_z.bits = l.dac_bits;
        plant.travel_z.min_m = l.u_min_m;
        plant.travel_z.max_m = l.u_max_m;
        plant.dac_xy.min_m = l.xy_min_m;
        plant.dac_xy.max_m = l.xy_max_m;
        plant.dac_xy.bits = l.xy_dac_bits;
        plant.travel_xy.min_m = l.xy_min_m;
        plant.travel_xy.max_m = l.xy_max_m;
        Setup {
            config,
            plant,
            sample,
            seed,
        }
    }

    /// The apex's swing under the two tones of `mode` on the nominal contact (see
    /// [`scaling::swing`]): the base amplitudes times |Z/U|.
    pub fn tip_swing(&self, mode: Mode) -> Vec<f64> {
        let c = &self.config;
        let (x, n) = match mode {
            Mode::Dive => (c.dive.excitation, c.nominal_dive),
            Mode::Sve => (c.sve.excitation, c.nominal_sve),
        };
        let t = |f: f64, a: f64| a * c.cantilever.tip_over_base(f, n.k_n_per_m, n.c_ns_per_m);
        scaling::swing([t(x.f1_hz, x.a1_m), t(x.f2_hz, x.a2_m)])
    }

    /// The sample's lattice, for the exact element counts.
    pub fn lattice(&self) -> Lattice {
        let o = self.sample.origin_m();
        let p = self.sample.pitch_m();
        Lattice {
            pitch_x: p,
            pitch_y: p,
            origin_x: o[0],
            origin_y: o[1],
        }
    }

    /// A plant at rest at the approach start, above the first tap.
    pub fn build_plant(&self) -> Result<Plant, ExperimentError> {
        let mut plant = Plant::new(self.plant.clone(), self.sample.clone(), self.seed)?;
        plant.set_time_step(1.0 / self.config.sample_rate_hz)?;
        let c = &self.config;
        plant.settle(c.approach.u_start_m, c.dive.x0_m, c.dive.y0_m);
        Ok(plant)
    }
}

/// Something that watches the loop: called after every step with the controller, the step's
/// output and the plant (for traces and figures), and with every record the core produces.
/// `()` watches nothing; a pair watches with both.
pub trait Observer {
    /// One sample.
    fn sample(&mut self, ctrl: &Controller<f32>, out: &visco_core::StepOut<f32>, plant: &Plant);
    /// A finished tap or pixel, with the plant as it is then.
    fn record(&mut self, _rec: &Record<f32>, _plant: &Plant) {}
}

impl Observer for () {
    #[inline(always)]
    fn sample(&mut self, _: &Controller<f32>, _: &visco_core::StepOut<f32>, _: &Plant) {}
}

impl<A: Observer, B: Observer> Observer for (A, B) {
    #[inline(always)]
    fn sample(&mut self, ctrl: &Controller<f32>, out: &visco_core::StepOut<f32>, plant: &Plant) {
        self.0.sample(ctrl, out, plant);
        self.1.sample(ctrl, out, plant);
    }
    fn record(&mut self, rec: &Record<f32>, plant: &Plant) {
        self.0.record(rec, plant);
        self.1.record(rec, plant);
    }
}

impl<O: Observer + ?Sized> Observer for &mut O {
    #[inline(always)]
    fn sample(&mut self, ctrl: &Controller<f32>, out: &visco_core::StepOut<f32>, plant: &Plant) {
        (**self).sample(ctrl, out, plant);
    }
    fn record(&mut self, rec: &Record<f32>, plant: &Plant) {
        (**self).record(rec, plant);
    }
}

/// The elements the tip actually touches while a record is being averaged — the paper's active
/// set W, sampled every `stride` read-out samples — and, for each record, their mean h, c, k
/// weighted by the time each spent in W: the "given values averaged over the tip footprint".
pub struct FootprintCollector {
    stride: u32,
    countdown: u32,
    weights: Vec<u32>,
    touched: Vec<usize>,
    snapshots: u32,
    members: u64,
    sag_sum: f64,
    /// The records in order, each with what the tip touched while it was averaged.
    pub records: Vec<(Record<f32>, Touched)>,
}

/// What the tip touched while a record was averaged (simulation ground truth).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Touched {
    /// The given values averaged over the elements in contact, each weighted by its time in W.
    pub reference: Props,
    /// Time-averaged |W|: the paper's n.
    pub n: f64,
    /// Mean sag of the sphere over the elements in contact (m).
    pub mean_sag_m: f64,
}

impl FootprintCollector {
    /// For a sample of `elements` elements, a snapshot every `stride` read-out samples.
    pub fn new(elements: usize, stride: u32) -> Self {
        Self {
            stride: stride.max(1),
            countdown: 0,
            weights: vec![0; elements],
            touched: Vec::new(),
            snapshots: 0,
            members: 0,
            sag_sum: 0.0,
            records: Vec::new(),
        }
    }
}

impl Observer for FootprintCollector {
    #[inline(always)]
    fn sample(&mut self, _: &Controller<f32>, out: &visco_core::StepOut<f32>, plant: &Plant) {
        if out.status & status::READOUT == 0 {
            return;
        }
        if self.countdown > 0 {
            self.countdown -= 1;
            return;
        }
        self.countdown = self.stride - 1;
        self.snapshots += 1;
        let [x, y, _] = plant.tip_position_m();
        let r = plant.config().tip_radius_m;
        let sample = plant.sample();
        for i in plant.active_element_indices() {
            if let Some(w) = self.weights.get_mut(i) {
                if *w == 0 {
                    self.touched.push(i);
                }
                *w += 1;
                self.members += 1;
                let [ex, ey] = sample.element_xy_m(i % sample.nx(), i / sample.nx());
                let r2 = (ex - x) * (ex - x) + (ey - y) * (ey - y);
                self.sag_sum += r - (r * r - r2).max(0.0).sqrt();
            }
        }
    }

    fn record(&mut self, rec: &Record<f32>, plant: &Plant) {
        let s = plant.sample();
        let (mut wsum, mut h, mut c, mut k) = (0.0f64, 0.0, 0.0, 0.0);
        for &i in &self.touched {
            let w = self.weights[i] as f64;
            wsum += w;
            h += w * s.h_m()[i];
            c += w * s.c_n_s_per_m()[i];
            k += w * s.k_n_per_m()[i];
            self.weights[i] = 0;
        }
        self.touched.clear();
        let props = if wsum > 0.0 {
            Props {
                h_m: h / wsum,
                c_ns_per_m: c / wsum,
                k_n_per_m: k / wsum,
            }
        } else {
            Props {
                h_m: f64::NAN,
                c_ns_per_m: f64::NAN,
                k_n_per_m: f64::NAN,
            }
        };
        let n = if self.snapshots > 0 {
            self.members as f64 / self.snapshots as f64
        } else {
            0.0
        };
        let mean_sag_m = if self.members > 0 {
            self.sag_sum / self.members as f64
        } else {
            0.0
        };
        self.records.push((
            *rec,
            Touched {
                reference: props,
                n,
                mean_sag_m,
            },
        ));
        self.snapshots = 0;
        self.members = 0;
        self.sag_sum = 0.0;
        self.countdown = 0;
    }
}

/// Run `mode` to its end (or `max_s` of simulated time). Records go to the observer with the
/// plant as it is when the record is taken; `progress` is called about every 10 ms of simulated
/// time with the elapsed simulated seconds. Returns the simulated time (s).
pub fn run(
    ctrl: &mut Controller<f32>,
    plant: &mut Plant,
    mode: Mode,
    max_s: f64,
    observer: &mut impl Observer,
    mut progress: impl FnMut(f64),
) -> f64 {
    let fs = ctrl.config().sample_rate_hz;
    let max_steps = (max_s * fs) as u64;
    let report_every = ((0.01 * fs) as u64).max(1);
    ctrl.command(Command::Start(mode));
    let mut d = plant.measured_deflection_m() as f32;
    let mut steps = 0u64;
    while steps < max_steps {
        let out = ctrl.step(d);
        steps += 1;
        observer.sample(ctrl, &out, plant);
        if out.status & status::RECORD_READY != 0 {
            if let Some(r) = ctrl.take_record() {
                observer.record(&r, plant);
            }
        }
        if ctrl.phase() == Phase::Done {
            break;
        }
        d = plant_reading(plant, &out);
        if steps % report_every == 0 {
            progress(steps as f64 / fs);
        }
    }
    progress(steps as f64 / fs);
    steps as f64 / fs
}

/// Per-element values of one record under the two scalings (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Scaled {
    /// The paper's scaling: n = |W| and the mean sag over W from the simulation.
    pub paper: Props,
    /// The instrument's: n and the sag estimated from measured quantities only.
    pub instrument: Props,
    /// The instrument's estimate of n.
    pub n_estimated: f64,
}

/// One DIVE tap: what the core reported, and the per-element estimates against the reference.
#[derive(Clone, Copy, Debug)]
pub struct TapEstimate {
    /// The core's record (aggregates).
    pub record: TapRecord<f32>,
    /// What the tip touched (reference, |W|, sag).
    pub touched: Touched,
    /// Per-element estimates.
    pub scaled: Scaled,
    /// Slope of the identified topography over the footprint (largest |∇ĥ| of the taps within
    /// R); infinite where the footprint reaches over the sample's border. What "steep" uses.
    pub slope: f64,
    /// Steepest element slope |Δh|/pitch in the footprint (simulation truth, for comparison).
    pub slope_true: f64,
    /// The tap found no contact or had a too-short dwell.
    pub failed: bool,
}

/// Per-element values from aggregates (ĉ, k̂), an element count n, a mean sag and the bed
/// height; `paper_dive` applies correction (32) with the mean depth and takes the contact
/// height for h.
fn per_element(rec: &TapRecord<f32>, n: f64, sag: f64) -> Props {
    let n = n.max(1.0);
    let c = rec.c_ns_per_m as f64 / n;
    match rec.regressor {
        DiveRegressor::Paper => {
            let delta = rec.depth_m as f64;
            Props {
                h_m: rec.contact_height_m as f64,
                c_ns_per_m: c,
                k_n_per_m: rec.k_n_per_m as f64 / n * delta / (delta - sag),
            }
        }
        DiveRegressor::Offset => Props {
            h_m: rec.bed_height_m() + sag,
            c_ns_per_m: c,
            k_n_per_m: rec.k_n_per_m as f64 / n,
        },
    }
}

/// Per-element estimates of a tap (module docs); `grad` is the local gradient of the
/// identified topography (zero for a first pass), `swing` the apex's excitation swing.
pub fn scale_tap(
    setup: &Setup,
    rec: &TapRecord<f32>,
    touched: Touched,
    grad: [f64; 2],
    swing: &[f64],
) -> TapEstimate {
    let r = setup.config.tip_radius_m;
    let (x, y) = (rec.x_m as f64, rec.y_m as f64);
    let (n_est, sag_est) = match rec.regressor {
        // The paper: every element within R.
        DiveRegressor::Paper => setup
            .sample
            .footprint_mean(x, y, r)
            .map_or((0.0, 0.0), |f| (f.n as f64, f.sag_m)),
        // From the measured effective depth and the local slope.
        DiveRegressor::Offset => {
            let z_mean = rec.contact_height_m as f64 - rec.depth_m as f64;
            let lc = scaling::contact_for(
                &setup.sample,
                &[(x, y)],
                r,
                rec.bed_height_m() - z_mean,
                grad,
                swing,
            );
            (lc.n, lc.mean_sag_m)
        }
    };
    TapEstimate {
        record: *rec,
        touched,
        scaled: Scaled {
            paper: per_element(rec, touched.n, touched.mean_sag_m),
            instrument: per_element(rec, n_est, sag_est),
            n_estimated: n_est,
        },
        slope: f64::NAN,
        slope_true: footprint_slope(&setup.sample, &[(x, y)], r),
        failed: rec.flags & (status::NO_CONTACT | status::SHORT_DWELL) != 0 || rec.samples == 0,
    }
}

/// Steepest element slope (|Δh| to a neighbour / pitch) within `radius` of any of `points`;
/// infinite when a footprint reaches beyond the sample's area, where part of the tip has no
/// elements under it (the sample's border is an edge too: the flat-bed geometry fails there
/// as on a steep slope).
pub fn footprint_slope(sample: &Sample, points: &[(f64, f64)], radius: f64) -> f64 {
    let slopes = sample.slope_map();
    let [x0, x1, y0, y1] = sample.extent_m();
    let mut s: f64 = 0.0;
    for &(x, y) in points {
        if x - radius < x0 || x + radius > x1 || y - radius < y0 || y + radius > y1 {
            return f64::INFINITY;
        }
        sample.for_each_within(x, y, radius, |e| s = s.max(slopes[e.index]));
    }
    s
}

/// A footprint of radius `radius` at (x, y) reaches beyond the sample's lattice (the lattice is
/// the instrument's stated model of the bed, so this is known without the sample's heights).
fn over_border(sample: &Sample, x: f64, y: f64, radius: f64) -> bool {
    let [x0, x1, y0, y1] = sample.extent_m();
    x - radius < x0 || x + radius > x1 || y - radius < y0 || y + radius > y1
}

/// The result of a DIVE image.
#[derive(Clone, Debug)]
pub struct DiveOutcome {
    /// Taps in sequence order.
    pub taps: Vec<TapEstimate>,
    /// Grid size.
    pub nx: usize,
    /// Grid size.
    pub ny: usize,
    /// Simulated time (s).
    pub simulated_s: f64,
}

/// Snapshots of the contact set per read-out: every 1/25 of the read-out window.
fn collector(setup: &Setup, window_s: f64) -> FootprintCollector {
    let stride = (window_s * setup.config.sample_rate_hz / 25.0).max(1.0) as u32;
    FootprintCollector::new(setup.sample.len(), stride)
}

/// Run the DIVE image of `setup` and scale every tap.
pub fn run_dive(
    setup: &Setup,
    observer: &mut impl Observer,
    progress: impl FnMut(f64),
) -> Result<DiveOutcome, ExperimentError> {
    let mut ctrl = Controller::<f32>::new(&setup.config)?;
    let mut plant = setup.build_plant()?;
    let mut obs = (collector(setup, setup.config.dive.readout_s), observer);
    let max_s = setup.config.dive_imaging_s() * 1.5 + 1.0;
    let simulated_s = run(&mut ctrl, &mut plant, Mode::Dive, max_s, &mut obs, progress);
    let d = &setup.config.dive;
    let (nx, ny) = (d.nx as usize, d.ny as usize);
    let records: Vec<(TapRecord<f32>, Touched)> = obs
        .0
        .records
        .iter()
        .filter_map(|(r, t)| match r {
            Record::Tap(rec) => Some((*rec, *t)),
            _ => None,
        })
        .collect();
    // The identified heights give the topography's gradient, which tilts the contact set.
    let swing = setup.tip_swing(Mode::Dive);
    let mut h = vec![f64::NAN; nx * ny];
    for (rec, _) in &records {
        if let Some(v) = h.get_mut(rec.iy as usize * nx + rec.ix as usize) {
            let failed =
                rec.flags & (status::NO_CONTACT | status::SHORT_DWELL) != 0 || rec.samples == 0;
            *v = if failed { f64::NAN } else { rec.bed_height_m() };
        }
    }
    let grad = scaling::grid_gradient(&h, nx, ny, d.dx_m, d.dy_m);
    let r = setup.config.tip_radius_m;
    let reach = |pitch: f64| if pitch > 0.0 { (r / pitch) as usize } else { 0 };
    let slope_id = scaling::footprint_max_slope(&grad, nx, ny, reach(d.dx_m), reach(d.dy_m));
    let taps = records
        .iter()
        .map(|(rec, touched)| {
            let g = grad
                .get(rec.iy as usize * nx + rec.ix as usize)
                .copied()
                .unwrap_or([0.0; 2]);
            let mut t = scale_tap(setup, rec, *touched, g, &swing);
            let (x, y) = (rec.x_m as f64, rec.y_m as f64);
            t.slope = if over_border(&setup.sample, x, y, r) {
                f64::INFINITY
            } else {
                slope_id
                    .get(rec.iy as usize * nx + rec.ix as usize)
                    .copied()
                    .unwrap_or(f64::INFINITY)
            };
            t
        })
        .collect();
    Ok(DiveOutcome {
        taps,
        nx,
        ny,
        simulated_s,
    })
}

/// One SVE map pixel: forward and backward records of the same place, averaged.
#[derive(Clone, Copy, Debug)]
pub struct PixelEstimate {
    /// Line (row of the map).
    pub line: usize,
    /// Pixel along the line.
    pub pixel: usize,
    /// Mean lateral position of the two passes (m).
    pub x_m: f64,
    /// Lateral position (m).
    pub y_m: f64,
    /// What the tip touched, averaged over both passes.
    pub touched: Touched,
    /// Per-element estimates, mean of forward and backward.
    pub scaled: Scaled,
    /// Forward pass only (instrument scaling).
    pub forward: Props,
    /// Backward pass only (instrument scaling).
    pub backward: Props,
    /// Slope of the identified topography over the footprint (largest |∇ĥ| of the pixels within
    /// the contact radius); infinite where the footprint reaches over the sample's border. What
    /// "steep" uses.
    pub slope: f64,
    /// Steepest element slope in the footprints (simulation truth, for comparison).
    pub slope_true: f64,
    /// The local bed the instrument scaling assumed (identified gradient and curvature).
    pub bed: scaling::LocalBed,
    /// Status bits of both passes.
    pub flags: u32,
}

/// The result of an SVE image.
#[derive(Clone, Debug)]
pub struct SveOutcome {
    /// Pixels, line by line.
    pub pixels: Vec<PixelEstimate>,
    /// Pixels per line.
    pub nx: usize,
    /// Lines.
    pub ny: usize,
    /// Simulated time (s), approach and settle included.
    pub simulated_s: f64,
}

/// Positions along a pixel's pass, for its element count.
fn pixel_path(setup: &Setup, rec: &PixelRecord<f32>) -> Vec<(f64, f64)> {
    let s = &setup.config.sve;
    let w = (s.x1_m - s.x0_m) / s.pixels as f64;
    let x0 = s.x0_m + w * rec.pixel as f64;
    (0..8)
        .map(|i| (x0 + w * (i as f64 + 0.5) / 8.0, rec.y_m as f64))
        .collect()
}

fn pixel_props(rec: &PixelRecord<f32>, n: f64, sag: f64) -> Props {
    let n = n.max(1.0);
    Props {
        h_m: rec.bed_height_m as f64 + sag,
        c_ns_per_m: rec.c_ns_per_m as f64 / n,
        k_n_per_m: rec.k_n_per_m as f64 / n,
    }
}

/// Per-element estimates of one pass on the identified local bed.
fn scale_pixel(
    setup: &Setup,
    rec: &PixelRecord<f32>,
    touched: &Touched,
    bed: &scaling::LocalBed,
    swing: &[f64],
) -> Scaled {
    let r = setup.config.tip_radius_m;
    let lc = scaling::contact_on(
        &setup.sample,
        &pixel_path(setup, rec),
        r,
        rec.depth_m as f64,
        bed,
        swing,
    );
    Scaled {
        paper: pixel_props(rec, touched.n, touched.mean_sag_m),
        instrument: pixel_props(rec, lc.n, lc.mean_sag_m),
        n_estimated: lc.n,
    }
}

/// Run the SVE image of `setup`, pair forward and backward pixels and scale them.
pub fn run_sve(
    setup: &Setup,
    observer: &mut impl Observer,
    progress: impl FnMut(f64),
) -> Result<SveOutcome, ExperimentError> {
    let mut ctrl = Controller::<f32>::new(&setup.config)?;
    let mut plant = setup.build_plant()?;
    let s = &setup.config.sve;
    let (nx, ny) = (s.pixels as usize, s.lines as usize);
    let pixel_s = (s.line_period_s - s.turn_s) / 2.0 / s.pixels as f64;
    let mut obs = (collector(setup, pixel_s), observer);
    let max_s = setup.config.sve_imaging_s() * 1.5 + 1.0;
    let simulated_s = run(&mut ctrl, &mut plant, Mode::Sve, max_s, &mut obs, progress);
    let mut fwd: Vec<Option<(PixelRecord<f32>, Touched)>> = vec![None; nx * ny];
    let mut bwd = fwd.clone();
    for (r, t) in &obs.0.records {
        if let Record::Pixel(p) = r {
            let i = p.line as usize * nx + p.pixel as usize;
            if i < fwd.len() {
                let slot = if p.forward { &mut fwd[i] } else { &mut bwd[i] };
                *slot = Some((*p, *t));
            }
        }
    }
    let r = setup.config.tip_radius_m;
    let a_ref = contact_radius(r, s.depth_ref_m);
    let mean = |a: f64, b: f64| 0.5 * (a + b);
    let mean_props = |a: &Props, b: &Props| Props {
        h_m: mean(a.h_m, b.h_m),
        c_ns_per_m: mean(a.c_ns_per_m, b.c_ns_per_m),
        k_n_per_m: mean(a.k_n_per_m, b.k_n_per_m),
    };
    // The identified bed heights give the topography's gradient and curvature, which tilt and
    // bend the bed under the tip (module docs). Pixels whose footprint reaches over the lattice's
    // border read a bed that is cut off there; they take no part in the derivatives.
    let swing = setup.tip_swing(Mode::Sve);
    let w = (s.x1_m - s.x0_m) / nx as f64;
    let centre = |pixel: usize, line: usize| {
        [
            s.x0_m + w * (pixel as f64 + 0.5),
            s.y0_m + s.dy_m * line as f64,
        ]
    };
    let border = |pixel: usize, line: usize| {
        let c = centre(pixel, line);
        over_border(&setup.sample, c[0], c[1], a_ref + 0.5 * w)
    };
    let mut h = vec![f64::NAN; nx * ny];
    for i in 0..nx * ny {
        if let (Some((f, _)), Some((b, _))) = (&fwd[i], &bwd[i]) {
            if !border(i % nx, i / nx) {
                h[i] = mean(f.bed_height_m as f64, b.bed_height_m as f64);
            }
        }
    }
    // Lines farther apart than the contact's diameter do not see the same bed: across them the
    // topography is unresolved and the bed is taken as level.
    let resolve_y = s.dy_m <= 2.0 * a_ref;
    let mut grad = scaling::grid_gradient(&h, nx, ny, w, s.dy_m);
    for line in 0..ny {
        for pixel in 0..nx {
            let i = line * nx + pixel;
            if !resolve_y {
                grad[i][1] = 0.0;
            }
            if !h[i].is_finite() {
                // The nearest pixel of the line with a gradient.
                if let Some(q) = (0..nx)
                    .filter(|&q| h[line * nx + q].is_finite())
                    .min_by_key(|&q| q.abs_diff(pixel))
                {
                    grad[i] = grad[line * nx + q];
                }
            }
        }
    }
    let curv = scaling::grid_curvature(&h, nx, ny, w, s.dy_m, resolve_y);
    let slope_id = scaling::footprint_max_slope(
        &grad,
        nx,
        ny,
        ((a_ref + 0.5 * w) / w).ceil() as usize,
        if resolve_y {
            (a_ref / s.dy_m) as usize
        } else {
            0
        },
    );
    let mut pixels = Vec::with_capacity(nx * ny);
    for line in 0..ny {
        for pixel in 0..nx {
            let i = line * nx + pixel;
            let (Some((f, tf)), Some((b, tb))) = (fwd[i], bwd[i]) else {
                continue;
            };
            let bed = scaling::LocalBed {
                centre_m: centre(pixel, line),
                grad: grad[i],
                curv_per_m: curv[i],
            };
            let sf = scale_pixel(setup, &f, &tf, &bed, &swing);
            let sb = scale_pixel(setup, &b, &tb, &bed, &swing);
            pixels.push(PixelEstimate {
                line,
                pixel,
                x_m: mean(f.x_m as f64, b.x_m as f64),
                y_m: f.y_m as f64,
                touched: Touched {
                    reference: mean_props(&tf.reference, &tb.reference),
                    n: mean(tf.n, tb.n),
                    mean_sag_m: mean(tf.mean_sag_m, tb.mean_sag_m),
                },
                scaled: Scaled {
                    paper: mean_props(&sf.paper, &sb.paper),
                    instrument: mean_props(&sf.instrument, &sb.instrument),
                    n_estimated: mean(sf.n_estimated, sb.n_estimated),
                },
                forward: sf.instrument,
                backward: sb.instrument,
                slope: if border(pixel, line) {
                    f64::INFINITY
                } else {
                    slope_id[i]
                },
                slope_true: footprint_slope(&setup.sample, &pixel_path(setup, &f), a_ref),
                bed,
                flags: f.flags | b.flags,
            });
        }
    }
    Ok(SveOutcome {
        pixels,
        nx,
        ny,
        simulated_s,
    })
}

/// The plant's next reading (m) for the loop's output: the plant driven in nm, without round
/// trips through metres (its `step_nm`).
pub(crate) fn plant_reading(plant: &mut Plant, out: &visco_core::StepOut<f32>) -> f32 {
    (plant.step_nm(
        out.u_m as f64 * 1e9,
        out.x_m as f64 * 1e9,
        out.y_m as f64 * 1e9,
    ) * 1e-9) as f32
}
