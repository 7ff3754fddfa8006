//! The free deflection of a force curve, `D₀(U)`: an offset, a linear tilt and, when the free
//! approach shows one, an optical-interference wave.
//!
//! ## The interference wave
//! Laser light that spills past the lever reflects off the sample and interferes with the
//! lever's own reflection on the photodiode. The path difference changes by twice the lever's
//! height, so the free deflection carries a sinusoid in the lever's height of period λ/2
//! (0.3–0.4 µm for the 0.6–0.85 µm lasers of AFM heads, longer when the beam is inclined).
//! It is modelled as a sinusoid in the lever's height `U − D` (D the deflection from the free
//! level): fitted as `a·cos(2π(U − U_ref)/P) + b·sin(2π(U − U_ref)/P)` on the free part, where D
//! stays at its free level, and evaluated at `U − D` elsewhere. In contact the two differ by the
//! deflection: a 30 nm deflection under a 320 nm period moves the wave's phase by 0.6 rad, which
//! on refsim's curves (it puts the wave in U − D) left 0.15 nm of misfit when the wave was
//! evaluated at U.
//!
//! A wave is kept only when the free part shows it beyond doubt, so that nothing else is
//! absorbed by it:
//! - **Seen**: the period lies between 10 rows (resolved) and 2/3 of the free part's travel
//!   (at least 1.5 periods, so a tilt or a bend is not a wave).
//! - **Significant**: the drop of the residual sum of squares passes the periodogram's
//!   false-alarm level `2·S(ω)·ln(M/α)` over the `M` independent periods searched,
//!   α = 10⁻³ (Schuster's test), with S(ω) the noise power at the wave's frequency of an AR(1)
//!   model of the residual (an instrument's deflection noise is rarely white).
//! - **Worth a model**: its amplitude is at least the noise σ left about it.
//! - **Stationary**: fitted separately on the two halves of the free part at the same period,
//!   the two waves agree to within half the amplitude plus three standard errors. Interference
//!   is periodic in U with a slowly changing amplitude; a force that grows towards the surface
//!   (surface attraction, a soft layer), a drift or low-frequency noise that happens to fit a
//!   sinusoid do not repeat from one half to the other.

use std::ops::Range;

use nalgebra::{DMatrix, DVector};

use super::signal::{minimize, robust_sigma};

/// An interference wave in the free deflection.
#[derive(Clone, Debug, PartialEq)]
pub struct Wave {
    /// Amplitude (m of D).
    pub amplitude_m: f64,
    /// Period in U (m).
    pub period_m: f64,
    /// Phase at `u_ref` (rad): the wave is `amplitude·sin(2π(U − u_ref)/period + phase)`.
    pub phase_rad: f64,
    /// The false-alarm level the fit's sum-of-squares drop passed, as their ratio (> 1).
    pub significance: f64,
    /// The two halves' amplitudes (m), fitted separately at the same period.
    pub halves_m: [f64; 2],
}

/// The free deflection `D₀(U) = offset + tilt·(U − u_ref) [+ wave]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Baseline {
    /// D₀ at `u_ref` (m), without the wave.
    pub offset_m: f64,
    /// dD₀/dU (dimensionless); 0 when only an offset was fitted.
    pub tilt: f64,
    /// Reference base position (m): the end of the free part.
    pub u_ref_m: f64,
    /// Whether a tilt was fitted (the free part long enough).
    pub linear: bool,
    /// The interference wave, when the free part shows one (see the module docs).
    pub wave: Option<Wave>,
    /// Robust σ of the free deflection about the baseline (m).
    pub noise_m: f64,
    /// Rows of the free part used.
    pub free_rows: Range<usize>,
}

impl Baseline {
    /// Offset and tilt at base position `u` (no wave).
    pub fn line_at(&self, u: f64) -> f64 {
        self.offset_m + self.tilt * (u - self.u_ref_m)
    }

