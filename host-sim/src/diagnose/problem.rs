//! A recording made ready for fitting: the samples in internal units, the instrument, the
//! units (taps, curves) that each get their own contact, the fit and held-out samples, and
//! the nominal model's starting point.
//!
//! **Fit and held-out samples.** The recording is cut into blocks of two samples and every
//! other block is held out. Interleaving this finely keeps every phase (approach, dwell,
//! retract) in both halves and pins even an event's timing (a pull-off, a ring) from the fit
//! half to within a sample — with longer blocks, the timing of a pull-off inside a held-out
//! block is free for the fit and wrong for the test. The halves are still independent where
//! it matters: the tests compare the *whitened* residuals, which are independent samples when
//! the noise model is right (`noise`), and a fitted model of a few parameters cannot follow
//! the noise of single samples.
//!
//! **Starting point.** From the data alone, quasi-statically: the free deflection's level from
//! the start of the recording, the force `−K·(D − d₀)` smoothed over the excitation, its
//! first rise past 5 σ as the touch, the contact height where a least-squares fit of the
//! bed's law `F = k_a·V(h − Z) + c_a·A·δ̇` fits best, and that fit's k_a, c_a. The
//! Levenberg–Marquardt fit of the full model starts there.

use super::model::{cap_volume, contact_area, Contact, Data, Instrument, Nominal};
use crate::identify::signal::{median, minimize, moving_average, robust_sigma, two_column_nonneg};
use crate::recording::Recording;
use visco_core::units::{DAMPING, LENGTH, MASS, TIME};

/// Samples per block of the fit/held-out interleave.
pub const BLOCK: usize = 2;

/// A dynamic model needs the resonance sampled at least this many times per period.
pub const DYNAMIC_SAMPLES_PER_PERIOD: f64 = 4.0;

/// Whether sampling at `fs` resolves a resonance at `f0` (any one unit of frequency): at
/// least [`DYNAMIC_SAMPLES_PER_PERIOD`] samples per period.
pub fn resolves(fs: f64, f0: f64) -> bool {
    fs >= DYNAMIC_SAMPLES_PER_PERIOD * f0
}

/// The share of a step's transient left one sample later above which a lever whose
/// resonance the sampling does not resolve is still integrated dynamically: a DAC's staircase
/// at the sampling rate rings a high-Q lever for longer than a sample (a 17 kHz, Q 76 lever
/// sampled at 1 kHz keeps half of each step's ringing), which no quasi-static model follows.
pub const UNSETTLED: f64 = 1e-3;

/// Why a recording cannot be diagnosed.
#[derive(Debug, Clone, PartialEq)]
pub struct ProblemError(pub String);

