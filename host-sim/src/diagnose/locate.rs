//! Where the nominal model's misfit sits, tested.
//!
//! Every test works on the held-out samples' residual whitened by the nominal model's noise
//! model ([`super::noise`]), where the nominal model predicts independent N(0, σ²) samples;
//! all p-values of one recording form one family, corrected by Holm's step-down method at
//! the diagnosis's α:
//!
//! | group | test | statistic |
//! | --- | --- | --- |
//! | phase | a mean offset in each phase (approach, contact, dwell, retract, free) | z = Σε/(σ√n), two-sided |
//! | phase | excess variance in each phase | χ² = Σε²/σ², n dof |
//! | state | a mean offset in each quarter of the contact depth, and loading against unloading | z |
//! | frequency | power at the excitation tones, their harmonics and intermodulation, f₀, and the strongest line between 4 and 9 f₀ | periodogram / local floor, χ²(2·segments) |
//! | whiteness | Ljung–Box on the whitened residual, 20 lags | χ²(20) |
//! | input | the whitened residual regressed on the input's increments, lags 0–20 | explained sum of squares, χ²(rank) |
//! | time | CUSUM of the whitened residual | sup of a Brownian motion, `P ≤ 4·Φ̄(c)` |
//! | map | excess variance per tap (recordings of several taps with X, Y) | χ², n dof |
//!
//! A test is *significant* at the family's level; it is *material* when it is significant and
//! the misfit it attributes is at least [`MATERIAL`]. Sizes are on the whitened residual over
//! the innovation σ — a signal-to-noise ratio where the noise model puts the noise: an
//! offset's |mean|, the excess variance's √(χ²/n − 1), for the correlation tests the
//! explained part's RMS over the rest's (√(R²/(1 − R²)) of a regression on the 20 past samples
//! or the 21 lagged input increments), the CUSUM's mean up to its excursion, and the RMS of a
//! line at the lever's resonances (f₀, 4–9 f₀), whose thermal ringing is part of the noise
//! model. A line the drive makes (its tones, harmonics, intermodulation) is sized on the
//! residual itself over its RMS: the noise knows nothing of the drive, and an autoregressive
//! noise model fitted to a residual with such a line would take part of it for noise. A
//! misfit the noise model absorbs (a slow wander it takes for coloured noise) reads small on
//! the whitened scale; the held-out RMS and the verdict still count it.
//!
//! Phases come from the fitted nominal model (in contact or not) and the slow motion of the
//! base (U smoothed over the excitation): `approach` (moving towards the sample, free),
//! `contact` (moving in, loading), `dwell` (U at rest in contact), `retract` (moving away),
//! `free` (at rest out of contact).

use super::json_report::{SpanJson, TestJson};
use super::model::Trace;
use super::noise::{chi2_sf, normal_sf, NoiseModel};
use super::problem::Problem;
use super::spectrum::Spectrum;
use crate::identify::signal::moving_average;
use nalgebra::{DMatrix, DVector};
use visco_core::units::{FORCE, LENGTH, TIME};

/// What the instrument is doing at a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Phase {
    Approach,
    Contact,
    Dwell,
    Retract,
    Free,
}

impl Phase {
    pub const ALL: [Phase; 5] = [
        Phase::Approach,
        Phase::Contact,
        Phase::Dwell,
        Phase::Retract,
        Phase::Free,
    ];
    /// The report's word.
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Approach => "approach",
            Phase::Contact => "contact",
            Phase::Dwell => "dwell",
            Phase::Retract => "retract",
            Phase::Free => "free",
        }
    }
}

/// Each sample's phase (module docs), runs shorter than the smoothing merged into their
/// neighbours.
pub fn phases(p: &Problem, trace: &Trace) -> Vec<Phase> {
    let d = &p.data;
    let n = d.len();
    let w = p.smoothing_half_width();
    let us = moving_average(&d.u, w);
    let v: Vec<f64> = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            if b > a {
                (us[b] - us[a]) / (d.t[b] - d.t[a])
            } else {
                0.0
            }
        })
        .collect();
    let vmax = v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let th = 0.05 * vmax;
    let mut out: Vec<Phase> = (0..n)
        .map(|i| {
            let contact = trace.depth[i] > 0.0;
            if vmax == 0.0 || v[i].abs() <= th {
                if contact {
                    Phase::Dwell
                } else {
                    Phase::Free
                }
            } else if v[i] < 0.0 {
                if contact {
                    Phase::Contact
                } else {
                    Phase::Approach
                }
            } else {
                Phase::Retract
            }
        })
        .collect();
    // Merge short runs into the previous one.
    let min_run = w.max(2);
    let mut i = 0;
    while i < n {
        let mut j = i;
        while j < n && out[j] == out[i] {
            j += 1;
        }
        if j - i < min_run && i > 0 {
            let prev = out[i - 1];
            for x in &mut out[i..j] {
                *x = prev;
            }
        }
        i = j;
    }
    out
}