    /// D₀ at base position `u` for a lever deflected `deflection` from its free level: the
    /// line in U, and the wave at the lever's height `U − deflection`.
    pub fn at(&self, u: f64, deflection: f64) -> f64 {
        self.line_at(u) + self.wave_at(u - deflection)
    }

    /// D₀ under a recorded deflection `d` at base position `u`. The lever's deflection is
    /// `d − D₀`, and D₀ depends on it through the wave, so this solves
    /// `w = wave(U − (d − line − w))` by fixed-point iteration: a contraction by 2π·A/P per step
    /// (0.25 for a 16 nm wave of 400 nm period), converged to 10⁻¹⁵ m in a few steps.
    pub fn under(&self, u: f64, d: f64) -> f64 {
        let line = self.line_at(u);
        let mut w = 0.0;
        if self.wave.is_some() {
            for _ in 0..50 {
                let next = self.wave_at(u - (d - line - w));
                let done = (next - w).abs() <= 1e-15;
                w = next;
                if done {
                    break;
                }
            }
        }
        line + w
    }

    /// The wave's part of D₀ at lever height `x` (0 without one).
    pub fn wave_at(&self, x: f64) -> f64 {
        self.wave.as_ref().map_or(0.0, |w| {
            w.amplitude_m
                * (std::f64::consts::TAU * (x - self.u_ref_m) / w.period_m + w.phase_rad).sin()
        })
    }

    /// What was fitted, in words (the report's `kind`).
    pub fn describe(&self) -> &'static str {
        match (self.linear, self.wave.is_some()) {
            (true, true) => "offset + linear tilt in U + interference wave in U",
            (true, false) => "offset + linear tilt in U",
            (false, _) => "offset",
        }
    }
}

/// Rows a free part needs for a tilt.
const MIN_ROWS_TILT: usize = 50;
/// Rows a free part needs before a wave is looked for.
const MIN_ROWS_WAVE: usize = 100;
/// Shortest period searched, in rows: a sinusoid needs this many samples per period to be told
/// from noise that happens to alternate.
const MIN_ROWS_PER_PERIOD: f64 = 10.0;
/// Periods the free part must span at least.
const MIN_PERIODS: f64 = 1.5;
/// Most periods searched in the free part's travel.
const MAX_PERIODS: f64 = 100.0;
/// False-alarm probability of the wave's significance test.
const WAVE_ALPHA: f64 = 1e-3;

/// Least-squares offset and tilt (when the free part spans enough rows) of D against U, and an
/// interference wave when the free part shows one.
pub fn fit_baseline(u: &[f64], d: &[f64], rows: Range<usize>) -> Baseline {
    let uu = &u[rows.clone()];
    let dd = &d[rows.clone()];
    let u_ref = *uu.last().unwrap_or(&0.0);
    let linear = uu.len() >= MIN_ROWS_TILT;
    let line = if linear {
        solve(&design(uu, u_ref, None, false), dd, false)
    } else {
        None
    };
    let (offset, tilt, resid) = match line {
        Some(f) => (f.coef[0], f.coef[1] / scale(uu, u_ref), f.resid),
        None => {
            let m = dd.iter().sum::<f64>() / (dd.len() as f64).max(1.0);
            (m, 0.0, dd.iter().map(|y| y - m).collect())
        }
    };
    let mut b = Baseline {
        offset_m: offset,
        tilt,
        u_ref_m: u_ref,
        linear,
        wave: None,
        noise_m: robust_sigma(&resid),
        free_rows: rows,
    };
    if linear {
        if let Some((wave, offset, tilt, resid)) = fit_wave(uu, dd, u_ref, &resid) {
            b.offset_m = offset;
            b.tilt = tilt;
            b.wave = Some(wave);
            b.noise_m = robust_sigma(&resid);
        }
    }
    b
}

/// A least-squares fit: coefficients and residuals.
struct Fit {
    coef: Vec<f64>,
    resid: Vec<f64>,
    /// (XᵀX)⁻¹ (for standard errors), when asked for.
    cov_unit: Option<DMatrix<f64>>,
}