impl std::fmt::Display for ProblemError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// The recording, ready for fitting.
#[derive(Clone, Debug)]
pub struct Problem {
    pub inst: Instrument,
    pub data: Data,
    /// Fit samples.
    pub fit: Vec<bool>,
    /// Held-out samples (the complement).
    pub held: Vec<bool>,
    /// Median sampling interval (µs).
    pub dt_us: f64,
    /// How the cantilever's M and C were obtained, for the report.
    pub dynamics_source: String,
    /// Lateral position per unit (m), when the recording has X, Y.
    pub unit_xy_m: Vec<Option<(f64, f64)>>,
    /// First and last sample of each unit.
    pub unit_rows: Vec<(usize, usize)>,
    /// The Huber scale (nm) when the fit is robust (a recording dominated by misfit, see
    /// `search`); `None`: least squares.
    pub huber_nm: Option<f64>,
    /// A force curve's optical-interference wave in U, found on its free approach as
    /// `identify` finds it, with its baseline; `data.d` holds the recording less this wave,
    /// so every model the search fits has it as part of the nominal's baseline.
    pub baseline_wave: Option<crate::identify::force_curve::Baseline>,
    /// The wave per sample (nm; empty without one): what `data.d` had taken out.
    pub wave_nm: Vec<f64>,
    /// Unique to each [`Problem::new`] and kept by its clones: the search's recent
    /// simulations are looked up by it (with the model and the scales), since what a
    /// simulation reads (`inst`, `data.t`, `data.u`, `data.unit`) is never changed after.
    pub(crate) simulations_key: u64,
    /// Simulations run on these samples (by this problem and its clones; `search`).
    pub(crate) simulations: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

impl Problem {
    /// From a recording (read whole). Errors say what is missing.
    pub fn new(rec: &Recording) -> Result<Problem, ProblemError> {
        let n = rec.len();
        if n < 64 {
            return Err(ProblemError(format!(
                "a diagnosis needs at least 64 samples, the recording has {n}"
            )));
        }
        if rec.meta.mode == crate::recording::Mode::ForceCurve {
            if let Some(why) = crate::identify::force_curve::deflection_scale_error(rec) {
                return Err(ProblemError(why));
            }
        }
        let t: Vec<f64> = rec.t_s.iter().map(|v| v / TIME).collect();
        let u: Vec<f64> = rec.u_m.iter().map(|v| v / LENGTH).collect();
        let mut d: Vec<f64> = rec.d_m.iter().map(|v| v / LENGTH).collect();
        // A force curve's interference wave belongs to the baseline, not to the physics of the
        // contact: it is found on the free approach (as identify finds it) and taken out.
        let baseline_wave = interference_wave(rec);
        let wave_nm: Vec<f64> = baseline_wave.as_ref().map_or(Vec::new(), |b| {
            // At the lever's height, from the recorded deflection (identify/baseline.rs).
            rec.u_m
                .iter()
                .zip(&rec.d_m)
                .map(|(&x, &y)| (b.under(x, y) - b.line_at(x)) / LENGTH)
                .collect()
        });
        for (x, w) in d.iter_mut().zip(&wave_nm) {
            *x -= w;
        }
        let mut dts: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        dts.sort_by(f64::total_cmp);
        let dt_us = dts[dts.len() / 2];
        // Units: the tap column's runs; without one, the contact episodes found in the data.
        let mut unit = vec![0usize; n];
        let mut unit_rows = vec![(0usize, n)];
        if let Some(tap) = &rec.tap {
            unit_rows.clear();
            let mut start = 0;
            for i in 1..=n {
                if i == n || tap[i] != tap[i - 1] {
                    unit_rows.push((start, i));
                    start = i;
                }
            }
        } else {
            unit_rows = contact_episodes(&d, &u);
        }
        for (k, &(a, b)) in unit_rows.iter().enumerate() {
            for x in &mut unit[a..b] {
                *x = k;
            }
        }
        let units = unit_rows.len();
        let unit_xy_m = unit_rows
            .iter()
            .map(|&(a, b)| match (&rec.x_m, &rec.y_m) {
                (Some(x), Some(y)) => {
                    let m = (a + b) / 2;
                    Some((x[m], y[m]))
                }
                _ => None,
            })
            .collect();
        // The cantilever.
        let meta = &rec.meta;
        let k = meta.cantilever_k_n_per_m; // N/m = nN/nm
        let fs = 1.0 / (dt_us * TIME);
        let (m_si, c_si, source) = match (
            meta.cantilever_m_kg,
            meta.cantilever_c_ns_per_m,
            meta.cantilever_f0_hz,
            meta.cantilever_q,
        ) {
            (Some(m), Some(c), _, _) => (
                Some(m),
                c,
                "recording: cantilever_m_kg, cantilever_c_ns_per_m".to_string(),
            ),
            (_, _, Some(f0), Some(q)) => {
                let w = 2.0 * std::f64::consts::PI * f0;
                let m = k / (w * w);
                (
                    Some(m),
                    (k * m).sqrt() / q,
                    "recording: cantilever_f0_hz, cantilever_q".to_string(),
                )
            }
            (Some(m), None, _, _) => (
                Some(m),
                0.0,
                "recording: cantilever_m_kg (no damping given: C = 0)".to_string(),
            ),
            _ => (
                None,
                0.0,
                "not in the recording: quasi-static model (the cantilever a spring)".to_string(),
            ),
        };
        let (m_int, c_int, dynamics_source) = match m_si {
            Some(m) => {
                let f0 = (k / m).sqrt() / (2.0 * std::f64::consts::PI);
                // A step of U leaves e^(−π·f₀·Δt/Q) of its transient at the next sample.
                let q = (k * m).sqrt() / c_si.max(1e-300);
                let left = (-std::f64::consts::PI * f0 / (q * fs)).exp();
                if resolves(fs, f0) {
                    (
                        Some(m / MASS),
                        c_si / DAMPING,
                        format!(
                            "{source}; dynamic model (f0 = {f0:.4e} Hz, sampled at {fs:.4e} Hz)"
                        ),
                    )
                } else if left > UNSETTLED {
                    (
                        Some(m / MASS),
                        c_si / DAMPING,
                        format!(
                            "{source}; dynamic model, resonance aliased (f0 = {f0:.4e} Hz, \
                             sampled at {fs:.4e} Hz): a step of U still rings {left:.1e} of \
                             itself one sample later"
                        ),
                    )
                } else {
                    (None, 0.0, format!("{source}; quasi-static model: f0 = {f0:.4e} Hz is not resolved at {fs:.4e} Hz, and a step of U settles within a sample"))
                }
            }
            None => (None, 0.0, source),
        };
        let inst = Instrument {
            k,
            c: c_int,
            m: m_int,
            r_tip: meta.tip_radius_m / LENGTH,
        };
        let block = BLOCK;
        let fit: Vec<bool> = (0..n).map(|i| (i / block) % 2 == 0).collect();
        let held = fit.iter().map(|f| !f).collect();
        Ok(Problem {
            inst,
            data: Data {
                t,
                u,
                d,
                unit,
                units,
            },
            fit,
            held,
            dt_us,
            dynamics_source,
            unit_xy_m,
            unit_rows,
            huber_nm: None,
            baseline_wave,
            wave_nm,
            simulations_key: {
                static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
                NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
            },
            simulations: Default::default(),
        })
    }

