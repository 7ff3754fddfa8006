//! The noise model and the tests built on it.
//!
//! A recording's noise is not white: the thermal force drives the cantilever, so at a high
//! sampling rate the deflection noise rings at the resonance (Q/π·f₀ samples of memory); a
//! detector adds white noise on top. The residual of a good fit is modelled as an
//! autoregressive process `r_t = −Σ_{j≤p} a_j r_{t−j} + ε_t` (Burg's method over the fit
//! samples, order by BIC), and every test uses the *whitened* residual ε, whose samples are
//! independent when the model is right. Then:
//!
//! * [`held_out_test`]: does an extension, fitted on the fit samples, explain the held-out
//!   samples better than the model it extends? With ε₀ and ε₁ the whitened held-out residuals
//!   of the two and w = ε₀ − ε₁ (the extension's whitened contribution, fixed by the fit
//!   samples), the held-out log-likelihood ratio is `Σ(ε₀² − ε₁²)/2σ² = (Σε₀·w − ½Σw²)/σ²`.
//!   Without the effect ε₀ is white noise independent of w, so `z = (Σε₀w − ½Σw²)/(σ‖w‖)` is
//!   N(−‖w‖/2σ, 1): `P(z > z_α) ≤ α` whatever the extension — a one-sided test at a stated
//!   false-alarm rate, and conservative.
//! * [`diebold_mariano`]: the same question where the residuals are dominated by misfit, not
//!   noise (real recordings before their large effects are modelled): there a noise model
//!   fitted to the residual describes the misfit, and whitening with it can turn a far
//!   better fit into a worse one (its inverse differentiates, and blows up any sharp
//!   residual). The mean held-out gain in squared residual is tested with a
//!   heteroscedasticity- and autocorrelation-consistent variance, no noise model needed.
//! * [`normal_sf`], [`chi2_sf`]: the tails the locating tests need.

use statrs::distribution::{ChiSquared, ContinuousCDF};
use statrs::function::erf::erfc_inv;

/// Autoregressive noise model: prediction-error filter `ε_t = r_t + Σ a_j r_{t−j}`.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// Filter coefficients a₁…a_p.
    pub a: Vec<f64>,
    /// Innovation σ (the whitened residual's).
    pub sigma: f64,
    /// σ of the residual itself.
    pub raw_sigma: f64,
}

/// Largest AR order tried.
pub const MAX_ORDER: usize = 16;

impl NoiseModel {
    /// White noise of σ.
    pub fn white(sigma: f64) -> Self {
        NoiseModel {
            a: Vec::new(),
            sigma,
            raw_sigma: sigma,
        }
    }

    /// Burg's method on the runs of `r` where `mask` holds (each run a separate stretch of
    /// one process), order 0…`max_order` by BIC. Runs shorter than the order are skipped.
    pub fn fit(r: &[f64], mask: &[bool], max_order: usize) -> Self {
        let runs = runs(mask);
        let n_total: usize = runs.iter().map(|(a, b)| b - a).sum();
        let mean = if n_total > 0 {
            runs.iter().flat_map(|&(a, b)| r[a..b].iter()).sum::<f64>() / n_total as f64
        } else {
            0.0
        };
        let raw_var = if n_total > 0 {
            runs.iter()
                .flat_map(|&(a, b)| r[a..b].iter())
                .map(|x| (x - mean) * (x - mean))
                .sum::<f64>()
                / n_total as f64
        } else {
            0.0
        };
        if n_total < 8 || !(raw_var > 0.0) {
            return NoiseModel::white(raw_var.sqrt());
        }
        // Forward and backward errors per run.
        let mut f: Vec<Vec<f64>> = runs
            .iter()
            .map(|&(a, b)| r[a..b].iter().map(|x| x - mean).collect())
            .collect();
        let mut bk = f.clone();
        let mut a: Vec<f64> = Vec::new();
        let mut var = raw_var;
        let nf = n_total as f64;
        let mut best = (nf * var.ln(), Vec::new(), var);
        let max_order = max_order.min(n_total / 4);
        for m in 1..=max_order {
            // Reflection coefficient over all runs: errors at t ≥ m.
            let (mut num, mut den) = (0.0, 0.0);
            for (fr, br) in f.iter().zip(&bk) {
                let len = fr.len();
                if len <= m {
                    continue;
                }
                for t in m..len {
                    num += fr[t] * br[t - 1];
                    den += fr[t] * fr[t] + br[t - 1] * br[t - 1];
                }
            }
            if !(den > 0.0) {
                break;
            }
            let k = -2.0 * num / den;
            if !(k.abs() < 1.0) {
                break;
            }
            // Levinson update of the filter.
            let prev = a.clone();
            a.push(k);
            for j in 0..m - 1 {
                a[j] = prev[j] + k * prev[m - 2 - j];
            }
            var *= 1.0 - k * k;
            // Update the errors (from the top down, using the old values).
            for (fr, br) in f.iter_mut().zip(bk.iter_mut()) {
                let len = fr.len();
                if len <= m {
                    continue;
                }
                for t in (m..len).rev() {
                    let ft = fr[t] + k * br[t - 1];
                    let bt = br[t - 1] + k * fr[t];
                    fr[t] = ft;
                    br[t] = bt;
                }
            }
            let bic = nf * var.ln() + m as f64 * nf.ln();
            if bic < best.0 {
                best = (bic, a.clone(), var);
            }
        }
        NoiseModel {
            a: best.1,
            sigma: best.2.sqrt(),
            raw_sigma: raw_var.sqrt(),
        }
    }