impl Fit {
    fn ssr(&self) -> f64 {
        self.resid.iter().map(|r| r * r).sum()
    }
}

/// The scale of U − u_ref over the rows, so that the tilt's column is O(1).
fn scale(uu: &[f64], u_ref: f64) -> f64 {
    uu.iter()
        .map(|x| (x - u_ref).abs())
        .fold(0.0, f64::max)
        .max(1e-300)
}

/// Columns: 1, (U − u_ref)/scale and, with a period, its cosine and sine (`split`: one pair
/// for each half of the rows).
fn design(uu: &[f64], u_ref: f64, period: Option<f64>, split: bool) -> DMatrix<f64> {
    let n = uu.len();
    let s = scale(uu, u_ref);
    let cols = match (period, split) {
        (None, _) => 2,
        (Some(_), false) => 4,
        (Some(_), true) => 6,
    };
    DMatrix::from_fn(n, cols, |i, j| {
        let x = uu[i] - u_ref;
        match j {
            0 => 1.0,
            1 => x / s,
            _ => {
                let half = usize::from(split && 2 * i >= n);
                let pair = (j - 2) / 2;
                if pair != half {
                    return 0.0;
                }
                let ph = std::f64::consts::TAU * x / period.unwrap_or(1.0);
                if (j - 2) % 2 == 0 {
                    ph.cos()
                } else {
                    ph.sin()
                }
            }
        }
    })
}

/// Least squares by Householder QR (nalgebra); `None` when the columns are dependent.
/// `with_cov`: also (XᵀX)⁻¹, which only the halves' test needs (not the period search).
fn solve(x: &DMatrix<f64>, y: &[f64], with_cov: bool) -> Option<Fit> {
    let (n, p) = x.shape();
    if n <= p {
        return None;
    }
    let qr = x.clone().qr();
    let mut qty = DVector::from_column_slice(y);
    qr.q_tr_mul(&mut qty);
    let r = qr.r();
    let coef = r.solve_upper_triangular(&qty.rows(0, p))?;
    let fitted = x * &coef;
    let resid = y.iter().zip(fitted.iter()).map(|(a, b)| a - b).collect();
    let cov_unit = if with_cov {
        r.try_inverse().map(|ri| &ri * ri.transpose())
    } else {
        None
    };
    Some(Fit {
        coef: coef.iter().copied().collect(),
        resid,
        cov_unit,
    })
}