    /// The recorded D at sample `i` (nm): `data.d` with the baseline wave put back.
    pub fn recorded_nm(&self, i: usize) -> f64 {
        self.data.d[i] + self.wave_nm.get(i).copied().unwrap_or(0.0)
    }

    /// A simulated D (nm) with the baseline wave added: the model a user compares with the
    /// recording.
    pub fn with_wave(&self, mut sim: Vec<f64>) -> Vec<f64> {
        for (x, w) in sim.iter_mut().zip(&self.wave_nm) {
            *x += w;
        }
        sim
    }

    /// Smoothing half-width (samples) that removes an excitation and most noise but keeps a
    /// force curve's shape: 1/200 of the recording, and at least 0.25 ms for dynamic ones.
    pub fn smoothing_half_width(&self) -> usize {
        let n = self.data.len();
        let mut w = (n / 400).max(1);
        if self.inst.dynamic() {
            w = w.max((250.0 / self.dt_us) as usize);
        }
        w.min(n / 8).max(1)
    }

    /// The nominal model's starting points (see the module docs): the contact where the
    /// force first rises past 5 σ, and where the deflection first leaves its free level by
    /// 5 σ either way (an attraction at the touch pulls the tip in before the bed pushes).
    pub fn initial_nominals(&self) -> Vec<Nominal> {
        let d = &self.data;
        let n = d.len();
        let k = self.inst.k;
        let r = self.inst.r_tip;
        let w = self.smoothing_half_width();
        let ds = moving_average(&d.d, w);
        let us = moving_average(&d.u, w);
        // Free level from the first tenth (the approach starts away from the sample).
        let head = (n / 10).max(8).min(n);
        let offset = median(&d.d[..head]);
        // The smoothed deflection's own noise on the free head, about its linear trend.
        let noise = {
            let m = head as f64;
            let tm = d.t[..head].iter().sum::<f64>() / m;
            let dm = ds[..head].iter().sum::<f64>() / m;
            let (mut stt, mut std) = (0.0, 0.0);
            for (t, x) in d.t[..head].iter().zip(&ds[..head]) {
                stt += (t - tm) * (t - tm);
                std += (t - tm) * (x - dm);
            }
            let slope = if stt > 0.0 { std / stt } else { 0.0 };
            let dev: Vec<f64> = (0..head)
                .map(|i| ds[i] - dm - slope * (d.t[i] - tm))
                .collect();
            robust_sigma(&dev).max(1e-4)
        };
        let mut out: Vec<Nominal> = Vec::new();
        for departure in [false, true] {
            let contacts: Vec<Contact> = self
                .unit_rows
                .iter()
                .map(|&(a, b)| self.initial_contact(a, b, &ds, &us, offset, noise, k, r, departure))
                .collect();
            let nom = Nominal::new(offset, contacts);
            if out.iter().all(|o| {
                o.contacts
                    .iter()
                    .zip(&nom.contacts)
                    .any(|(x, y)| (x.h - y.h).abs() > 2.0 * noise.max(0.5))
            }) {
                out.push(nom);
            }
        }
        out
    }

