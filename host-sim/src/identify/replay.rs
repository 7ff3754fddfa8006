//! What the DIVE and SVE replays share: the cantilever from the metadata, the observer's
//! configuration derived from the recording, the survey pass's smoothing and contact search,
//! and the nominal plant of the fit.

use std::path::Path;

use visco_core::config::{ContactConfig, EstimatorConfig, NominalContact};
use visco_core::observer::ObserverConfig;
use visco_core::prefilter::HighPass;
use visco_core::regressor::{Regressor, RegressorParams};
use visco_core::{units, Cantilever, DiveRegressor};

use super::error::{IdentifyError, Result};
use super::report::{ContactDetectorJson, EstimatorJson, Observer};
use crate::plant::{Plant, PlantConfig, Travel};
use crate::recording::Metadata;
use crate::sample::Sample;

/// The estimator memories of the controller (`Config::paper`): DIVE 10 ms (short against the
/// dwell, long against the tones' periods), SVE 2 ms (a tenth of a pixel).
pub const DIVE_MEMORY_S: f64 = 10e-3;
/// See [`DIVE_MEMORY_S`].
pub const SVE_MEMORY_S: f64 = 2e-3;
/// The prior P₀ is worth this much typical data (as the controller's).
const PRIOR_S: f64 = 20e-6;
/// Contact detector of the controller: 5 kHz low-pass, γ = 0.3 nm, γ⁺ = 1 nm. The replay
/// raises γ above the free deflection's noise when the recording is noisier.
const CONTACT_LOWPASS_HZ: f64 = 5e3;
const GAMMA_M: f64 = 0.3e-9;
const GAMMA_PLUS_M: f64 = 1.0e-9;
/// Thresholds in σ of the low-passed free deflection.
const GAMMA_SIGMA: f64 = 6.0;

/// The cantilever's K, C, M from the metadata (C and M directly, or from f₀ and Q).
pub fn cantilever(meta: &Metadata, path: &Path) -> Result<(Cantilever, &'static str)> {
    let k = meta.cantilever_k_n_per_m;
    match (
        meta.cantilever_c_ns_per_m,
        meta.cantilever_m_kg,
        meta.cantilever_f0_hz,
        meta.cantilever_q,
    ) {
        (Some(c), Some(m), _, _) if c > 0.0 => Ok((
            Cantilever {
                k_n_per_m: k,
                c_ns_per_m: c,
                m_kg: m,
            },
            "cantilever_c_ns_per_m and cantilever_m_kg",
        )),
        (_, _, Some(f0), Some(q)) => Ok((
            Cantilever::from_resonance(k, f0, q),
            "cantilever_f0_hz and cantilever_q",
        )),
        _ => Err(IdentifyError::new(
            path,
            format!(
                "a `{}` recording is identified with the cantilever's dynamics (10), which need \
                 its damping and mass",
                meta.mode
            ),
        )
        .with_fix(
            "add `# cantilever_c_ns_per_m:` and `# cantilever_m_kg:` (or `# cantilever_f0_hz:` \
             and `# cantilever_q:`) to the recording's metadata",
        )),
    }
}

/// The loop rate: the metadata's, checked against the time column by the survey.
pub fn check_rate(path: &Path, meta_fs: f64, dt: &super::signal::Summary) -> Result<f64> {
    if dt.n == 0 {
        return Err(IdentifyError::new(
            path,
            "the recording has fewer than two rows",
        ));
    }
    let mean = dt.mean();
    if (dt.max - dt.min) > 0.01 * mean {
        return Err(IdentifyError::new(
            path,
            format!(
                "the sampling is not uniform (time steps from {:.4e} s to {:.4e} s): the \
                 estimator's filters are discretised at one period",
                dt.min, dt.max
            ),
        ));
    }
    let fs = 1.0 / mean;
    if (fs * (1.0 / meta_fs) - 1.0).abs() > 0.01 {
        return Err(IdentifyError::new(
            path,
            format!("sample_rate_hz is {meta_fs} but the time column advances at {fs:.6} Hz"),
        )
        .with_fix("correct `# sample_rate_hz:` (t_s rules)"));
    }
    Ok(fs)
}