/// The wave, the offset and tilt fitted with it and the residuals, when the free part shows
/// a wave (see the module docs); `resid_line` are the residuals of the line alone.
fn fit_wave(
    uu: &[f64],
    dd: &[f64],
    u_ref: f64,
    resid_line: &[f64],
) -> Option<(Wave, f64, f64, Vec<f64>)> {
    let n = uu.len();
    if n < MIN_ROWS_WAVE {
        return None;
    }
    let travel = uu.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - uu.iter().copied().fold(f64::INFINITY, f64::min);
    let step = travel / (n - 1) as f64;
    // At most MAX_PERIODS periods in the travel: interference periods are ≥ 0.2 µm, and a long
    // approach sampled finely need not be searched at every resolvable period.
    let (p_min, p_max) = (
        (MIN_ROWS_PER_PERIOD * step).max(travel / MAX_PERIODS),
        travel / MIN_PERIODS,
    );
    if !(travel > 0.0 && p_max > p_min) {
        return None;
    }
    // Search the spatial frequency (periodogram-like: independent frequencies are 1/travel
    // apart), four grid points per independent frequency, then golden section.
    let (f_lo, f_hi) = (1.0 / p_max, 1.0 / p_min);
    let independent = ((f_hi - f_lo) * travel).max(1.0);
    let grid = (4.0 * independent).ceil() as usize;
    let ssr_at = |f: f64| {
        solve(&design(uu, u_ref, Some(1.0 / f), false), dd, false)
            .map_or(f64::INFINITY, |x| x.ssr())
    };
    let f_best = minimize(ssr_at, f_lo, f_hi, grid.max(8));
    let period = 1.0 / f_best;
    let fit = solve(&design(uu, u_ref, Some(period), false), dd, false)?;
    let ssr_line: f64 = resid_line.iter().map(|r| r * r).sum();
    let ssr = fit.ssr();
    let var = ssr / (n - 4) as f64;
    // Schuster: at one frequency the drop is σ²·χ²₂ under white noise; the largest of M
    // independent ones passes 2σ²·ln(M/α) with probability α.
    // The deflection noise of real instruments is not white (drift, 1/f, the detector's
    // filter): with the residual's lag-1 correlation ρ, an AR(1) noise has, at the wave's
    // frequency ω (rad per row), g(ω) = (1 − ρ²)/(1 − 2ρ·cos ω + ρ²) times the white power.
    let rho = lag1(&fit.resid).clamp(0.0, 0.99);
    let omega = std::f64::consts::TAU * step / period;
    let colour = (1.0 - rho * rho) / (1.0 - 2.0 * rho * omega.cos() + rho * rho);
    let level = 2.0 * var * colour * (independent / WAVE_ALPHA).ln();
    let significance = (ssr_line - ssr) / level;
    if !(significance > 1.0) {
        return None;
    }
    // Worth a model: a wave below the noise moves the force's zero by less than the noise
    // itself, and slow instrument noise (drift, 1/f) fits such small sinusoids at long periods.
    let amp = (fit.coef[2].powi(2) + fit.coef[3].powi(2)).sqrt();
    if !(amp >= robust_sigma(&fit.resid)) {
        return None;
    }
    // Stationary: the halves' waves at the same period, with their standard errors.
    let halves = solve(&design(uu, u_ref, Some(period), true), dd, true)?;
    let cov = halves.cov_unit.as_ref()?;
    let var_h = halves.ssr() / (n - 6) as f64;
    let (w1, w2) = (
        [halves.coef[2], halves.coef[3]],
        [halves.coef[4], halves.coef[5]],
    );
    let diff = ((w1[0] - w2[0]).powi(2) + (w1[1] - w2[1]).powi(2)).sqrt();
    // SE of the difference's length: the variances of both halves' pairs (independent rows).
    let se_diff =
        (var_h * colour * (cov[(2, 2)] + cov[(3, 3)] + cov[(4, 4)] + cov[(5, 5)]) / 2.0).sqrt();
    if !(diff <= 0.5 * amp + 3.0 * se_diff) {
        return None;
    }
    let norm = |w: [f64; 2]| (w[0] * w[0] + w[1] * w[1]).sqrt();
    // a·cos φ + b·sin φ = A·sin(φ + ψ) with A = √(a² + b²), ψ = atan2(a, b).
    let wave = Wave {
        amplitude_m: amp,
        period_m: period,
        phase_rad: fit.coef[2].atan2(fit.coef[3]),
        significance,
        halves_m: [norm(w1), norm(w2)],
    };
    Some((wave, fit.coef[0], fit.coef[1] / scale(uu, u_ref), fit.resid))
}