    #[allow(clippy::too_many_arguments)]
    fn initial_contact(
        &self,
        a: usize,
        b: usize,
        ds: &[f64],
        us: &[f64],
        offset: f64,
        noise: f64,
        k: f64,
        r: f64,
        departure: bool,
    ) -> Contact {
        let f: Vec<f64> = (a..b).map(|i| -k * (ds[i] - offset)).collect();
        let z: Vec<f64> = (a..b).map(|i| us[i] - (ds[i] - offset)).collect();
        let t: Vec<f64> = self.data.t[a..b].to_vec();
        let f_max = f.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let thr = (5.0 * k * noise).max(0.05 * f_max);
        let none = Contact {
            h: z.iter().copied().fold(f64::INFINITY, f64::min) - 10.0 * r - 1e3,
            k_a: 0.0,
            c_a: 0.0,
        };
        if !(f_max > thr) {
            return none;
        }
        // The first sample past the threshold, and the last one at the free level before it.
        let Some(ic) = f.iter().position(|&x| x > thr) else {
            return none;
        };
        let i0 = (0..ic).rev().find(|&i| f[i] <= k * noise).unwrap_or(0);
        if departure {
            // The first sample off the free level by 5 σ either way, before the force rise.
            let Some(id) = f[..=ic].iter().position(|&x| x.abs() > 5.0 * k * noise) else {
                return none;
            };
            let h = z[id];
            let (k_a, c_a, _) = regress_bed(&t, &f, &z, h, r);
            if !(k_a > 0.0) {
                return none;
            }
            return Contact { h, k_a, c_a };
        }
        let z_lo = z[ic];
        let back = (z[i0] - z[ic]).abs().max(2.0 * noise);
        let z_hi = z_lo + 2.0 * back + 1.0;
        // The deepest point: the fit uses the loading part up to it and the unloading after.
        let fit_at = |h: f64| -> (f64, f64, f64) { regress_bed(&t, &f, &z, h, r) };
        let h = minimize(|h| fit_at(h).2, z_lo, z_hi, 60);
        let (k_a, c_a, _) = fit_at(h);
        if !(k_a > 0.0) {
            return none;
        }
        Contact { h, k_a, c_a }
    }