/// Typical regressor sizes measured in contact by the survey (internal units: nm/µs, nm).
#[derive(Clone, Copy, Debug, Default)]
pub struct PhiTypical {
    sum_v2: f64,
    sum_p2: f64,
    n: u64,
}

impl PhiTypical {
    /// Adds one sample: the filtered tip velocity and the high-passed filtered position.
    pub fn add(&mut self, v: f64, p: f64) {
        self.sum_v2 += v * v;
        self.sum_p2 += p * p;
        self.n += 1;
    }

    /// RMS values, or the paper's DIVE scale when nothing was measured.
    pub fn rms(&self, fallback: [f64; 2]) -> [f64; 2] {
        if self.n < 100 {
            return fallback;
        }
        let v = (self.sum_v2 / self.n as f64).sqrt();
        let p = (self.sum_p2 / self.n as f64).sqrt();
        if v > 0.0 && p > 0.0 {
            [v, p]
        } else {
            fallback
        }
    }
}

/// Measures what the estimator will see: Z's filtered velocity and its position without the
/// slow part (the high-pass the SVE regression uses), with the controller's prefilter.
pub struct PhiProbe {
    params: RegressorParams<f64>,
    reg: Regressor<f64>,
    hp: HighPass<f64>,
    a: f64,
    started: bool,
}

impl PhiProbe {
    /// For the cantilever and the prefilter λ at rate `fs`.
    pub fn new(cant: &Cantilever, lambda_s: f64, fs: f64) -> Self {
        PhiProbe {
            params: RegressorParams::new(
                cant.m_kg / units::MASS,
                cant.c_ns_per_m / units::DAMPING,
                cant.k_n_per_m / units::STIFFNESS,
                lambda_s / units::TIME,
                1e6 / fs,
            ),
            reg: Regressor::at_rest(0.0, 0.0),
            hp: HighPass::at_rest(0.0),
            a: HighPass::<f64>::coefficient(highpass_hz(cant), fs),
            started: false,
        }
    }

    /// One row; returns (velocity, high-passed position), internal units.
    pub fn step(&mut self, u_m: f64, d_m: f64) -> (f64, f64) {
        let (u, z) = (u_m / units::LENGTH, (u_m - d_m) / units::LENGTH);
        if !self.started {
            self.reg = Regressor::at_rest(z, u);
            self.hp = HighPass::at_rest(z);
            self.started = true;
        }
        self.reg.update(&self.params, u, z);
        let (x, dx) = (self.reg.z_x(), self.reg.z_dx());
        (dx, self.hp.update(self.a, x))
    }
}

/// The prefilter's λ: corner at the cantilever's resonance (as `Config::paper`).
pub fn lambda_s(cant: &Cantilever) -> f64 {
    1.0 / (2.0 * std::f64::consts::PI * cant.f0_hz())
}

/// The SVE high-pass corner: f₀/32 (`Config::paper`: an eighth of f₂ = f₀/4).
pub fn highpass_hz(cant: &Cantilever) -> f64 {
    cant.f0_hz() / 32.0
}

/// A nominal aggregate contact for a tip of radius `r`: the paper's element bed (k = 3.5e-3
/// N/m, c = 6e-7 N·s/m per 100 nm element) under a fully submerged tip. Only the estimator's
/// starting point; P₀ makes it worth 20 µs of data.
pub fn nominal_contact(r: f64) -> NominalContact {
    let n = std::f64::consts::PI * r * r / (100e-9 * 100e-9);
    NominalContact {
        k_n_per_m: 3.5e-3 * n,
        c_ns_per_m: 6e-7 * n,
    }
}

