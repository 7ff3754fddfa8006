//! Which excitation (f₁, f₂, amplitudes) identifies fastest — argued from the persistency of
//! excitation and checked by simulation.
//!
//! The regressor of a DIVE tap is φ = [−sZ/Λ, z₀ − Z/Λ, 1]: the filtered tip velocity, position
//! and a constant. Under two tones of tip amplitudes A₁, A₂ at ω₁, ω₂ the averaged information
//! R̄ = E[φφᵀ]/m² is diagonal in the first two entries (velocity and position of one tone are in
//! quadrature, different tones are uncorrelated): the damping c is learnt from Σ ωᵢ²Aᵢ²/|Λ(ωᵢ)|²
//! and the spring constant k from Σ Aᵢ²/|Λ(ωᵢ)|². What limits the time to a given accuracy is
//! the *relative* information of the worst-known parameter, each entry scaled by its parameter
//! (θᵢ²·R̄ᵢᵢ), against the noise in w. In contact c·ω ≫ k above ~1 kHz (c·ω/k = 21 at 20 kHz
//! for the paper's numbers), so the spring term is the small one: k is the parameter the
//! excitation must serve, and a tone well below resonance carries most of its information
//! (|Λ| → 1 there and the noise of w, dominated by M·s²Z, falls with frequency), while the tone
//! near resonance serves c.
//!
//! The study measures it: for each candidate excitation a DIVE tap on a flat sample (the full
//! plant, noise and converters on, the core in the loop) with the estimator's memory fixed, and
//! the spread of ĉ and k̂ over the read-out. A smaller spread at a fixed memory is more
//! information per second: the time to reach a given accuracy scales with the spread squared.
//! The predicted relative information per parameter is reported beside it.

use super::{run, Observer, Setup};
use crate::plant::Plant;
use crate::sample::Sample;
use schemars::JsonSchema;
use serde::Serialize;
use visco_core::{status, Controller, Mode, StepOut};

/// One candidate and its result.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct Candidate {
    /// f₁ (Hz).
    pub f1_hz: f64,
    /// f₂ (Hz).
    pub f2_hz: f64,
    /// Tip amplitudes at f₁ and f₂ on the nominal contact (m).
    pub tip_amplitudes_m: [f64; 2],
    /// Relative standard deviation of ĉ and k̂ over the read-out windows (fraction).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 2]")]
    pub relative_spread: [f64; 2],
    /// Time for the estimator's k̂ to come within 1 % of its final value, from the nominal
    /// start, averaged over the taps (s).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "Option<f64>")]
    pub time_to_1pct_s: f64,
    /// Predicted relative information per sample of c and k (θ²·R̄ᵢᵢ, arbitrary common scale).
    pub predicted_information: [f64; 2],
}

/// Keeps k̂ and ĉ samples while estimating, per tap.
#[derive(Default)]
struct Spread {
    taps: Vec<Vec<(f64, f64, f64)>>,
    current: Vec<(f64, f64, f64)>,
    t: f64,
    dt: f64,
}

impl Observer for Spread {
    fn sample(&mut self, ctrl: &Controller<f32>, out: &StepOut<f32>, _plant: &Plant) {
        self.t += self.dt;
        if out.status & status::ESTIMATING != 0 {
            let (c, k, _) = ctrl.estimates();
            self.current.push((self.t, c as f64, k as f64));
        }
    }
    fn record(&mut self, _rec: &visco_core::Record<f32>, _plant: &Plant) {
        self.taps.push(std::mem::take(&mut self.current));
    }
}

fn rel_std(v: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = v.clone().count() as f64;
    let mean = v.clone().sum::<f64>() / n;
    let var = v.map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    var.sqrt() / mean.abs()
}