    /// Median sampling rate (Hz).
    pub fn fs_hz(&self) -> f64 {
        1.0 / (self.dt_us * TIME)
    }
}

/// The free approach's baseline of a force curve when it carries an interference wave
/// (`identify::baseline`); `None` for other modes, without a wave, or when the curve's free
/// part cannot be found (the search then works on the recording as it is).
fn interference_wave(rec: &Recording) -> Option<crate::identify::force_curve::Baseline> {
    if rec.meta.mode != crate::recording::Mode::ForceCurve {
        return None;
    }
    let path = std::path::Path::new("recording");
    let free =
        crate::identify::force_curve::free_part(rec, path, crate::identify::CONTACT_SIGMA).ok()?;
    free.baseline.wave.is_some().then_some(free.baseline)
}

/// Units of a recording without a `tap` column: one per contact episode. The deflection is
/// smoothed over 1/200 of the recording; an episode is a run where it leaves the free level
/// (the median of the first tenth) downwards — the bed pushing — by more than a third of its
/// largest such excursion, runs less than 4 smoothing widths apart joined, that reaches half
/// of that excursion. Only the samples the full window smooths count (at the ends it is
/// shortened, and a swing of the excitation there read as a touch). Two episodes are cut
/// where, between them, the base comes closest to where it was in the first tenth (free).
/// One episode (a force curve, one tap) gives one unit.
fn contact_episodes(d: &[f64], u: &[f64]) -> Vec<(usize, usize)> {
    let n = d.len().min(u.len());
    let w = (n / 400).max(2);
    if n <= 2 * w + 1 {
        return vec![(0, n)];
    }
    let ds = moving_average(d, w);
    let head = (n / 10).max(8).min(n);
    let free = median(&ds[..head]);
    let u_free = median(&u[..head]);
    // The bed pushes the tip up: D below its free level (a pull on the retract is not a touch).
    let dev: Vec<f64> = ds.iter().map(|x| free - x).collect();
    let interior = w..n - w;
    let peak = dev[interior.clone()].iter().copied().fold(0.0f64, f64::max);
    if !(peak > 0.0) {
        return vec![(0, n)];
    }
    let on: Vec<bool> = dev
        .iter()
        .enumerate()
        .map(|(i, &x)| interior.contains(&i) && x > peak / 3.0)
        .collect();
    let runs = super::noise::runs(&on);
    // Episodes separated by at least 4 smoothing widths of free data.
    let mut episodes: Vec<(usize, usize)> = Vec::new();
    for (a, b) in runs {
        match episodes.last_mut() {
            Some(last) if a - last.1 < 8 * w => last.1 = b,
            _ => episodes.push((a, b)),
        }
    }
    // A touch of the same recording pushes about as far as the deepest one (the taps go to
    // one set depth, a curve to one set force); an episode that reaches less than half of
    // it is the excitation's swing or the ringing after a release, not a touch.
    episodes.retain(|&(a, b)| dev[a..b].iter().copied().fold(0.0f64, f64::max) >= 0.5 * peak);
    if episodes.len() < 2 {
        return vec![(0, n)];
    }
    // Not halfway: the retract's viscous pull can bring D back to its free level while the
    // tip still indents (refsim's nonlinear-stiffness s9, a 12 kHz lever tapped at 11 kHz,
    // was cut there, mid-retract, and half of its contact fitted as free at 7× the noise);
    // where the base is back at its free height the tip has left.
    let mut cuts = vec![0];
    for pair in episodes.windows(2) {
        let gap = pair[0].1..pair[1].0;
        let cut = gap
            .clone()
            .min_by(|&i, &j| (u[i] - u_free).abs().total_cmp(&(u[j] - u_free).abs()))
            .unwrap_or(gap.start);
        cuts.push(cut);
    }
    cuts.push(n);
    cuts.windows(2).map(|c| (c[0], c[1])).collect()
}

/// The pseudo-residual whose square is twice Huber's loss at scale `c`: itself within ±c,
/// growing as √(2c|r| − c²) beyond, so that a gross misfit (a tether's rupture the
/// vocabulary has no term for) weighs linearly, not quadratically.
#[inline]
pub fn huber_residual(r: f64, c: f64) -> f64 {
    let a = r.abs();
    if a <= c {
        r
    } else {
        r.signum() * (2.0 * c * a - c * c).sqrt()
    }
}

/// Least squares of the quasi-static bed law `F = k_a·V(h − Z) + c_a·A(h − Z)·δ̇` at height
/// h over every sample (free ones have V = 0 and pull the fit to F = 0 there): (k_a, c_a ≥ 0,
/// SSR).
fn regress_bed(t: &[f64], f: &[f64], z: &[f64], h: f64, r: f64) -> (f64, f64, f64) {
    let n = f.len();
    let (mut svv, mut sva, mut saa, mut sfv, mut sfa, mut sff) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..n {
        let dl = h - z[i];
        let v = cap_volume(r, dl);
        let rate = if i > 0 && i + 1 < n {
            -(z[i + 1] - z[i - 1]) / (t[i + 1] - t[i - 1])
        } else {
            0.0
        };
        let ar = contact_area(r, dl) * rate;
        svv += v * v;
        sva += v * ar;
        saa += ar * ar;
        sfv += f[i] * v;
        sfa += f[i] * ar;
        sff += f[i] * f[i];
    }
    two_column_nonneg(svv, sva, saa, sfv, sfa, sff)
}

#[cfg(test)]
mod tests {
    use super::contact_episodes;