/// The observer of a recording: the controller's filters, detector and estimator laws, with
/// the normalisation derived from the regressor sizes measured in the recording and bounds
/// wide enough for any sample (the projection only guards the division by k̂).
pub fn observer_config(
    fs: f64,
    cant: &Cantilever,
    r: f64,
    regressor: DiveRegressor,
    phi_dive: [f64; 2],
    phi_sve: [f64; 2],
    height_span_m: f64,
) -> ObserverConfig {
    let nominal = nominal_contact(r);
    let widen = |mut e: EstimatorConfig| {
        e.k_min_n_per_m = 1e-6;
        e.k_max_n_per_m = 1e4;
        e.c_max_ns_per_m = 1.0;
        e
    };
    let dive = widen(EstimatorConfig::derived(
        [phi_dive[0], phi_dive[1], 1.0],
        DIVE_MEMORY_S,
        PRIOR_S,
        fs,
        nominal,
    ));
    let sve = widen(EstimatorConfig::derived(
        [phi_sve[0], phi_sve[1], 1.0],
        SVE_MEMORY_S,
        PRIOR_S,
        fs,
        nominal,
    ));
    ObserverConfig {
        sample_rate_hz: fs,
        cantilever: *cant,
        lambda_s: lambda_s(cant).max(0.5 / fs),
        contact: ContactConfig {
            lowpass_hz: CONTACT_LOWPASS_HZ.min(fs / 10.0),
            gamma_m: GAMMA_M,
            gamma_plus_m: GAMMA_PLUS_M,
        },
        dive_regressor: regressor,
        dive_estimator: dive,
        sve_estimator: sve,
        sve_highpass_hz: highpass_hz(cant).min(0.2 * fs),
        height_span_m: height_span_m.max(1e-6),
    }
}

/// The observer configuration for the report (what the replay ran with).
pub fn observer_json(c: &ObserverConfig, mode_memory_s: f64, est: &EstimatorConfig) -> Observer {
    Observer {
        prefilter_lambda_s: c.lambda_s,
        estimator: EstimatorJson {
            law: "least squares with forgetting (20)–(25), exact per sample".into(),
            memory_s: mode_memory_s,
            alpha: est.alpha,
            p0: est.p0,
            r0: est.r0,
        },
        contact_detector: ContactDetectorJson {
            lowpass_hz: c.contact.lowpass_hz,
            gamma_m: c.contact.gamma_m,
            gamma_plus_m: c.contact.gamma_plus_m,
        },
    }
}

/// A causal moving average applied twice (a triangle of 2W − 1 samples): the slow part of a
/// signal with the excitation tones (≥ 1/W) taken out; its output describes the sample W − 1
/// rows back.
pub struct Smoother {
    w: usize,
    a: Boxcar,
    b: Boxcar,
    seen: u64,
}

struct Boxcar {
    buf: Vec<f64>,
    i: usize,
    sum: f64,
    n: usize,
}

impl Boxcar {
    fn new(w: usize) -> Self {
        Boxcar {
            buf: vec![0.0; w],
            i: 0,
            sum: 0.0,
            n: 0,
        }
    }
    fn push(&mut self, x: f64) -> Option<f64> {
        let w = self.buf.len();
        if self.n == w {
            self.sum -= self.buf[self.i];
        } else {
            self.n += 1;
        }
        self.buf[self.i] = x;
        self.sum += x;
        self.i = (self.i + 1) % w;
        // Recompute now and then against drift of the running sum.
        if self.i == 0 {
            self.sum = self.buf.iter().sum();
        }
        (self.n == w).then(|| self.sum / w as f64)
    }
}

impl Smoother {
    /// Window `w` samples per pass.
    pub fn new(w: usize) -> Self {
        let w = w.max(1);
        Smoother {
            w,
            a: Boxcar::new(w),
            b: Boxcar::new(w),
            seen: 0,
        }
    }

    /// Delay of the output in samples.
    pub fn delay(&self) -> u64 {
        (self.w - 1) as u64
    }

    /// Takes row `row`'s value; returns `(row − delay, smoothed)` once the window is full.
    pub fn push(&mut self, row: u64, x: f64) -> Option<(u64, f64)> {
        self.seen += 1;
        let m = self.a.push(x)?;
        let s = self.b.push(m)?;
        Some((row - self.delay(), s))
    }
}