/// A time span where something sits.
#[derive(Clone, Debug, PartialEq)]
pub struct Span {
    /// Rows, 0-based half-open.
    pub rows: (usize, usize),
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub phase: Phase,
    /// Lateral position (m), when the recording has one.
    pub xy_m: Option<(f64, f64)>,
    /// Share of the contribution's energy (∫c² dt) in the span.
    pub share: f64,
}

impl Span {
    /// For the report.
    pub fn to_json(&self) -> SpanJson {
        SpanJson {
            t_start_s: self.t_start_s,
            t_end_s: self.t_end_s,
            phase: self.phase.as_str().into(),
            rows: [self.rows.0 as u64 + 1, self.rows.1 as u64],
            share: self.share.into(),
            x_m: self.xy_m.map(|(x, _)| x),
            y_m: self.xy_m.map(|(_, y)| y),
        }
    }
}

/// Where a contribution `c` (nm, per sample) matters: runs of one phase where |c| is above a
/// fifth of its peak and above the noise, gaps shorter than the smoothing closed, at most
/// `max` spans (the largest by energy), in time order.
pub fn spans(p: &Problem, phase: &[Phase], c: &[f64], noise_nm: f64, max: usize) -> Vec<Span> {
    let n = c.len();
    let peak = c.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    if !(peak > 0.0) {
        return Vec::new();
    }
    let th = (0.2 * peak).max(noise_nm.min(0.5 * peak));
    let mut mask: Vec<bool> = c.iter().map(|x| x.abs() >= th).collect();
    let gap = p.smoothing_half_width().max(2);
    // Close short gaps.
    let mut last: Option<usize> = None;
    for i in 0..n {
        if mask[i] {
            if let Some(l) = last {
                if i - l > 1 && i - l <= gap {
                    for x in &mut mask[l + 1..i] {
                        *x = true;
                    }
                }
            }
            last = Some(i);
        }
    }
    // Energies weighted by time: a recording may sample its holds slower than its ramps.
    let t = &p.data.t;
    let w = |i: usize| {
        let a = i.saturating_sub(1);
        let b = (i + 1).min(n - 1);
        if b > a {
            0.5 * (t[b] - t[a])
        } else {
            1.0
        }
    };
    let total: f64 = (0..n).map(|i| c[i] * c[i] * w(i)).sum();
    let mut out = Vec::new();
    let mut i = 0;
    while i < n {
        if !mask[i] {
            i += 1;
            continue;
        }
        let ph = phase[i];
        let mut j = i;
        while j < n && mask[j] && phase[j] == ph {
            j += 1;
        }
        let e: f64 = (i..j).map(|k| c[k] * c[k] * w(k)).sum();
        let unit = p.data.unit[i];
        out.push(Span {
            rows: (i, j),
            t_start_s: p.data.t[i] * TIME,
            t_end_s: p.data.t[j - 1] * TIME,
            phase: ph,
            xy_m: p.unit_xy_m.get(unit).copied().flatten(),
            share: if total > 0.0 { e / total } else { 0.0 },
        });
        i = j;
    }
    out.sort_by(|a, b| b.share.total_cmp(&a.share));
    // The pieces that carry something, and at least the largest three.
    let keep = out.iter().filter(|s| s.share >= 0.02).count().max(3);
    out.truncate(keep.min(max));
    out.sort_by_key(|s| s.rows.0);
    out
}

/// One test of the locate step.
#[derive(Clone, Debug, PartialEq)]
pub struct Test {
    pub group: &'static str,
    pub name: String,
    pub statistic: &'static str,
    pub value: f64,
    pub p_value: f64,
    /// Holm-adjusted p-value.
    pub p_adjusted: f64,
    pub significant: bool,
    /// The misfit the test attributes over the noise (the module docs' scale).
    pub size: f64,
    /// Significant and at least [`MATERIAL`] in size.
    pub material: bool,
    /// What it measured, in words and numbers.
    pub detail: String,
    /// Where (when it is a place).
    pub span: Option<(f64, f64)>,
    /// The frequency tested (Hz), for the frequency group.
    pub freq_hz: Option<f64>,
}

impl Test {
    /// For the report.
    pub fn to_json(&self) -> TestJson {
        TestJson {
            group: self.group.into(),
            test: self.name.clone(),
            statistic: self.statistic.into(),
            value: self.value.into(),
            p_value: self.p_value.into(),
            p_adjusted: self.p_adjusted.into(),
            significant: self.significant,
            size_over_noise: self.size.into(),
            material: self.material,
            detail: self.detail.clone(),
            t_start_s: self.span.map(|(a, _)| a),
            t_end_s: self.span.map(|(_, b)| b),
            f_hz: self.freq_hz,
        }
    }
}

/// Per-phase misfit of a model, for the report.
#[derive(Clone, Debug, PartialEq)]
pub struct PhaseMisfit {
    pub phase: Phase,
    pub samples: usize,
    pub rms_before_m: f64,
    pub rms_after_m: f64,
}