/// Lag-1 autocorrelation of `r` (0 for fewer than 3 values or no variance).
fn lag1(r: &[f64]) -> f64 {
    if r.len() < 3 {
        return 0.0;
    }
    let m = r.iter().sum::<f64>() / r.len() as f64;
    let var: f64 = r.iter().map(|x| (x - m) * (x - m)).sum();
    let cov: f64 = r.windows(2).map(|w| (w[0] - m) * (w[1] - m)).sum();
    if var > 0.0 {
        cov / var
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A free approach: 1 nm steps from 1 µm down, with a tilt, noise from a fixed LCG.
    fn approach(n: usize, wave: impl Fn(f64) -> f64, noise: f64) -> (Vec<f64>, Vec<f64>) {
        let mut s = 12345u64;
        let mut rnd = || {
            // Sum of 12 uniforms − 6: unit variance, close enough to normal for these tests.
            (0..12)
                .map(|_| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (s >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        };
        let u: Vec<f64> = (0..n).map(|i| 1e-6 - i as f64 * 1e-9).collect();
        let d: Vec<f64> = u
            .iter()
            .map(|&x| 2e-9 + 1e-3 * x + wave(x) + noise * rnd())
            .collect();
        (u, d)
    }

    #[test]
    fn a_wave_beyond_the_noise_is_found_with_its_period_and_amplitude() {
        let (a, p) = (0.03e-9, 320e-9);
        let (u, d) = approach(
            900,
            |x| a * (std::f64::consts::TAU * x / p + 0.3).sin(),
            0.01e-9,
        );
        let b = fit_baseline(&u, &d, 0..900);
        let w = b.wave.as_ref().expect("a wave at 3× the noise");
        // Over 2.8 periods of 900 rows at σ = 0.01 nm the amplitude's SE is σ·√(2/n) ≈ 0.5 pm
        // and the period's ~0.1 %: allow 5 %.
        assert!((w.amplitude_m / a - 1.0).abs() < 0.05, "{w:?}");
        assert!((w.period_m / p - 1.0).abs() < 0.01, "{w:?}");
        assert!((b.tilt / 1e-3 - 1.0).abs() < 0.01, "tilt {}", b.tilt);
        // The noise is the noise once the wave is out.
        assert!(
            (b.noise_m / 0.01e-9 - 1.0).abs() < 0.15,
            "noise {}",
            b.noise_m
        );
        // The model reproduces the wave where it was not fitted (beyond the free part).
        let x = u[899] - 150e-9;
        let want = 2e-9 + 1e-3 * x + a * (std::f64::consts::TAU * x / p + 0.3).sin();
        assert!(
            (b.at(x, 0.0) - want).abs() < 0.1 * a,
            "{} vs {want}",
            b.at(x, 0.0)
        );
    }

    #[test]
    fn noise_alone_gives_no_wave() {
        for seed_shift in 0..5 {
            let (u, d) = approach(600 + 100 * seed_shift, |_| 0.0, 0.01e-9);
            let b = fit_baseline(&u, &d, 0..u.len());
            assert!(b.wave.is_none(), "{:?}", b.wave);
        }
    }

    #[test]
    fn slow_correlated_noise_gives_no_wave() {
        // AR(1) noise with ρ = 0.98 (a detector's drift and 1/f): it wanders like a sinusoid
        // of long period, which a white-noise test would take for one.
        for seed in 0..5u64 {
            let mut s = 99 + seed;
            let mut e = 0.0f64;
            let (u, mut d) = approach(2000, |_| 0.0, 0.0);
            for x in d.iter_mut() {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let w = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                e = 0.98 * e + 0.05e-9 * w;
                *x += e;
            }
            let b = fit_baseline(&u, &d, 0..u.len());
            assert!(b.wave.is_none(), "seed {seed}: {:?}", b.wave);
        }
    }

    #[test]
    fn a_force_growing_towards_the_surface_is_not_a_wave() {
        // Surface attraction: an exponential rise over the last 150 nm of the free part, 10× the
        // noise at its end. It is not periodic, so the halves disagree.
        let (u, d) = approach(900, |x| -0.1e-9 * (-(x - 0.1e-6) / 150e-9).exp(), 0.01e-9);
        let b = fit_baseline(&u, &d, 0..900);
        assert!(b.wave.is_none(), "{:?}", b.wave);
    }

    #[test]
    fn a_period_longer_than_two_thirds_of_the_free_travel_is_left_to_the_tilt() {
        let (u, d) = approach(
            300,
            |x| 0.05e-9 * (std::f64::consts::TAU * x / 400e-9).sin(),
            0.01e-9,
        );
        let b = fit_baseline(&u, &d, 0..300);
        assert!(b.wave.is_none(), "{:?}", b.wave);
    }
}