    /// The whitened series `ε_t = r_t + Σ a_j r_{t−j}` (the first p samples use what exists).
    pub fn whiten(&self, r: &[f64]) -> Vec<f64> {
        let p = self.a.len();
        (0..r.len())
            .map(|t| {
                let mut e = r[t];
                for j in 1..=p.min(t) {
                    e += self.a[j - 1] * r[t - j];
                }
                e
            })
            .collect()
    }

    /// Power spectral density of the model relative to white noise of the same innovation σ,
    /// `1/|A(e^{iω})|²`, at the normalised frequency `f` (cycles per sample).
    pub fn shape(&self, f: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * f;
        let (mut re, mut im) = (1.0, 0.0);
        for (j, a) in self.a.iter().enumerate() {
            let ph = w * (j + 1) as f64;
            re += a * ph.cos();
            im -= a * ph.sin();
        }
        1.0 / (re * re + im * im).max(1e-300)
    }
}

/// Half-open runs `[a, b)` where `mask` is true.
pub fn runs(mask: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < mask.len() {
        if mask[i] {
            let s = i;
            while i < mask.len() && mask[i] {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

/// The held-out comparison of a model and its extension (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldOut {
    /// The standardised log-likelihood ratio z.
    pub z: f64,
    /// One-sided p-value of z.
    pub p_value: f64,
    /// Held-out log-likelihood gain `Σ(ε₀² − ε₁²)/2σ²`.
    pub loglik_gain: f64,
    /// `‖w‖/σ`: the extension's whitened size on the held-out samples.
    pub effect_size: f64,
    /// Samples compared.
    pub n: usize,
}

/// Compares whitened held-out residuals `e0` (model) and `e1` (extension) where `mask` holds,
/// with innovation σ.
pub fn held_out_test(e0: &[f64], e1: &[f64], mask: &[bool], sigma: f64) -> HeldOut {
    let (mut gain, mut ww, mut n) = (0.0, 0.0, 0usize);
    for i in 0..e0.len() {
        if mask[i] {
            gain += 0.5 * (e0[i] * e0[i] - e1[i] * e1[i]);
            let w = e0[i] - e1[i];
            ww += w * w;
            n += 1;
        }
    }
    let s2 = sigma * sigma;
    let norm = sigma * ww.sqrt();
    let z = if norm > 0.0 { gain / norm } else { 0.0 };
    HeldOut {
        z,
        p_value: normal_sf(z),
        loglik_gain: gain / s2,
        effect_size: ww.sqrt() / sigma,
        n,
    }
}

/// The Diebold–Mariano comparison of held-out predictive accuracy, for residuals dominated by
/// misfit rather than noise (where no noise model describes them): the per-sample gains
/// `g_i = (r0_i² − r1_i²)/2` over the held-out samples, their mean tested against zero with a
/// heteroscedasticity- and autocorrelation-consistent variance (Bartlett kernel, `lags`).
/// One-sided; for nested models it is conservative.
pub fn diebold_mariano(r0: &[f64], r1: &[f64], mask: &[bool], lags: usize) -> HeldOut {
    let g: Vec<f64> = (0..r0.len())
        .filter(|&i| mask[i])
        .map(|i| 0.5 * (r0[i] * r0[i] - r1[i] * r1[i]))
        .collect();
    let n = g.len();
    if n < 2 {
        return HeldOut {
            z: 0.0,
            p_value: 1.0,
            loglik_gain: 0.0,
            effect_size: 0.0,
            n,
        };
    }
    let mean = g.iter().sum::<f64>() / n as f64;
    let dev: Vec<f64> = g.iter().map(|x| x - mean).collect();
    let mut var = dev.iter().map(|x| x * x).sum::<f64>() / n as f64;
    for l in 1..=lags.min(n - 1) {
        let c = (l..n).map(|i| dev[i] * dev[i - l]).sum::<f64>() / n as f64;
        var += 2.0 * (1.0 - l as f64 / (lags + 1) as f64) * c;
    }
    let se = (var.max(0.0) / n as f64).sqrt();
    let z = if se > 0.0 { mean / se } else { 0.0 };
    let s0: f64 = (0..r0.len())
        .filter(|&i| mask[i])
        .map(|i| r0[i] * r0[i])
        .sum();
    let s1: f64 = (0..r1.len())
        .filter(|&i| mask[i])
        .map(|i| r1[i] * r1[i])
        .sum();
    HeldOut {
        z,
        p_value: normal_sf(z),
        // Gaussian log-likelihood gain with the variance profiled out.
        loglik_gain: 0.5 * n as f64 * (s0 / s1.max(1e-300)).ln(),
        effect_size: (s0 - s1).abs().sqrt(),
        n,
    }
}

/// Upper tail of the standard normal, `P(Z > z) = erfc(z/√2)/2` (not `1 − Φ(z)`, so a tiny
/// p-value keeps its relative precision). libm's erfc (FreeBSD's, within an ulp or two), not
/// statrs's: statrs (0.18 and 0.19.1) keeps Boost's interval constants to 10 digits, which
/// costs ~1e-10 relative (1.6e-11 at z = −1), more than the tests below allow.
pub fn normal_sf(z: f64) -> f64 {
    0.5 * libm::erfc(z * std::f64::consts::FRAC_1_SQRT_2)
}

/// The z with `P(Z > z) = p` (`√2·erfc⁻¹(2p)`: no `1 − p`, so it holds in the far tail).
pub fn normal_isf(p: f64) -> f64 {
    std::f64::consts::SQRT_2 * erfc_inv(2.0 * p)
}

/// Upper tail of the χ² distribution with `k` degrees of freedom, `P(X > x)`. A statistic
/// that is not positive (or is NaN), or a test with no degrees of freedom, is no evidence: 1.
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    if !(x > 0.0) {
        return 1.0;
    }
    match ChiSquared::new(k) {
        Ok(d) => d.sf(x),
        Err(_) => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::rng::NormalRng;

    /// The tails against scipy 1.17.1 (`scipy.stats.norm.sf`, `norm.isf`, `chi2.sf`, printed
    /// with `%.17e`; the oracle, statrs is under test), to 1e-12 relative: far beyond what a
    /// test at α = 0.01 needs, and what the single-precision erfc this replaced (1.2e-7)
    /// could not meet. They span the centre, both tails and the far tail to 1e-89, and χ²
    /// from 1 to 900 degrees of freedom on both sides of the mean.
    #[test]
    #[allow(clippy::excessive_precision)] // scipy's values as printed, digit for digit
    fn tails_match_scipy() {
        #[rustfmt::skip]
        const NORMAL_SF: &[(f64, f64)] = &[
            (-3.0, 9.98650101968369897e-01),
            (-1.0, 8.41344746068542926e-01),
            (0.0, 5.00000000000000000e-01),
            (0.5, 3.08537538725986882e-01),
            (1.0, 1.58655253931457074e-01),
            (1.959963984540054, 2.50000000000000014e-02),
            (3.0, 1.34989803163009328e-03),
            (5.0, 2.86651571879193277e-07),
            (8.0, 6.22096057427174049e-16),
            (10.0, 7.61985302416046961e-24),
            (20.0, 2.75362411860615560e-89),
        ];
        #[rustfmt::skip]
        const NORMAL_ISF: &[(f64, f64)] = &[
            (0.05, 1.64485362695147286e+00),
            (1e-3, 3.09023230616781319e+00),
            (1e-10, 6.36134090240405570e+00),
            (1e-100, 2.12734535609653221e+01),
            (0.9, -1.28155156554460037e+00),
        ];
        #[rustfmt::skip]
        const CHI2_SF: &[(f64, f64, f64)] = &[
            (3.841458820694124, 1.0, 4.99999999999998918e-02),
            (0.5, 1.0, 4.79500122186953370e-01),
            (18.307038053275146, 10.0, 5.00000000000000513e-02),
            (124.342, 100.0, 5.00007157699717819e-02),
            (1000.0, 900.0, 1.09946089421358445e-02),
            (5.0, 3.0, 1.71797144296733512e-01),
            (0.1, 4.0, 9.98790895725749750e-01),
            (50.0, 2.0, 1.38879438649639999e-11),
            (200.0, 50.0, 7.85761072465479138e-20),
            (2.0, 2.0, 3.67879441171442445e-01),
            (30.0, 5.0, 1.47485810384430725e-05),
        ];
        let rel = |got: f64, want: f64| ((got - want) / want).abs();
        let mut off = Vec::new();
        for &(z, p) in NORMAL_SF {
            let got = normal_sf(z);
            if !(rel(got, p) < 1e-12) {
                off.push(format!("normal_sf({z}) = {got:e}, scipy {p:e}"));
            }
        }
        for &(p, z) in NORMAL_ISF {
            let got = normal_isf(p);
            if !(rel(got, z) < 1e-12) {
                off.push(format!("normal_isf({p}) = {got:e}, scipy {z:e}"));
            }
        }
        for &(x, k, p) in CHI2_SF {
            let got = chi2_sf(x, k);
            if !(rel(got, p) < 1e-12) {
                off.push(format!("chi2_sf({x}, {k}) = {got:e}, scipy {p:e}"));
            }
        }
        assert!(off.is_empty(), "{off:#?}");
        assert_eq!(normal_isf(0.5), 0.0);
        // No statistic or no degrees of freedom: no evidence, and no panic.
        assert_eq!(chi2_sf(0.0, 3.0), 1.0);
        assert_eq!(chi2_sf(f64::NAN, 3.0), 1.0);
        assert_eq!(chi2_sf(5.0, 0.0), 1.0);
        assert_eq!(chi2_sf(f64::INFINITY, 3.0), 0.0);
    }

    /// Burg recovers an AR(2) with a sharp resonance (a high-Q cantilever's noise sampled fast)
    /// and whitens it.
    #[test]
    fn burg_recovers_a_resonant_ar2() {
        let mut rng = NormalRng::new(3);
        let (f, r) = (0.04, 0.995); // pole radius and frequency (cycles/sample)
        let a1 = -2.0 * r * (2.0 * std::f64::consts::PI * f).cos();
        let a2 = r * r;
        let n = 100_000;
        let mut x = vec![0.0; n];
        for t in 2..n {
            x[t] = -a1 * x[t - 1] - a2 * x[t - 2] + rng.normal();
        }
        let mask = vec![true; n];
        let m = NoiseModel::fit(&x, &mask, MAX_ORDER);
        assert!(m.a.len() >= 2);
        assert!((m.a[0] - a1).abs() < 0.01, "{:?}", m.a);
        assert!((m.a[1] - a2).abs() < 0.01, "{:?}", m.a);
        assert!((m.sigma - 1.0).abs() < 0.02, "{}", m.sigma);
        let e = m.whiten(&x);
        // Lag-1..5 autocorrelation of the whitened series within ±4/√n.
        let var: f64 = e.iter().map(|v| v * v).sum::<f64>() / n as f64;
        for lag in 1..=5 {
            let c: f64 = (lag..n).map(|t| e[t] * e[t - lag]).sum::<f64>() / n as f64 / var;
            assert!(c.abs() < 4.0 / (n as f64).sqrt(), "lag {lag}: {c}");
        }
    }

    /// On pure noise the held-out test's z exceeds z_α no more often than α (it is
    /// conservative): 2000 trials of an extension fitted to the other half's noise.
    #[test]
    fn held_out_test_keeps_its_false_alarm_rate() {
        let mut rng = NormalRng::new(11);
        let n = 400;
        let mut alarms = 0;
        let trials = 2000;
        let mask: Vec<bool> = (0..n).map(|i| (i / 20) % 2 == 1).collect();
        for _ in 0..trials {
            let e0: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
            // An "extension": a step fitted (least squares) to the fit half's noise.
            let (mut s, mut c) = (0.0, 0);
            for i in n / 2..n {
                if !mask[i] {
                    s += e0[i];
                    c += 1;
                }
            }
            let level = s / c as f64;
            let e1: Vec<f64> = (0..n)
                .map(|i| if i >= n / 2 { e0[i] - level } else { e0[i] })
                .collect();
            let t = held_out_test(&e0, &e1, &mask, 1.0);
            if t.p_value < 0.05 {
                alarms += 1;
            }
        }
        let rate = alarms as f64 / trials as f64;
        assert!(rate <= 0.05, "false-alarm rate {rate}");
        // And not absurdly conservative for a fitted effect of this size.
        assert!(rate > 0.001, "false-alarm rate {rate}");
    }
}