/// The locate step's result.
#[derive(Clone, Debug, Default)]
pub struct Located {
    pub tests: Vec<Test>,
    pub phases: Vec<PhaseMisfit>,
    /// The excitation tones found in U (Hz).
    pub tones_hz: Vec<f64>,
    /// The residual's spectrum before and after (for the figure).
    pub spectrum_before: Spectrum,
    pub spectrum_after: Spectrum,
}

/// Runs the tests (module docs) on the nominal residual `r_nom` (nm), with the final model's
/// residual `r_fin` for the per-phase table.
#[allow(clippy::too_many_arguments)]
pub fn locate(
    p: &Problem,
    phase: &[Phase],
    trace: &Trace,
    r_nom: &[f64],
    r_fin: &[f64],
    noise: &NoiseModel,
    alpha: f64,
) -> Located {
    let n = r_nom.len();
    let held = &p.held;
    let e = noise.whiten(r_nom);
    let sigma = noise.sigma.max(1e-12);
    let mut tests: Vec<Test> = Vec::new();
    let t_s = |i: usize| p.data.t[i] * TIME;
    // Phases.
    let mut phases = Vec::new();
    for ph in Phase::ALL {
        let idx: Vec<usize> = (0..n).filter(|&i| held[i] && phase[i] == ph).collect();
        if idx.len() < 16 {
            continue;
        }
        let m = idx.len() as f64;
        let s: f64 = idx.iter().map(|&i| e[i]).sum();
        let s2: f64 = idx.iter().map(|&i| e[i] * e[i]).sum();
        let z = s / (sigma * m.sqrt());
        let chi = s2 / (sigma * sigma);
        let rms_b = rms_at(r_nom, &idx) * LENGTH;
        let rms_a = rms_at(r_fin, &idx) * LENGTH;
        let span = (t_s(idx[0]), t_s(idx[idx.len() - 1]));
        tests.push(Test {
            group: "phase",
            name: format!("{} offset", ph.as_str()),
            statistic: "z of the mean whitened residual",
            value: z,
            p_value: (2.0 * normal_sf(z.abs())).min(1.0),
            p_adjusted: f64::NAN,
            significant: false,
            size: (s / m).abs() / sigma,
            material: false,
            detail: format!(
                "{} held-out samples; nominal misfit {:.3e} m RMS",
                idx.len(),
                rms_b
            ),
            span: Some(span),
            freq_hz: None,
        });
        tests.push(Test {
            group: "phase",
            name: format!("{} excess variance", ph.as_str()),
            statistic: "chi-square of the whitened residual",
            value: chi,
            p_value: chi2_sf(chi, m),
            p_adjusted: f64::NAN,
            significant: false,
            size: (chi / m - 1.0).max(0.0).sqrt(),
            material: false,
            detail: format!(
                "{:.2}× the noise model's variance over {} samples",
                chi / m,
                idx.len()
            ),
            span: Some(span),
            freq_hz: None,
        });
        phases.push(PhaseMisfit {
            phase: ph,
            samples: idx.len(),
            rms_before_m: rms_b,
            rms_after_m: rms_a,
        });
    }
    // State: depth quartiles in contact, loading against unloading.
    let mut contact: Vec<usize> = (0..n)
        .filter(|&i| held[i] && trace.depth[i] > 0.0)
        .collect();
    if contact.len() >= 64 {
        contact.sort_by(|&a, &b| trace.depth[a].total_cmp(&trace.depth[b]));
        let q = contact.len() / 4;
        for k in 0..4 {
            let idx = &contact[k * q..if k == 3 { contact.len() } else { (k + 1) * q }];
            let m = idx.len() as f64;
            let s: f64 = idx.iter().map(|&i| e[i]).sum();
            let z = s / (sigma * m.sqrt());
            let (lo, hi) = (trace.depth[idx[0]], trace.depth[idx[idx.len() - 1]]);
            tests.push(Test {
                group: "state",
                name: format!("depth quarter {}", k + 1),
                statistic: "z of the mean whitened residual",
                value: z,
                p_value: (2.0 * normal_sf(z.abs())).min(1.0),
                p_adjusted: f64::NAN,
                significant: false,
                size: (s / m).abs() / sigma,
                material: false,
                detail: format!(
                    "depth {:.3e}–{:.3e} m: misfit {:.3e} m RMS",
                    lo * LENGTH,
                    hi * LENGTH,
                    rms_at(r_nom, idx) * LENGTH
                ),
                span: None,
                freq_hz: None,
            });
        }
        let load: Vec<usize> = (0..n)
            .filter(|&i| held[i] && trace.depth[i] > 0.0 && phase[i] == Phase::Contact)
            .collect();
        let unload: Vec<usize> = (0..n)
            .filter(|&i| held[i] && trace.depth[i] > 0.0 && phase[i] == Phase::Retract)
            .collect();
        if load.len() >= 16 && unload.len() >= 16 {
            let ml = load.iter().map(|&i| e[i]).sum::<f64>() / load.len() as f64;
            let mu = unload.iter().map(|&i| e[i]).sum::<f64>() / unload.len() as f64;
            let se = sigma * (1.0 / load.len() as f64 + 1.0 / unload.len() as f64).sqrt();
            let z = (ml - mu) / se;
            tests.push(Test {
                group: "state",
                name: "loading against unloading".to_string(),
                statistic: "z of the difference of mean whitened residuals",
                value: z,
                p_value: (2.0 * normal_sf(z.abs())).min(1.0),
                p_adjusted: f64::NAN,
                significant: false,
                // +a loading and −a unloading differ by 2a.
                size: 0.5 * (ml - mu).abs() / sigma,
                material: false,
                detail: format!(
                    "loading misfit {:.3e} m RMS over {} samples, unloading {:.3e} m RMS over {}",
                    rms_at(r_nom, &load) * LENGTH,
                    load.len(),
                    rms_at(r_nom, &unload) * LENGTH,
                    unload.len()
                ),
                span: None,
                freq_hz: None,
            });
        }
    }
    // Frequency.
    let fs = p.fs_hz();
    let seg = (n / 8).clamp(64, 4096);
    let spec_b = Spectrum::welch(r_nom, fs, seg);
    // The resonances' lines sized on the whitened residual (below).
    let spec_w = Spectrum::welch(&e, fs, seg);
    let spec_a = Spectrum::welch(r_fin, fs, seg);
    let spec_u = Spectrum::welch(&p.data.u, fs, seg);
    let mut tones: Vec<f64> = Vec::new();
    if spec_u.f_hz.len() > 8 {
        let mut peaks: Vec<(f64, f64)> = (3..spec_u.psd.len() - 1)
            .filter(|&k| spec_u.psd[k] > spec_u.psd[k - 1] && spec_u.psd[k] >= spec_u.psd[k + 1])
            .map(|k| {
                (
                    spec_u.f_hz[k],
                    spec_u.psd[k] / spec_u.local_floor(k, 16).max(1e-300),
                )
            })
            .filter(|(_, r)| *r > 100.0)
            .collect();
        peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
        tones = peaks.iter().take(2).map(|x| x.0).collect();
        tones.sort_by(f64::total_cmp);
    }
    // (name, frequency, whether the drive makes it: the noise knows nothing of the drive, so
    // such a line is sized on the residual itself; the lever's resonances are sized on the
    // whitened residual, where its thermal ringing is part of the noise model).
    let mut lines: Vec<(String, f64, bool)> = Vec::new();
    for (i, &f) in tones.iter().enumerate() {
        lines.push((format!("tone {} ({:.4e} Hz)", i + 1, f), f, true));
        lines.push((format!("2nd harmonic of tone {}", i + 1), 2.0 * f, true));
        lines.push((format!("3rd harmonic of tone {}", i + 1), 3.0 * f, true));
    }
    if tones.len() == 2 {
        lines.push(("intermodulation f1 + f2".into(), tones[0] + tones[1], true));
        lines.push(("intermodulation f2 − f1".into(), tones[1] - tones[0], true));
    }
    if let Some(f0) = p.inst.f0_mhz().map(|f| f / TIME) {
        lines.push((format!("first resonance f0 ({f0:.4e} Hz)"), f0, false));
        if let Some((f2, _)) = spec_b
            .transient_peaks(4.0 * f0, (9.0 * f0).min(0.48 * fs), 1)
            .first()
        {
            lines.push((
                format!("strongest line between 4 and 9 f0 ({f2:.4e} Hz)"),
                *f2,
                false,
            ));
        }
    }
    let dof = 2.0 * spec_b.segments.max(1) as f64;
    for (name, f, of_drive) in lines {
        if !(f > 0.0 && f < 0.5 * fs) {
            continue;
        }
        let Some(k) = spec_b.bin(f) else { continue };
        let floor = spec_b.local_floor(k, 12);
        if !(floor > 0.0) {
            continue;
        }
        let ratio = spec_b.psd[k] / floor;
        tests.push(Test {
            group: "frequency",
            name,
            statistic: "residual power / local floor",
            value: ratio,
            p_value: chi2_sf(ratio * dof, dof),
            p_adjusted: f64::NAN,
            significant: false,
            size: if of_drive {
                line_size(&spec_b, f, fs, noise.raw_sigma)
            } else {
                line_size(&spec_w, f, fs, sigma)
            },
            material: false,
            detail: format!(
                "{:.3e} m²/Hz at {:.4e} Hz against a floor of {:.3e} m²/Hz",
                spec_b.psd[k] * LENGTH * LENGTH,
                f,
                floor * LENGTH * LENGTH
            ),
            span: None,
            freq_hz: Some(f),
        });
    }
    // Whiteness and input correlation on the held-out runs.
    let runs = super::noise::runs(held);
    let p_ar = noise.a.len();
    let mut du: Vec<f64> = (0..n)
        .map(|i| {
            if i > 0 {
                p.data.u[i] - p.data.u[i - 1]
            } else {
                0.0
            }
        })
        .collect();
    let du_sd = (du.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
    if du_sd > 0.0 {
        for x in &mut du {
            *x /= du_sd;
        }
    }
    let lags = 20usize;
    let (mut num, mut count) = (vec![0.0; lags + 1], vec![0usize; lags + 1]);
    let mut total = 0usize;
    for &(a, b) in &runs {
        let a = a.max(p_ar);
        if b <= a {
            continue;
        }
        total += b - a;
        for lag in 0..=lags {
            for i in a + lag..b {
                num[lag] += e[i] * e[i - lag];
                count[lag] += 1;
            }
        }
    }
    if total > 4 * lags && num[0] > 0.0 {
        let c0 = num[0] / count[0] as f64;
        let mut q = 0.0;
        for lag in 1..=lags {
            if count[lag] > 0 {
                let r = num[lag] / count[lag] as f64 / c0;
                q += r * r * total as f64;
            }
        }
        tests.push(Test {
            group: "whiteness",
            name: "Ljung–Box, 20 lags".to_string(),
            statistic: "Q",
            value: q,
            p_value: chi2_sf(q, lags as f64),
            p_adjusted: f64::NAN,
            significant: false,
            // The share its own 20 past samples predict (the same regression as the input's).
            size: {
                let (qa, _, rows) = lag_regression(&e, &e, &runs, p_ar, 1..=lags, c0.sqrt());
                snr(qa / rows.max(1) as f64)
            },
            material: false,
            detail: "autocorrelation of the whitened held-out residual".to_string(),
            span: None,
            freq_hz: None,
        });
        if du_sd > 0.0 {
            let (q, dof, rows) = lag_regression(&e, &du, &runs, p_ar, 0..=lags, c0.sqrt());
            if dof > 0 && rows > 4 * (lags + 1) {
                tests.push(Test {
                    group: "input",
                    name: "regression on U increments, lags 0–20".to_string(),
                    statistic: "explained sum of squares / variance",
                    value: q,
                    p_value: chi2_sf(q, dof as f64),
                    p_adjusted: f64::NAN,
                    significant: false,
                    size: snr(q / rows as f64),
                    material: false,
                    detail: format!(
                        "what of the input the residual still follows ({dof} independent \
                         directions of the lagged increments, {rows} samples)"
                    ),
                    span: None,
                    freq_hz: None,
                });
            }
        }
    }
    // Time: CUSUM over the held-out samples in order.
    let idx: Vec<usize> = (0..n).filter(|&i| held[i]).collect();
    if idx.len() >= 32 {
        let (mut s, mut best, mut at) = (0.0f64, 0.0f64, 0usize);
        for (k, &i) in idx.iter().enumerate() {
            s += e[i] / sigma;
            if s.abs() > best {
                best = s.abs();
                at = k;
            }
        }
        let c = best / (idx.len() as f64).sqrt();
        tests.push(Test {
            group: "time",
            name: "CUSUM of the whitened residual".to_string(),
            statistic: "max |Σε|/(σ√n)",
            value: c,
            p_value: (4.0 * normal_sf(c)).min(1.0),
            p_adjusted: f64::NAN,
            significant: false,
            // `s` counts in σ: the mean offset from the start to the excursion.
            size: best / (at + 1) as f64,
            material: false,
            detail: format!("largest excursion at t = {:.6e} s", t_s(idx[at])),
            span: Some((t_s(idx[0]), t_s(idx[at]))),
            freq_hz: None,
        });
    }
    // Map: per unit with a position.
    if p.unit_xy_m.iter().filter(|x| x.is_some()).count() >= 2 {
        for (u, &(a, b)) in p.unit_rows.iter().enumerate() {
            let idx: Vec<usize> = (a..b).filter(|&i| held[i]).collect();
            if idx.len() < 16 {
                continue;
            }
            let chi: f64 = idx.iter().map(|&i| e[i] * e[i]).sum::<f64>() / (sigma * sigma);
            let xy = p.unit_xy_m[u];
            tests.push(Test {
                group: "map",
                name: match xy {
                    Some((x, y)) => format!("tap {u} at ({x:.4e}, {y:.4e}) m"),
                    None => format!("tap {u}"),
                },
                statistic: "chi-square of the whitened residual",
                value: chi,
                p_value: chi2_sf(chi, idx.len() as f64),
                p_adjusted: f64::NAN,
                significant: false,
                size: (chi / idx.len() as f64 - 1.0).max(0.0).sqrt(),
                material: false,
                detail: format!("misfit {:.3e} m RMS", rms_at(r_nom, &idx) * LENGTH),
                span: Some((t_s(a), t_s(b - 1))),
                freq_hz: None,
            });
        }
    }
    holm(&mut tests, alpha);
    for t in &mut tests {
        t.material = t.significant && t.size >= MATERIAL;
    }
    Located {
        tests,
        phases,
        tones_hz: tones,
        spectrum_before: spec_b,
        spectrum_after: spec_a,
    }
}

/// The smallest misfit a located test reports as material: half the noise (on the scale of
/// the module docs; the effects' detection floor, [`super::search::DETECTION_FLOOR`], asks
/// the same of an effect's peak over the raw noise RMS). With 10⁴–10⁵ held-out samples the tests see far smaller misfits (a mean offset of
/// 0.06 σ over a dwell is significant), which no plot of the residual would show and which
/// a model of another simulator's integrator can leave on clean data; a test's p-value says
/// that a misfit is there, its size whether it matters.
pub const MATERIAL: f64 = 0.5;

/// The RMS of a line at `f` in a Hann-windowed Welch spectrum of a residual of RMS `sigma`,
/// over the rest's: the power above the local floor over the window's main lobe (bins k ± 2,
/// so a line between bins counts whole).
fn line_size(s: &Spectrum, f: f64, fs: f64, sigma: f64) -> f64 {
    let Some(k) = s.bin(f) else { return 0.0 };
    let floor = s.local_floor(k, 12);
    if !(floor > 0.0) {
        return 0.0;
    }
    let bins = s.f_hz.len().saturating_sub(1).max(1) as f64;
    let df = 0.5 * fs / bins;
    let lobe = k.saturating_sub(2)..(k + 3).min(s.psd.len());
    let power: f64 = s.psd[lobe].iter().map(|p| (p - floor) * df).sum();
    // `sigma` is the whole residual's, the line included: the line over the rest.
    snr(power / (sigma * sigma).max(1e-300))
}

/// A share R² of the variance explained, as the explained part's RMS over the rest's.
fn snr(r2: f64) -> f64 {
    (r2.max(0.0) / (1.0 - r2).max(1e-12)).sqrt()
}

/// The whitened residual `e` (scaled by `scale` to unit variance) regressed on `x` at `lags`
/// (the input's increments at 0..=20, or `e` itself at 1..=20) over the held-out `runs`: the
/// explained sum of squares beyond a constant's, its degrees of freedom (the rank of the
/// lagged regressors beside the constant) and the rows used. Where the whitened residual is white and independent of the input, the sum
/// is χ² with that many degrees of freedom whatever the input's own correlation; the sum of
/// squared cross-correlations it replaced is not (a force curve's increments are nearly
/// constant, so its 21 lags are one direction counted 21 times, and a clean curve read as
/// significant).
fn lag_regression(
    e: &[f64],
    x_of: &[f64],
    runs: &[(usize, usize)],
    p_ar: usize,
    lags: std::ops::RangeInclusive<usize>,
    scale: f64,
) -> (f64, usize, usize) {
    let (first, last) = (*lags.start(), *lags.end());
    // The lagged regressors and a constant, so that an offset of the residual is not read as
    // following the input (a one-way ramp's increments have a mean).
    let k = last + 2 - first;
    let mut g = DMatrix::<f64>::zeros(k, k);
    let mut b = DVector::<f64>::zeros(k);
    let mut rows = 0usize;
    let mut x = vec![0.0; k];
    for &(a, end) in runs {
        for i in a.max(p_ar).max(last)..end {
            for (j, xj) in x[..k - 1].iter_mut().enumerate() {
                *xj = x_of[i - first - j];
            }
            x[k - 1] = 1.0;
            let y = e[i] / scale;
            for r in 0..k {
                b[r] += x[r] * y;
                for c in r..k {
                    g[(r, c)] += x[r] * x[c];
                }
            }
            rows += 1;
        }
    }
    for r in 0..k {
        for c in 0..r {
            g[(r, c)] = g[(c, r)];
        }
    }
    // The projection onto the lagged increments' span, by a pseudo-inverse: a ramp's
    // increments span only a few directions.
    let eig = g.symmetric_eigen();
    let top = eig.eigenvalues.iter().cloned().fold(0.0f64, f64::max);
    let (mut q, mut dof) = (0.0, 0usize);
    for (j, &l) in eig.eigenvalues.iter().enumerate() {
        if l > top * 1e-9 && l > 0.0 {
            let proj = eig.eigenvectors.column(j).dot(&b);
            q += proj * proj / l;
            dof += 1;
        }
    }
    // Less what the constant alone explains (its one degree of freedom).
    let mean_part = b[k - 1] * b[k - 1] / rows.max(1) as f64;
    ((q - mean_part).max(0.0), dof.saturating_sub(1), rows)
}

/// Holm's step-down adjustment at family-wise rate `alpha`.
pub fn holm(tests: &mut [Test], alpha: f64) {
    let m = tests.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| tests[a].p_value.total_cmp(&tests[b].p_value));
    let mut running: f64 = 0.0;
    for (rank, &i) in order.iter().enumerate() {
        let adj = ((m - rank) as f64 * tests[i].p_value).min(1.0);
        running = running.max(adj);
        tests[i].p_adjusted = running;
        tests[i].significant = running < alpha;
    }
}