/// Evaluate the candidates on a flat sample of the paper's mid-range element properties.
pub fn study(
    candidates: &[(f64, f64, [f64; 2])],
    sample_rate_hz: f64,
    seed: u64,
) -> Vec<Candidate> {
    let mut out = Vec::new();
    for &(f1, f2, tip) in candidates {
        let sample = Sample::flat(50, 50, 100e-9, [50e-9, 50e-9], 100e-9, 6e-7, 3.5e-3)
            .expect("flat sample");
        let mut setup = Setup::paper(sample, sample_rate_hz, seed);
        let c = &mut setup.config;
        c.dive.nx = 3;
        c.dive.ny = 1;
        c.dive.x0_m = 2.0e-6;
        c.dive.y0_m = 2.5e-6;
        c.dive.dx_m = 0.5e-6;
        let n = c.nominal_dive;
        let cant = c.cantilever;
        let base = |f: f64, a: f64| a / cant.tip_over_base(f, n.k_n_per_m, n.c_ns_per_m);
        c.dive.excitation.f1_hz = f1;
        c.dive.excitation.f2_hz = f2;
        c.dive.excitation.a1_m = base(f1, tip[0]);
        c.dive.excitation.a2_m = base(f2, tip[1]);
        // A fixed memory for all candidates, so the spreads compare information rates.
        c.dive.estimator.beta_per_s = 100.0;
        c.dive.readout_s = 60e-3;
        if setup.config.validate().is_err() {
            continue;
        }
        let mut ctrl = match Controller::<f32>::new(&setup.config) {
            Ok(c) => c,
            Err(_) => continue,
        };
        let Ok(mut plant) = setup.build_plant() else {
            continue;
        };
        let mut obs = Spread {
            dt: 1.0 / sample_rate_hz,
            ..Default::default()
        };
        run(&mut ctrl, &mut plant, Mode::Dive, 1.0, &mut obs, |_| {});
        let window = (60e-3 * sample_rate_hz) as usize;
        let (mut sc, mut sk, mut t1, mut m) = (0.0, 0.0, 0.0, 0.0);
        for tap in &obs.taps {
            if tap.len() < window {
                continue;
            }
            let last = &tap[tap.len() - window..];
            sc += rel_std(last.iter().map(|p| p.1));
            sk += rel_std(last.iter().map(|p| p.2));
            let kf = last.iter().map(|p| p.2).sum::<f64>() / window as f64;
            // The last time k̂ was more than 1 % from its final value.
            let t_out = tap
                .iter()
                .rev()
                .find(|p| (p.2 / kf - 1.0).abs() > 0.01)
                .map(|p| p.0)
                .unwrap_or(tap[0].0);
            t1 += t_out - tap[0].0;
            m += 1.0;
        }
        if m == 0.0 {
            continue;
        }
        // Predicted relative information per sample: θ²·Σ (ω·A)²/(2|Λ|²) for c, θ²·Σ A²/(2|Λ|²) for k.
        let lam = setup.config.prefilter.lambda_s;
        let info = |f: f64, a: f64| {
            let w = 2.0 * std::f64::consts::PI * f;
            let l2 = (1.0 + (lam * w).powi(2)).powi(2);
            ((w * a).powi(2) / (2.0 * l2), a * a / (2.0 * l2))
        };
        let (i1, i2) = (info(f1, tip[0]), info(f2, tip[1]));
        let (cn, kn) = (n.c_ns_per_m, n.k_n_per_m);
        out.push(Candidate {
            f1_hz: f1,
            f2_hz: f2,
            tip_amplitudes_m: tip,
            relative_spread: [sc / m, sk / m],
            time_to_1pct_s: t1 / m,
            predicted_information: [
                cn * cn * (i1.0 + i2.0) * 1e12,
                kn * kn * (i1.1 + i2.1) * 1e18,
            ],
        });
    }
    out
}

/// The candidates of the study: f₁ around resonance, f₂ from a sixteenth to half of it, the
/// paper's tip amplitudes (100 nm, 25 nm) and their swap.
pub fn candidates(f0_hz: f64) -> Vec<(f64, f64, [f64; 2])> {
    let mut v = Vec::new();
    for f1 in [0.5 * f0_hz, f0_hz, 1.5 * f0_hz] {
        for div in [16.0, 8.0, 4.0, 2.0] {
            let f2 = f0_hz / div;
            if (f2 - f1).abs() < 1.0 {
                continue;
            }
            for tip in [[100e-9, 25e-9], [25e-9, 100e-9]] {
                v.push((f1, f2, tip));
            }
        }
    }
    v
}