/// The survey's contact search within one tap: the core detector on D less the mean free
/// deflection so far, with γ raised to 6·σ of the low-passed free deflection
/// when that is larger than the controller's γ.
pub struct FreeContact {
    det: visco_core::contact::ContactDetector<f64>,
    lowpass: f64,
    /// Mean of the free deflection so far.
    sum: f64,
    n: u64,
    /// The same low-pass on the raw deflection; its spread per block of ~1 ms, and the
    /// smallest block spread so far: the noise floor, which neither the ringing after a
    /// retract (it decays) nor the deflection's ramp into contact (a ramp spreads a block)
    /// can inflate.
    lp: f64,
    block: (f64, f64, u64),
    block_rows: u64,
    sigma_floor: f64,
    /// Once a candidate appears, the baseline and thresholds freeze.
    frozen: Option<(f64, f64, f64)>,
}

/// A contact found by the survey.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FoundContact {
    /// Row where it was confirmed.
    pub row: u64,
    /// Contact height Z(t₁) (m).
    pub h_m: f64,
    /// Free deflection D₀ (m).
    pub d0_m: f64,
    /// γ and γ⁺ used (m).
    pub gamma_m: f64,
    /// γ⁺ (m).
    pub gamma_plus_m: f64,
}

impl FreeContact {
    /// Armed, with the detector's low-pass coefficient for `fs`.
    pub fn new(fs: f64) -> Self {
        let lowpass_hz = CONTACT_LOWPASS_HZ.min(fs / 10.0);
        FreeContact {
            det: visco_core::contact::ContactDetector::new(0.0),
            lowpass: 1.0 - (-2.0 * std::f64::consts::PI * lowpass_hz / fs).exp(),
            sum: 0.0,
            n: 0,
            lp: 0.0,
            block: (0.0, 0.0, 0),
            block_rows: ((1e-3 * fs).round() as u64).max(20),
            sigma_floor: f64::INFINITY,
            frozen: None,
        }
    }

    /// One row (SI); returns the contact once confirmed (only at that row).
    pub fn step(&mut self, row: u64, u_m: f64, d_m: f64) -> Option<FoundContact> {
        use visco_core::contact::{ContactParams, ContactState};
        let nm = 1.0 / units::LENGTH;
        if self.n == 0 && self.frozen.is_none() {
            self.lp = d_m;
            self.det = visco_core::contact::ContactDetector::new(0.0);
        }
        self.lp += self.lowpass * (d_m - self.lp);
        let (d0, g, gp) = match self.frozen {
            Some(f) => f,
            None => {
                self.sum += d_m;
                self.n += 1;
                let x = self.lp - self.sum / self.n as f64;
                self.block.0 += x;
                self.block.1 += x * x;
                self.block.2 += 1;
                if self.block.2 == self.block_rows {
                    let m = self.block.0 / self.block.2 as f64;
                    let var = (self.block.1 / self.block.2 as f64 - m * m).max(0.0);
                    self.sigma_floor = self.sigma_floor.min(var.sqrt());
                    self.block = (0.0, 0.0, 0);
                }
                let sigma = if self.sigma_floor.is_finite() {
                    self.sigma_floor
                } else {
                    0.0
                };
                let g = GAMMA_M.max(GAMMA_SIGMA * sigma);
                (self.sum / self.n as f64, g, g * GAMMA_PLUS_M / GAMMA_M)
            }
        };
        let p = ContactParams {
            lowpass: self.lowpass,
            gamma: g * nm,
            gamma_plus: gp * nm,
        };
        if !self.sigma_floor.is_finite() {
            // Armed only once the first block has measured the noise floor: a tap may start
            // with the cantilever still ringing from the last retract.
            self.det.update(&p, 0.0, 0.0);
            return None;
        }
        let before = self.det.state();
        let state = self
            .det
            .update(&p, (d_m - d0) * nm, (u_m - (d_m - d0)) * nm);
        match (before, state) {
            (ContactState::Armed, ContactState::Candidate { .. }) => {
                self.frozen = Some((d0, g, gp));
                None
            }
            (ContactState::Candidate { .. }, ContactState::Armed) => {
                self.frozen = None;
                None
            }
            (ContactState::Candidate { .. }, ContactState::Confirmed { h }) => Some(FoundContact {
                row,
                h_m: h / nm,
                d0_m: d0,
                gamma_m: g,
                gamma_plus_m: gp,
            }),
            _ => None,
        }
    }
}

