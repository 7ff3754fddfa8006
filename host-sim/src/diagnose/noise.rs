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

/// Upper tail of the standard normal, `P(Z > z)`, accurate in the far tail.
pub fn normal_sf(z: f64) -> f64 {
    0.5 * erfc(z / std::f64::consts::SQRT_2)
}

/// The z with `P(Z > z) = p`.
pub fn normal_isf(p: f64) -> f64 {
    // Bisection on the monotone tail: robust, and called rarely.
    let (mut lo, mut hi) = (-40.0, 40.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if normal_sf(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Complementary error function (Chebyshev fit of Numerical Recipes' `erfcc`, relative
/// error below 1.2e-7 everywhere, tails included).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let ans = t
        * (-z * z - 1.26551223
            + t * (1.00002368
                + t * (0.37409196
                    + t * (0.09678418
                        + t * (-0.18628806
                            + t * (0.27886807
                                + t * (-1.13520398
                                    + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277)))))))))
            .exp();
    if x >= 0.0 {
        ans
    } else {
        2.0 - ans
    }
}

/// ln Γ(x), x > 0 (Lanczos, 15 digits).
pub fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Upper tail of the χ² distribution with `k` degrees of freedom, `P(X > x)`.
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    if !(x > 0.0) {
        return 1.0;
    }
    gamma_q(0.5 * k, 0.5 * x)
}

/// Regularised upper incomplete gamma Q(a, x) (series or continued fraction).
fn gamma_q(a: f64, x: f64) -> f64 {
    let gln = ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        (1.0 - sum * (-x + a * x.ln() - gln).exp()).max(0.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        ((-x + a * x.ln() - gln).exp() * h).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::rng::NormalRng;

    #[test]
    fn tails() {
        assert!((normal_sf(0.0) - 0.5).abs() < 1e-7);
        assert!((normal_sf(1.959964) - 0.025).abs() < 1e-6);
        assert!((normal_sf(3.090232) - 0.001).abs() < 1e-7);
        // Far tail, relative.
        let p = normal_sf(10.0);
        assert!((p / 7.619853e-24 - 1.0).abs() < 1e-5, "{p}");
        assert!((normal_isf(0.001) - 3.090232).abs() < 1e-5);
        assert!((chi2_sf(3.841459, 1.0) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(18.307038, 10.0) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(124.342, 100.0) - 0.05).abs() < 1e-4);
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