fn rms_at(r: &[f64], idx: &[usize]) -> f64 {
    if idx.is_empty() {
        return f64::NAN;
    }
    (idx.iter().map(|&i| r[i] * r[i]).sum::<f64>() / idx.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A residual offset by half its σ on a one-way ramp (increments 1 ± 0.1): the offset is
    /// not the input's doing, and the regression, with its constant, does not say it is.
    #[test]
    fn an_offset_is_not_read_as_following_the_input() {
        use crate::plant::rng::NormalRng;
        let mut rng = NormalRng::new(23);
        let n = 5000;
        let du: Vec<f64> = (0..n).map(|_| 1.0 + 0.1 * rng.normal()).collect();
        let e: Vec<f64> = (0..n).map(|_| rng.normal() + 0.5).collect();
        let (q, dof, _) = lag_regression(&e, &du, &[(0, n)], 0, 0..=20, 1.0);
        assert_eq!(dof, 21);
        assert!(chi2_sf(q, dof as f64) > 1e-3, "q {q}");
    }

    /// A line of RMS 0.5 in white noise of σ 1 reads 0.5, on a bin or between two.
    #[test]
    fn a_line_reads_its_rms_on_or_between_bins() {
        use crate::plant::rng::NormalRng;
        let mut rng = NormalRng::new(9);
        let (n, fs) = (1usize << 16, 1.0e6);
        for f in [fs * 410.0 / 4096.0, fs * 410.5 / 4096.0] {
            let x: Vec<f64> = (0..n)
                .map(|i| {
                    let t = i as f64 / fs;
                    rng.normal() + 0.5 * 2f64.sqrt() * (2.0 * std::f64::consts::PI * f * t).sin()
                })
                .collect();
            let s = Spectrum::welch(&x, fs, 4096);
            // The residual's RMS, the line included.
            let size = line_size(&s, f, fs, 1.25f64.sqrt());
            assert!((size - 0.5).abs() < 0.04, "f = {f} Hz: {size}");
        }
    }

    /// On a force curve's input (increments constant on the approach, opposite on the
    /// retract, zero in the dwell) a white residual independent of it must reach the 5 %
    /// level in about 5 % of trials. The sum of squared cross-correlations the regression
    /// replaced, read as χ²(21), counts the ramp's one direction 21 times and does not.
    #[test]
    fn input_regression_keeps_its_level_on_a_ramp() {
        use crate::plant::rng::NormalRng;
        let mut rng = NormalRng::new(17);
        let n = 3000;
        let du: Vec<f64> = (0..n)
            .map(|i| match i * 3 / n {
                0 => 1.0,
                1 => 0.0,
                _ => -1.0,
            })
            .collect();
        let runs = [(0, n)];
        let trials = 400;
        let (mut hits, mut old_hits) = (0, 0);
        for _ in 0..trials {
            let e: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
            let (q, dof, rows) = lag_regression(&e, &du, &runs, 0, 0..=20, 1.0);
            assert_eq!(rows, n - 20);
            if chi2_sf(q, dof as f64) < 0.05 {
                hits += 1;
            }
            let old: f64 = (0..=20)
                .map(|lag| {
                    let r = (lag..n).map(|i| e[i] * du[i - lag]).sum::<f64>() / n as f64;
                    r * r * n as f64
                })
                .sum();
            if chi2_sf(old, 21.0) < 0.05 {
                old_hits += 1;
            }
        }
        // Binomial(400, 0.05): mean 20, σ 4.4; ±3σ.
        assert!(
            (7..=33).contains(&hits),
            "{hits} of {trials} at the 5 % level"
        );
        // The old sum is ≈ 21·(2/3)·χ²(1) here (all lags alike, E du² = 2/3): 12.6 % above
        // χ²(21)'s 5 % point, about 50 of 400.
        assert!(
            old_hits > 35,
            "the cross-correlations' sum: {old_hits} of {trials}"
        );
    }

    /// A residual that follows the input at lag 5 with a gain of 0.3 (unit-variance white
    /// increments): the regression finds it, and its size is the followed part's RMS over the
    /// rest's, 0.3.
    #[test]
    fn input_regression_sizes_what_the_residual_follows() {
        use crate::plant::rng::NormalRng;
        let mut rng = NormalRng::new(5);
        let n = 20_000;
        let du: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let e: Vec<f64> = (0..n)
            .map(|i| rng.normal() + if i >= 5 { 0.3 * du[i - 5] } else { 0.0 })
            .collect();
        let scale = (1.0f64 + 0.09).sqrt();
        let (q, dof, rows) = lag_regression(&e, &du, &[(0, n)], 0, 0..=20, scale);
        assert_eq!(dof, 21);
        let size = snr(q / rows as f64);
        assert!((size - 0.3).abs() < 0.02, "size {size}");
        assert!(chi2_sf(q, 21.0) < 1e-100);
    }

    #[test]
    fn holm_adjusts_in_order() {
        let mk = |p: f64| Test {
            group: "x",
            name: String::new(),
            statistic: "",
            value: 0.0,
            p_value: p,
            p_adjusted: f64::NAN,
            significant: false,
            size: 0.0,
            material: false,
            detail: String::new(),
            span: None,
            freq_hz: None,
        };
        let mut t = vec![mk(0.01), mk(0.04), mk(0.002), mk(0.5)];
        holm(&mut t, 0.05);
        // Sorted: 0.002·4 = 0.008, 0.01·3 = 0.03, 0.04·2 = 0.08, 0.5·1 → monotone.
        assert!((t[2].p_adjusted - 0.008).abs() < 1e-12);
        assert!((t[0].p_adjusted - 0.03).abs() < 1e-12);
        assert!((t[1].p_adjusted - 0.08).abs() < 1e-12);
        assert!((t[3].p_adjusted - 0.5).abs() < 1e-12);
        assert_eq!(
            t.iter().map(|x| x.significant).collect::<Vec<_>>(),
            vec![true, false, true, false]
        );
    }
}

/// What a hold in contact shows about who moved: the sample or the scanner.
///
/// Under a **constant force** (the force loop holds D), a sample that creeps lets the base sink
/// further into it, while a scanner that lags its command (piezo creep, continuing the
/// approach) makes the loop draw the command back, away from the sample. Under a **constant
/// height** (no loop), a sample that relaxes lets the force fall, while a lagging scanner keeps
/// pressing and the force rises. The recorded U of a scanner without a height sensor is its
/// command, so the sign of the base's travel or of the force change in the hold says which.
#[derive(Clone, Debug, PartialEq)]
pub struct HoldReading {
    /// Samples of the longest hold in contact.
    pub rows: (usize, usize),
    /// `"constant force"`, `"constant height"` or `"neither"` (both moved).
    pub kind: &'static str,
    /// How far the base moved towards the sample over the hold (m; negative: away).
    pub base_towards_sample_m: f64,
    /// Change of the contact force −K·ΔD over the hold (N).
    pub force_change_n: f64,
    /// The reading in words.
    pub reading: String,
}

/// The longest dwell (a hold in contact) of at least 32 samples, read as [`HoldReading`] says;
/// `None` without one. Levels are means over the hold's first and last tenth.
pub fn hold_reading(p: &Problem, phase: &[Phase], noise_nm: f64) -> Option<HoldReading> {
    let d = &p.data;
    let mut best: Option<(usize, usize)> = None;
    let mut i = 0;
    while i < phase.len() {
        let j = i + phase[i..].iter().take_while(|&&x| x == phase[i]).count();
        if phase[i] == Phase::Dwell && j - i >= 32 && best.is_none_or(|(a, b)| j - i > b - a) {
            best = Some((i, j));
        }
        i = j;
    }
    let (a, b) = best?;
    let m = ((b - a) / 10).max(4);
    let mean =
        |v: &[f64], r: std::ops::Range<usize>| v[r.clone()].iter().sum::<f64>() / r.len() as f64;
    // Approach is U decreasing (z up): towards the sample is −ΔU.
    let du = mean(&d.u, b - m..b) - mean(&d.u, a..a + m);
    let dd = mean(&d.d, b - m..b) - mean(&d.d, a..a + m);
    let towards = -du;
    let k = p.inst.k;
    let df_nn = -k * dd;
    // A level over m samples is known to ~σ/√m; a change to √2 of that.
    let floor = 3.0 * noise_nm * (2.0 / m as f64).sqrt();
    let kind = if du.abs() > 3.0 * dd.abs().max(floor) {
        "constant force"
    } else if dd.abs() > 3.0 * du.abs().max(floor) {
        "constant height"
    } else {
        "neither"
    };
    let (t0, t1) = (d.t[a] * TIME, d.t[b - 1] * TIME);
    let len = |x: f64| format!("{:.3} µm", x * LENGTH * 1e6);
    // Internal units: K in nN/nm, D in nm, so K·ΔD is in nN.
    let force = |x: f64| format!("{x:.3} nN");
    let reading = match kind {
        "constant force" if towards > 0.0 => format!(
            "in the hold at constant force ({t0:.3}–{t1:.3} s) the base moved {} further into \
             the sample: the sample creeps; a scanner lagging its command would have made the \
             force loop draw the command back, away from the sample",
            len(towards)
        ),
        "constant force" => format!(
            "in the hold at constant force ({t0:.3}–{t1:.3} s) the base was drawn back {} away \
             from the sample: the force loop following a scanner that lags its command (piezo \
             creep) — a creeping sample would have let it sink in",
            len(-towards)
        ),
        "constant height" if df_nn < 0.0 => format!(
            "in the hold at constant height ({t0:.3}–{t1:.3} s) the force fell by {}: the sample \
             relaxes; a scanner lagging its command would have kept pressing, the force rising",
            force(-df_nn)
        ),
        "constant height" => format!(
            "in the hold at constant height ({t0:.3}–{t1:.3} s) the force rose by {}: the scanner \
             keeps moving after its command stopped (piezo creep) — a relaxing sample would have \
             let the force fall",
            force(df_nn)
        ),
        _ => format!(
            "in the hold ({t0:.3}–{t1:.3} s) both the base ({} towards the sample) and the force \
             ({} change) moved: neither a constant-force nor a constant-height hold",
            len(towards),
            force(df_nn)
        ),
    };
    Some(HoldReading {
        rows: (a, b),
        kind,
        base_towards_sample_m: towards * LENGTH,
        force_change_n: df_nn * FORCE,
        reading,
    })
}