/// The per-tap minimum and maximum of a smoothed signal over blocks of rows, merged pairwise
/// when it grows past a bound: memory stays bounded whatever the tap's length.
#[derive(Clone, Debug)]
pub struct BlockTrack {
    start: u64,
    rows_per_block: u64,
    min: Vec<f64>,
    max: Vec<f64>,
}

const MAX_BLOCKS: usize = 1 << 18;

impl BlockTrack {
    /// Blocks of `rows_per_block` rows from row `start`.
    pub fn new(start: u64, rows_per_block: u64) -> Self {
        BlockTrack {
            start,
            rows_per_block: rows_per_block.max(1),
            min: Vec::new(),
            max: Vec::new(),
        }
    }

    /// Adds the value of row `row` (rows in increasing order, ≥ start).
    pub fn push(&mut self, row: u64, v: f64) {
        if row < self.start {
            return;
        }
        let b = ((row - self.start) / self.rows_per_block) as usize;
        while self.min.len() <= b {
            self.min.push(f64::INFINITY);
            self.max.push(f64::NEG_INFINITY);
        }
        self.min[b] = self.min[b].min(v);
        self.max[b] = self.max[b].max(v);
        if self.min.len() > MAX_BLOCKS {
            let merge = |v: &[f64], f: fn(f64, f64) -> f64| -> Vec<f64> {
                v.chunks(2)
                    .map(|c| c.iter().copied().fold(c[0], f))
                    .collect()
            };
            self.min = merge(&self.min, f64::min);
            self.max = merge(&self.max, f64::max);
            self.rows_per_block *= 2;
        }
    }

    /// The run of blocks around the lowest one (from row `from` on) whose values all stay
    /// within `tol(lowest)` of it: `(first row, end row, lowest)`.
    pub fn hold_around_minimum(
        &self,
        from: u64,
        tol: impl Fn(f64) -> f64,
    ) -> Option<(u64, u64, f64)> {
        let first = (from.saturating_sub(self.start)).div_ceil(self.rows_per_block) as usize;
        let (mut best, mut lo) = (None, f64::INFINITY);
        for b in first..self.min.len() {
            if self.min[b] < lo {
                lo = self.min[b];
                best = Some(b);
            }
        }
        let b0 = best?;
        let limit = lo + tol(lo);
        let mut a = b0;
        while a > first && self.max[a - 1] <= limit {
            a -= 1;
        }
        let mut e = b0;
        while e + 1 < self.max.len() && self.max[e + 1] <= limit {
            e += 1;
        }
        Some((
            self.start + a as u64 * self.rows_per_block,
            self.start + (e as u64 + 1) * self.rows_per_block,
            lo,
        ))
    }
}

/// A plant for the fit: the recording's cantilever and tip, no noise, ideal converters,
/// unlimited travel, at the recording's rate, on `sample`.
pub fn fit_plant(cant: &Cantilever, r: f64, fs: f64, sample: Sample) -> Result<Plant> {
    let mut cfg = PlantConfig::ideal();
    cfg.cantilever = *cant;
    cfg.tip_radius_m = r;
    cfg.time_step_s = 1.0 / fs;
    cfg.travel_z = Travel {
        min_m: -1.0,
        max_m: 1.0,
    };
    cfg.travel_xy = Travel {
        min_m: -1.0,
        max_m: 1.0,
    };
    Plant::new(cfg, sample, 0)
        .map_err(|e| IdentifyError::new(Path::new("(nominal plant)"), e.to_string()))
}
