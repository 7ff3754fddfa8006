//! `visco diagnose`: find the physics the nominal model left out, model it, show the fit
//! improve.
//!
//! 1. **Nominal fit** ([`search`]): the cantilever and a spherical tip on a Kelvin–Voigt
//!    element bed ([`model`]), driven by the recorded U, fitted on half the samples
//!    (interleaved blocks, [`problem`]); its RMS misfit on the other half.
//! 2. **Locate** ([`locate`]): where the misfit sits — per phase (approach, contact, dwell,
//!    retract, free), against depth and velocity, in frequency (excitation tones, harmonics,
//!    intermodulation, the resonances), over time (CUSUM), residual whiteness and correlation
//!    with the input, and per tap on maps — each a test with its p-value, family-wise
//!    corrected (Holm).
//! 3. **Name** ([`search`], [`candidates`]): each effect of the vocabulary is a model
//!    extension with its own parameters (the plant's [`crate::plant::effects`], one definition
//!    shared with the simulator); each is screened by its linearised fit, the best few (and
//!    any other a brief fit shows better) fitted in full and tested on the held-out half
//!    ([`noise::held_out_test`]); the significant one with the largest held-out likelihood
//!    joins the model, and the search repeats.
//! 4. **Model it, show the improvement** ([`report`]): the extended model's held-out RMS
//!    against the nominal's, per effect over where it acts, in words with the numbers, and
//!    figures of recorded, nominal and extended D with the residual before and after.

pub mod candidates;
pub mod explain;
pub mod fit;
pub mod json_report;
pub mod locate;
pub mod model;
pub mod noise;
pub mod problem;
pub mod report;
pub mod search;
pub mod spectrum;

pub use json_report::DiagnoseReport;
pub use report::{diagnose, Diagnosis, Options};

use candidates::Env;
use model::Trace;
use problem::Problem;
use search::Model;
use visco_core::units::{FORCE, LENGTH, TIME};

use crate::identify::signal::{moving_average, robust_sigma};

/// The recording's scales under model `m` (SI), for the candidates' searches.
pub fn environment(p: &Problem, m: &Model, env_hint: Option<&Env>) -> Env {
    let d = &p.data;
    let n = d.len();
    let provisional = env_hint.cloned().unwrap_or_else(|| Env {
        t0_s: d.t[0] * TIME,
        duration_s: (d.t[n - 1] - d.t[0]) * TIME,
        dt_s: p.dt_us * TIME,
        u_ref_m: d.u[0] * LENGTH,
        u_span_m: 0.0,
        depth_max_m: 0.0,
        force_max_n: 0.0,
        k_n_per_m: p.inst.k,
        f0_hz: p.inst.f0_mhz().map(|f| f / TIME),
        fs_hz: p.fs_hz(),
        noise_m: 1e-10,
        r_tip_m: p.inst.r_tip * LENGTH,
        speed_m_per_s: 0.0,
        relaxation_times_s: Vec::new(),
        mode2_peaks_hz: Vec::new(),
    });
    let mut tr = Trace::default();
    let sim = p.simulate(m, &provisional, Some(&mut tr));
    let resid: Vec<f64> = d.d.iter().zip(&sim).map(|(a, b)| a - b).collect();
    let noise_nm = robust_sigma(&resid).max(1e-4);
    let (umin, umax) =
        d.u.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
    let depth_max = tr.depth.iter().copied().fold(0.0f64, f64::max);
    let force_max = tr.force.iter().copied().fold(0.0f64, f64::max);
    // Typical slow speed of the base: the median |dU/dt| of the smoothed U where it moves.
    let w = p.smoothing_half_width();
    let us = moving_average(&d.u, w);
    let mut speeds: Vec<f64> = (1..n)
        .map(|i| ((us[i] - us[i - 1]) / (d.t[i] - d.t[i - 1])).abs())
        .filter(|v| v.is_finite())
        .collect();
    speeds.sort_by(f64::total_cmp);
    let vmax = speeds.last().copied().unwrap_or(0.0);
    let moving: Vec<f64> = speeds.iter().copied().filter(|&v| v > 0.1 * vmax).collect();
    let speed = moving.get(moving.len() / 2).copied().unwrap_or(vmax);
    let mut env = provisional;
    env.u_span_m = (umax - umin).max(1e-3) * LENGTH;
    env.depth_max_m = depth_max * LENGTH;
    env.force_max_n = force_max * FORCE;
    env.noise_m = noise_nm * LENGTH;
    env.speed_m_per_s = speed * LENGTH / TIME;
    env.mode2_peaks_hz = mode2_peaks(p, &resid);
    env
}

/// Transient lines of the residual between 4 and 9 f₀ (Hz), strongest first.
pub fn mode2_peaks(p: &Problem, resid: &[f64]) -> Vec<f64> {
    let Some(f0) = p.inst.f0_mhz().map(|f| f / TIME) else {
        return Vec::new();
    };
    let fs = p.fs_hz();
    let s = spectrum::Spectrum::welch(resid, fs, 1024);
    s.transient_peaks(4.0 * f0, (9.0 * f0).min(0.48 * fs), 3)
        .into_iter()
        .filter(|(_, ratio)| *ratio > 5.0)
        .map(|(f, _)| f)
        .collect()
}