    /// A tap sampled at 500 kHz (nm): the base U from 80 nm above the surface down to 140
    /// nm into it and back (touch at 1 200, turn at 5 600, free again at 6 300), a free
    /// lever swinging at 2.7 kHz, the contact pushing D down by `push`; on the retract the
    /// viscous pull brings D back to its free level while the tip still indents, and the
    /// release starts a ring of `ring`. (D, U).
    fn tap(swing: f64, push: f64, ring: f64) -> (Vec<f64>, Vec<f64>) {
        let (touch, turn, free) = (1200usize, 5600usize, 6300usize);
        (0..7000usize)
            .map(|i| {
                let tone = (2.0 * std::f64::consts::PI * 2.7e3 * i as f64 / 500e3).sin();
                let x = i as f64;
                let u = if i < touch {
                    80.0 - 80.0 * x / touch as f64
                } else if i < turn {
                    -140.0 * (x - touch as f64) / (turn - touch) as f64
                } else if i < free + 200 {
                    -140.0 + 220.0 * (x - turn as f64) / (free + 200 - turn) as f64
                } else {
                    80.0
                };
                let d = if (touch..turn).contains(&i) {
                    -push * (x - touch as f64) / (turn - touch) as f64
                } else if i >= free {
                    (swing + ring * (-((i - free) as f64) / 300.0).exp()) * tone
                } else if i >= turn {
                    0.0
                } else {
                    swing * tone
                };
                (d, u)
            })
            .unzip()
    }

    #[test]
    fn one_tap_is_cut_only_where_the_base_is_free() {
        // The ringing after the release crosses a third of the push, not half of it.
        let (d, u) = tap(1.0, 10.0, 3.5);
        assert_eq!(contact_episodes(&d, &u), vec![(0, d.len())]);
        // A free swing of 60 % of the push, and a ring beyond half of it, read as touches of
        // their own; but each cut lies where the base is back at its free height — not
        // halfway between, where the retract's pull hides that the tip still indents.
        for (swing, ring) in [(6.0, 0.0), (1.0, 8.0)] {
            let (d, u) = tap(swing, 10.0, ring);
            let units = contact_episodes(&d, &u);
            assert!(units.len() > 1, "{units:?}");
            for &(_, b) in &units[..units.len() - 1] {
                assert!(u[b] > 0.0, "{units:?}: a cut at U = {} nm", u[b]);
            }
        }
    }

    #[test]
    fn two_taps_of_like_depth_are_two_units() {
        let (mut d, mut u) = tap(0.5, 10.0, 0.0);
        let (d2, u2) = tap(0.5, 8.0, 0.0);
        d.extend(d2);
        u.extend(u2);
        let units = contact_episodes(&d, &u);
        assert_eq!(units.len(), 2, "{units:?}");
        // The cut lies in the free stretch between the two contacts.
        assert!((6300..8200).contains(&units[0].1), "{units:?}");
    }
}
