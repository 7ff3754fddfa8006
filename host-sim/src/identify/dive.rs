//! DIVE recordings: one or more taps, each identified as the controller does at its end.
//!
//! Three streaming passes over the file, memory bounded by the number of taps:
//!
//! 1. **Survey.** Taps are the runs of the `tap` column, or, without it, the spans from one
//!    release of the sample to the next (contact detection). In each tap the core's contact
//!    detector runs on D less the mean free deflection so far (its thresholds raised above the
//!    free deflection's noise when that is larger than the controller's γ), which gives the
//!    contact height h = Z(t₁) and the free deflection D₀. The *dwell* is found in the data:
//!    the run of samples around the deepest slow tip position (Z smoothed over two 1 ms boxcars,
//!    which removes the excitation tones) that stays within 5 % of the depth (at least 5 nm) of
//!    it — the hold at constant depth where the controller estimates. The survey also measures
//!    the regressor's typical size for the estimator's normalisation, and checks the rate.
//! 2. **Estimation.** [`visco_core::observer::Observer`] (f64) replays every sample: prefilters
//!    and regressor continuously, the contact detector re-armed per tap, the estimator
//!    (least squares with forgetting, memory 10 ms) restarted at the dwell's start from the
//!    previous tap's estimates, and the estimates averaged over the last `--readout` of the
//!    dwell, as the controller's read-out. Offset form (default) θ = [c, k, k·(h_bed − z₀)],
//!    or the paper's (13) θ = [c, k] with δ = h − Z.
//! 3. **Fit.** Per tap, the nominal model — the plant (cantilever, sphere, element bed) on a flat
//!    bed patch with the identified per-element values, at the surface the tap identified — is
//!    driven by the recorded U; its D plus D₀ against the recorded D gives the misfit.
//!
//! Why the plant and not an aggregate Kelvin–Voigt contact as the nominal model: the aggregate
//! (10) holds only while the tip is fully submerged (the active set fixed); on the approach and
//! the retract the tip is partly in the bed and the force is the sphere's, not k·δ. The plant
//! with the per-element values reproduces the identified aggregate exactly in the dwell (same
//! n, same mean sag, by construction) and the sphere-on-bed physics everywhere else, which is
//! the paper's model and the one `diagnose` extends.
//!
//! Per-element values (5.2): n elements under the tip at the read-out depth (the continuum
//! π a²/pitch², or the exact count on `--lattice-origin`'s lattice), `c/n`; `k/n` for the
//! offset form, `(k/n)·δ/(δ − s̄)` (32) for the paper's, s̄ the mean sag (R/3 submerged).

use std::ops::Range;
use std::path::Path;

use visco_core::contact::ContactState;
use visco_core::geometry::{contact_radius, mean_sag, ElementCount, Lattice};
use visco_core::observer::{Observer, ObserverConfig};
use visco_core::{Cantilever, DiveRegressor};

use super::error::{IdentifyError, Result};
use super::files::{push_num, Staged};
use super::replay::{self, BlockTrack, FoundContact, FreeContact, PhiProbe, PhiTypical, Smoother};
use super::report as rep;
use super::signal::Summary;
use super::{Options, Outputs};
use crate::recording::{RecordingReader, Row};
use crate::report::Num;
use crate::sample::Sample;

/// Rows of the series CSV at most (the whole recording, decimated).
const SERIES_ROWS: u64 = 100_000;

/// One tap, as identified.
#[derive(Debug, Clone)]
pub struct DiveTap {
    /// Position in the recording (0, 1, …).
    pub index: usize,
    /// The `tap` column's value, if the recording has one.
    pub label: Option<u32>,
    /// Rows of the tap (0-based data rows).
    pub rows: Range<u64>,
    /// Time of the first and last row (s).
    pub t_span_s: (f64, f64),
    /// Lateral position over the read-out (m).
    pub x_m: f64,
    /// Lateral position over the read-out (m).
    pub y_m: f64,
    /// The contact found by the survey.
    pub contact: Option<FoundContact>,
    /// Contact height h = Z(t₁) used (m).
    pub contact_height_m: f64,
    /// The dwell (estimation window) and its read-out (rows).
    pub window: Option<Range<u64>>,
    /// The read-out rows.
    pub readout: Option<Range<u64>>,
    /// Slow tip position at the hold (m).
    pub hold_z_m: f64,
    /// Aggregate damping ĉ (N·s/m), read-out mean.
    pub c_ns_per_m: f64,
    /// Aggregate spring constant k̂ (N/m), read-out mean.
    pub k_n_per_m: f64,
    /// θ̂₃ = k̂·(h_bed − z₀) of the offset form (N); 0 for the paper's.
    pub offset_n: f64,
    /// Height of the element bed under the tip: z₀ + θ̂₃/k̂ (offset form), h (paper's) (m).
    pub bed_height_m: f64,
    /// Surface height: bed + mean sag (offset form), h (paper's) (m).
    pub surface_height_m: f64,
    /// Mean apex depth below h over the read-out, h − Z/Λ (m).
    pub depth_m: f64,
    /// Smallest and largest apex depth over the read-out (m).
    pub depth_range_m: (f64, f64),
    /// Elements under the tip n, and their mean sag s̄ (m).
    pub elements: f64,
    /// Mean sag s̄ (m).
    pub mean_sag_m: f64,
    /// Per-element damping (N·s/m).
    pub c_element_ns_per_m: f64,
    /// Per-element spring (N/m).
    pub k_element_n_per_m: f64,
    /// Samples averaged in the read-out.
    pub samples: u64,
    /// Remarks: `no contact`, `short dwell`, `projected`, `not fully submerged`, ….
    pub flags: Vec<String>,
    /// RMS misfit of the fit over the tap's rows (m).
    pub rms_misfit_m: f64,
    /// RMS misfit over the dwell (m).
    pub rms_misfit_dwell_m: f64,
}

impl DiveTap {
    /// One line for the terminal.
    pub fn summary(&self) -> String {
        match self.contact {
            None => format!("tap {}: no contact", self.index),
            Some(_) => format!(
                "tap {} at ({:.3e}, {:.3e}) m: contact {:.4e} m, c = {:.4e} N*s/m, k = {:.4e} N/m \
                 (per element {:.4e}, {:.4e}; n = {:.1}), misfit {:.3e} m{}",
                self.index,
                self.x_m,
                self.y_m,
                self.contact_height_m,
                self.c_ns_per_m,
                self.k_n_per_m,
                self.c_element_ns_per_m,
                self.k_element_n_per_m,
                self.elements,
                self.rms_misfit_m,
                if self.flags.is_empty() {
                    String::new()
                } else {
                    format!(" [{}]", self.flags.join(", "))
                }
            ),
        }
    }

    fn to_json(&self, t_of: impl Fn(u64) -> f64) -> rep::DiveTapJson {
        let rows = |r: &Range<u64>| rep::rows(r.start, r.end);
        // Without contact there is nothing to estimate: the three headline values are null.
        let if_contact = |v: f64| Num(if self.contact.is_some() { v } else { f64::NAN });
        rep::DiveTapJson {
            index: self.index as u64,
            tap: self.label,
            rows: rows(&self.rows),
            t_start_s: self.t_span_s.0,
            t_end_s: self.t_span_s.1,
            x_m: self.x_m.into(),
            y_m: self.y_m.into(),
            contact: self.contact.is_some(),
            contact_height_m: if_contact(self.contact_height_m),
            c_ns_per_m: if_contact(self.c_ns_per_m),
            k_n_per_m: if_contact(self.k_n_per_m),
            at_contact: self.contact.as_ref().map(|c| rep::DiveTapContact {
                contact_t_s: t_of(c.row),
                offset_n: self.offset_n.into(),
                bed_height_m: self.bed_height_m.into(),
                surface_height_m: self.surface_height_m.into(),
                depth_m: self.depth_m.into(),
                depth_range_m: [self.depth_range_m.0.into(), self.depth_range_m.1.into()],
                elements_under_tip: self.elements.into(),
                mean_sag_m: self.mean_sag_m.into(),
                c_element_ns_per_m: self.c_element_ns_per_m.into(),
                k_element_n_per_m: self.k_element_n_per_m.into(),
                free_deflection_m: c.d0_m.into(),
                dwell: match (&self.window, &self.readout) {
                    (Some(w), Some(r)) => Some(rep::Dwell {
                        rows: rows(w),
                        t_start_s: t_of(w.start),
                        t_end_s: t_of(w.end.saturating_sub(1)),
                        hold_z_m: self.hold_z_m.into(),
                        readout_t_start_s: t_of(r.start),
                        readout_samples: self.samples,
                    }),
                    _ => None,
                },
            }),
            rms_misfit_m: self.rms_misfit_m.into(),
            rms_misfit_dwell_m: self.rms_misfit_dwell_m.into(),
            flags: self.flags.clone(),
        }
    }
}

/// What a DIVE recording gives.
#[derive(Debug, Clone)]
pub struct DiveResult {
    /// The mode-specific part of the report.
    pub json: rep::DiveReport,
    /// RMS misfit over the whole recording (m).
    pub rms_misfit_m: f64,
    /// The taps.
    pub taps: Vec<DiveTap>,
    /// The observer configuration the replay ran with.
    pub observer: ObserverConfig,
}

/// A tap as the survey sees it.
struct SurveyTap {
    label: Option<u32>,
    start: u64,
    end: u64,
    t0: f64,
    t1: f64,
    contact: Option<FoundContact>,
    engaged: bool,
    released: bool,
    track: Option<BlockTrack>,
    window: Option<(u64, u64, f64)>,
}

impl SurveyTap {
    fn new(label: Option<u32>, start: u64, t0: f64, rows_per_block: u64) -> Self {
        SurveyTap {
            label,
            start,
            end: start,
            t0,
            t1: t0,
            contact: None,
            engaged: false,
            released: false,
            track: Some(BlockTrack::new(start, rows_per_block)),
            window: None,
        }
    }

    /// The dwell: around the deepest slow Z after contact, within 5 % of the depth (≥ 5 nm).
    fn finalize(&mut self) {
        if let (Some(c), Some(track)) = (self.contact, self.track.take()) {
            let h = c.h_m;
            self.window = track
                .hold_around_minimum(c.row, |lo| (0.05 * (h - lo)).max(5e-9))
                .map(|(a, e, lo)| (a.max(c.row), e.min(self.end), lo))
                .filter(|(a, e, _)| e > a);
        }
        self.track = None;
    }
}

struct Survey {
    rows: u64,
    fs: f64,
    taps: Vec<SurveyTap>,
    phi: PhiTypical,
    u_min: f64,
    u_max: f64,
    by_tap_column: bool,
    clip: Clip,
}

/// Rows at the extremes of D: many rows at exactly the lowest or highest value are an ADC at
/// its full scale, and those rows are not measurements.
#[derive(Clone, Copy, Debug)]
pub struct Clip {
    /// Lowest D and how many rows hold it.
    pub low: (f64, u64),
    /// Highest D and how many rows hold it.
    pub high: (f64, u64),
}

impl Clip {
    const ROWS: u64 = 20;

    fn new() -> Self {
        Clip {
            low: (f64::INFINITY, 0),
            high: (f64::NEG_INFINITY, 0),
        }
    }

    fn add(&mut self, d: f64) {
        if d < self.low.0 {
            self.low = (d, 1);
        } else if d == self.low.0 {
            self.low.1 += 1;
        }
        if d > self.high.0 {
            self.high = (d, 1);
        } else if d == self.high.0 {
            self.high.1 += 1;
        }
    }

    /// Whether `d` is a clipped reading.
    pub fn clipped(&self, d: f64) -> bool {
        (self.low.1 >= Self::ROWS && d == self.low.0)
            || (self.high.1 >= Self::ROWS && d == self.high.0)
    }

    /// Whether anything is clipped.
    pub fn any(&self) -> bool {
        self.low.1 >= Self::ROWS || self.high.1 >= Self::ROWS
    }

    /// For the report: `None` when nothing is clipped.
    pub fn to_json(&self) -> Option<rep::Clipped> {
        if !self.any() {
            return None;
        }
        Some(rep::Clipped {
            low_m: self.low.0,
            rows_at_low: self.low.1,
            high_m: self.high.0,
            rows_at_high: self.high.1,
            note: "rows at exactly the extreme deflection (ADC at full scale) are not \
                   measurements: the estimator skips them, as the controller skips saturated input"
                .into(),
        })
    }
}

fn survey(path: &Path, cant: &Cantilever) -> Result<Survey> {
    let mut reader = RecordingReader::open(path)?;
    let meta_fs = reader.header().meta.sample_rate_hz;
    let has_tap = reader.header().columns.has_tap;
    let w = ((1e-3 * meta_fs).round() as usize).max(3);
    let rows_per_block = ((20e-6 * meta_fs).round() as u64).max(1);
    let mut sz = Smoother::new(w);
    let mut sd = Smoother::new(w);
    let mut probe = PhiProbe::new(cant, replay::lambda_s(cant), meta_fs);
    let mut phi = PhiTypical::default();
    let mut contact = FreeContact::new(meta_fs);
    let mut dt = Summary::default();
    let (mut u_min, mut u_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut clip = Clip::new();
    let mut taps: Vec<SurveyTap> = Vec::new();
    let mut cur: Option<SurveyTap> = None;
    let mut row = Row::default();
    let mut i: u64 = 0;
    let mut t_prev = f64::NAN;
    while reader.read_row(&mut row)? {
        if i > 0 {
            dt.add(row.t_s - t_prev);
        }
        t_prev = row.t_s;
        u_min = u_min.min(row.u_m);
        u_max = u_max.max(row.u_m);
        clip.add(row.d_m);
        let boundary = match &cur {
            None => true,
            Some(c) if has_tap => row.tap != c.label,
            Some(c) => c.released,
        };
        if boundary {
            if let Some(mut c) = cur.take() {
                c.end = i;
                taps.push(c);
            }
            cur = Some(SurveyTap::new(row.tap, i, row.t_s, rows_per_block));
            contact = FreeContact::new(meta_fs);
        }
        let c = cur.as_mut().expect("a current tap");
        c.t1 = row.t_s;
        c.end = i + 1;
        if c.contact.is_none() {
            c.contact = contact.step(i, row.u_m, row.d_m);
        }
        let (v, p) = probe.step(row.u_m, row.d_m);
        if c.contact.is_some() && !c.released {
            phi.add(v, p);
        }
        if let Some((j, zs)) = sz.push(i, row.u_m - row.d_m) {
            // Row j belongs to the current tap or to one closed less than a window ago.
            if j >= c.start {
                if let Some(t) = c.track.as_mut() {
                    t.push(j, zs);
                }
            } else if let Some(t) = taps.iter_mut().rev().find(|t| j >= t.start) {
                if let Some(tr) = t.track.as_mut() {
                    tr.push(j, zs);
                }
            }
        }
        if let Some((j, ds)) = sd.push(i, row.d_m) {
            if let Some(fc) = c.contact {
                if j >= fc.row {
                    let rel = ds - fc.d0_m;
                    if rel < -fc.gamma_plus_m {
                        c.engaged = true;
                    } else if c.engaged && rel > -fc.gamma_m {
                        c.released = true;
                    }
                }
            }
        }
        // Taps whose rows have all been smoothed are complete.
        let done_below = (i + 1).saturating_sub(sz.delay());
        for t in taps.iter_mut().rev() {
            if t.track.is_none() {
                break;
            }
            if t.end <= done_below {
                t.finalize();
            }
        }
        i += 1;
    }
    if let Some(mut c) = cur.take() {
        c.end = i;
        taps.push(c);
    }
    for t in taps.iter_mut() {
        if t.track.is_some() {
            t.finalize();
        }
    }
    let fs = replay::check_rate(path, meta_fs, &dt)?;
    Ok(Survey {
        rows: i,
        fs,
        taps,
        phi,
        u_min,
        u_max,
        by_tap_column: has_tap,
        clip,
    })
}

/// Elements under the tip and their mean sag at (x, y) and apex depth δ.
fn element_count(opts: &Options, x: f64, y: f64, r: f64, delta: f64) -> (f64, f64, &'static str) {
    let p = opts.element_pitch_m;
    match opts.lattice_origin_m {
        Some(o) => {
            let l = Lattice {
                pitch_x: p,
                pitch_y: p,
                origin_x: o[0],
                origin_y: o[1],
            };
            let (n, s) = ElementCount::Lattice(l).at(x, y, r, delta);
            (n, s, "lattice")
        }
        None => {
            let (n, s) = ElementCount::Continuous {
                element_area: p * p,
            }
            .at(x, y, r, delta);
            (n, s, "continuum")
        }
    }
}

/// Identifies a DIVE recording (three passes) and stages its outputs.
pub(crate) fn identify(
    path: &Path,
    opts: &Options,
    out: &Outputs,
    staged: &mut Staged,
) -> Result<DiveResult> {
    let header = RecordingReader::open(path)?.header().clone();
    let meta = &header.meta;
    let (cant, cant_source) = replay::cantilever(meta, path)?;
    if cant.f0_hz() >= 0.25 * meta.sample_rate_hz {
        return Err(IdentifyError::new(
            path,
            format!(
                "the cantilever's resonance ({:.0} Hz) is not below a quarter of the sampling \
                 rate ({} Hz): the dynamic model cannot be replayed at this rate",
                cant.f0_hz(),
                meta.sample_rate_hz
            ),
        ));
    }
    let r = meta.tip_radius_m;
    let sv = survey(path, &cant)?;
    let fs = sv.fs;
    if !sv.taps.iter().any(|t| t.contact.is_some()) {
        return Err(IdentifyError::new(
            path,
            format!(
                "no contact in the dive recording: in {} tap{} over {} rows the deflection never \
                 passes the contact threshold (γ = 0.3 nm of the low-passed deflection, or more \
                 above the noise)",
                sv.taps.len(),
                if sv.taps.len() == 1 { "" } else { "s" },
                sv.rows
            ),
        )
        .with_fix("a DIVE tap indents the sample: check the recording's sign of D (D < 0 when the sample pushes the tip up)"));
    }

    // Pass 2: the observer.
    let phi = sv.phi.rms([30.0, 50.0]);
    let ocfg = replay::observer_config(
        fs,
        &cant,
        r,
        opts.regressor,
        phi,
        phi,
        (sv.u_max - sv.u_min) + 2e-6,
    );
    let mut obs = Observer::<f64>::new(&ocfg)
        .map_err(|e| IdentifyError::new(path, format!("cannot replay: {e}")))?;
    let readout_rows = ((opts.readout_s * fs).round() as u64).max(1);
    let nominal = replay::nominal_contact(r);
    let mut warm = [nominal.c_ns_per_m, nominal.k_n_per_m];
    let mut taps: Vec<DiveTap> = sv
        .taps
        .iter()
        .enumerate()
        .map(|(index, s)| DiveTap {
            index,
            label: s.label,
            rows: s.start..s.end,
            t_span_s: (s.t0, s.t1),
            x_m: 0.0,
            y_m: 0.0,
            contact: s.contact,
            contact_height_m: s.contact.map_or(f64::NAN, |c| c.h_m),
            window: s.window.map(|(a, e, _)| a..e),
            readout: s.window.map(|(a, e, _)| {
                let len = e - a;
                let n = if len >= 2 * readout_rows {
                    readout_rows
                } else {
                    len / 2
                };
                (e - n.max(1))..e
            }),
            hold_z_m: s.window.map_or(f64::NAN, |w| w.2),
            c_ns_per_m: f64::NAN,
            k_n_per_m: f64::NAN,
            offset_n: f64::NAN,
            bed_height_m: f64::NAN,
            surface_height_m: f64::NAN,
            depth_m: f64::NAN,
            depth_range_m: (f64::NAN, f64::NAN),
            elements: f64::NAN,
            mean_sag_m: f64::NAN,
            c_element_ns_per_m: f64::NAN,
            k_element_n_per_m: f64::NAN,
            samples: 0,
            flags: Vec::new(),
            rms_misfit_m: f64::NAN,
            rms_misfit_dwell_m: f64::NAN,
        })
        .collect();
    {
        let mut reader = RecordingReader::open(path)?;
        let mut row = Row::default();
        let mut i: u64 = 0;
        let mut k = 0usize;
        let mut acc = [Summary::default(); 7];
        let mut flags = 0u32;
        let mut started = false;
        let mut confirmed: Option<f64> = None;
        while reader.read_row(&mut row)? {
            while k + 1 < taps.len() && i >= taps[k].rows.end {
                k += 1;
            }
            let tap = &mut taps[k];
            let first = i == tap.rows.start;
            if first {
                let s = &sv.taps[k];
                if let Some(c) = s.contact {
                    obs.set_deflection_offset(c.d0_m);
                    obs.set_contact_thresholds(c.gamma_m, c.gamma_plus_m);
                }
                if i == 0 {
                    obs.reset(row.u_m, row.d_m);
                }
                acc = [Summary::default(); 7];
                flags = 0;
                started = false;
                confirmed = None;
            }
            if let (Some(w), Some(c)) = (tap.window.clone(), tap.contact) {
                if i == w.start {
                    // The survey's detection: the core detector armed once the free deflection's
                    // noise floor was measured (the replay's own, re-armed at the tap's first
                    // row, may fire on the ringing of the previous retract).
                    let h = c.h_m;
                    let _ = confirmed;
                    tap.contact_height_m = h;
                    let z0 = tap.hold_z_m;
                    let delta = h - z0;
                    let theta3 = warm[1] * (h - mean_sag(r, delta) - z0);
                    obs.start_dive(Some(h), delta, [warm[0], warm[1], theta3]);
                    started = true;
                }
            }
            let d = if sv.clip.clipped(row.d_m) {
                f64::NAN
            } else {
                row.d_m
            };
            let o = obs.step(row.u_m, d);
            if first {
                obs.restart_contact();
            }
            if let ContactState::Confirmed { h } = o.contact {
                if !first {
                    confirmed.get_or_insert(h);
                }
            }
            if started {
                if let Some(ro) = &tap.readout {
                    if ro.contains(&i) {
                        acc[0].add(o.c_ns_per_m);
                        acc[1].add(o.k_n_per_m);
                        acc[2].add(o.offset_n);
                        acc[3].add(o.bed_height_m);
                        acc[4].add(o.depth_m);
                        acc[5].add(row.x_m.unwrap_or(0.0));
                        acc[6].add(row.y_m.unwrap_or(0.0));
                        flags |= o.flags;
                    }
                }
                if tap.window.as_ref().is_some_and(|w| i + 1 == w.end) {
                    obs.stop();
                    started = false;
                    tap.c_ns_per_m = acc[0].mean();
                    tap.k_n_per_m = acc[1].mean();
                    tap.offset_n = acc[2].mean();
                    tap.bed_height_m = acc[3].mean();
                    tap.depth_m = acc[4].mean();
                    tap.depth_range_m = (acc[4].min, acc[4].max);
                    tap.x_m = acc[5].mean();
                    tap.y_m = acc[6].mean();
                    tap.samples = acc[0].n;
                    if flags & visco_core::status::PROJECTED != 0 {
                        tap.flags.push("projected onto a bound".into());
                    }
                    if flags & visco_core::status::INPUT_INVALID != 0 {
                        tap.flags.push("deflection clipped in the read-out".into());
                    }
                    if flags & visco_core::status::EST_RESET != 0 {
                        tap.flags.push("estimator reset".into());
                    }
                    if tap.k_n_per_m > 0.0 {
                        warm = [tap.c_ns_per_m, tap.k_n_per_m];
                    }
                }
            }
            i += 1;
        }
    }

    // Per-element values and flags.
    for tap in taps.iter_mut() {
        let Some(_) = tap.contact else {
            tap.flags.push("no contact".into());
            continue;
        };
        let (Some(w), Some(ro)) = (&tap.window, &tap.readout) else {
            tap.flags.push("no dwell found".into());
            continue;
        };
        if (w.end - w.start) < 2 * readout_rows {
            tap.flags.push(format!(
                "short dwell ({:.1} ms): read-out shortened",
                (w.end - w.start) as f64 / fs * 1e3
            ));
        }
        let _ = ro;
        let delta = tap.depth_m;
        let (n, sag, _) = element_count(opts, tap.x_m, tap.y_m, r, delta);
        tap.elements = n;
        tap.mean_sag_m = sag;
        match opts.regressor {
            DiveRegressor::Offset => {
                tap.surface_height_m = tap.bed_height_m + sag;
                tap.k_element_n_per_m = tap.k_n_per_m / n;
            }
            DiveRegressor::Paper => {
                tap.surface_height_m = tap.contact_height_m;
                tap.k_element_n_per_m = tap.k_n_per_m / n * delta / (delta - sag);
            }
        }
        tap.c_element_ns_per_m = tap.c_ns_per_m / n;
        if tap.depth_range_m.0 < r {
            tap.flags.push(format!(
                "not fully submerged (depth down to {:.1} nm < R = {:.1} nm): the aggregate \
                 model (10) is not exact there",
                tap.depth_range_m.0 * 1e9,
                r * 1e9
            ));
        }
    }

    // Pass 3: the fit.
    let stride = sv.rows.div_ceil(SERIES_ROWS).max(1);
    let detail_tap = taps
        .iter()
        .position(|t| t.readout.is_some() && t.k_n_per_m > 0.0);
    let mut series = staged.create(&out.path("fit.csv"))?;
    series.write_str(&format!(
        "# visco identify: dive fit, recorded vs simulated deflection, every {stride} row(s)\n\
         t_s,u_m,d_recorded_m,d_simulated_m,residual_m,tap\n"
    ))?;
    let mut detail = match detail_tap {
        Some(_) => {
            let mut w = staged.create(&out.path("fit_detail.csv"))?;
            w.write_str(
                "# visco identify: dive fit over the first tap's read-out, every row\n\
                 t_s,u_m,d_recorded_m,d_simulated_m,residual_m,tap\n",
            )?;
            Some(w)
        }
        None => None,
    };
    let mut total = Summary::default();
    let mut env = super::figures::Envelope::new(sv.rows);
    let mut detail_rows: Vec<(f64, f64, f64)> = Vec::new();
    {
        let mut reader = RecordingReader::open(path)?;
        let mut row = Row::default();
        let mut i: u64 = 0;
        let mut k = 0usize;
        let mut plant = None;
        let mut d0 = 0.0;
        let mut tap_acc = Summary::default();
        let mut dwell_acc = Summary::default();
        let mut line = String::new();
        let mut buf = String::new();
        let mut detail_buf = String::new();
        while reader.read_row(&mut row)? {
            while k + 1 < taps.len() && i >= taps[k].rows.end {
                taps[k].rms_misfit_m = tap_acc.rms();
                taps[k].rms_misfit_dwell_m = dwell_acc.rms();
                tap_acc = Summary::default();
                dwell_acc = Summary::default();
                k += 1;
            }
            let tap = &taps[k];
            if i == tap.rows.start {
                let (mut p, off) = tap_plant(tap, &cant, r, fs, opts)?;
                p.settle(row.u_m, tap.x_m, tap.y_m);
                // The cantilever carries on from the last tap (it may still ring).
                if let Some(prev) = &plant {
                    let prev: &crate::plant::Plant = prev;
                    p.set_tip_state_nm(
                        prev.tip_z_m() / visco_core::units::LENGTH,
                        prev.tip_velocity_m_per_s() * visco_core::units::TIME
                            / visco_core::units::LENGTH,
                    );
                }
                plant = Some(p);
                d0 = off;
            }
            let p = plant.as_mut().expect("a plant per tap");
            let sim = p.step(row.u_m, tap.x_m, tap.y_m) + d0;
            let resid = row.d_m - sim;
            tap_acc.add(resid);
            total.add(resid);
            env.push(row.t_s, row.d_m, sim);
            if tap.window.as_ref().is_some_and(|w| w.contains(&i)) {
                dwell_acc.add(resid);
            }
            let label = tap.label.map_or(k as f64, |l| l as f64);
            let write_line = |line: &mut String| {
                line.clear();
                for v in [row.t_s, row.u_m, row.d_m, sim, resid] {
                    push_num(line, v);
                    line.push(',');
                }
                push_num(line, label);
                line.push('\n');
            };
            if i % stride == 0 {
                write_line(&mut line);
                buf.push_str(&line);
                if buf.len() > 1 << 16 {
                    series.write_str(&buf)?;
                    buf.clear();
                }
            }
            if Some(k) == detail_tap && tap.readout.as_ref().is_some_and(|ro| ro.contains(&i)) {
                detail_rows.push((row.t_s, row.d_m, sim));
                write_line(&mut line);
                detail_buf.push_str(&line);
                if detail_buf.len() > 1 << 16 {
                    if let Some(w) = detail.as_mut() {
                        w.write_str(&detail_buf)?;
                    }
                    detail_buf.clear();
                }
            }
            i += 1;
        }
        taps[k].rms_misfit_m = tap_acc.rms();
        taps[k].rms_misfit_dwell_m = dwell_acc.rms();
        series.write_str(&buf)?;
        if let Some(w) = detail.as_mut() {
            w.write_str(&detail_buf)?;
        }
    }
    let series_path = series.path().to_path_buf();
    staged.finish(series)?;
    let detail_path = match detail {
        Some(w) => {
            let p = w.path().to_path_buf();
            staged.finish(w)?;
            Some(p)
        }
        None => None,
    };
    let name = path
        .file_name()
        .map_or(String::new(), |n| n.to_string_lossy().into_owned());
    let png = out.path("fit.png");
    super::figures::stage_overview(
        staged,
        &png,
        &format!("{name}: DIVE, the plant on each tap's identified bed"),
        &env,
    )?;
    let detail_png = match detail_tap {
        Some(k) => {
            let p = out.path("fit_detail.png");
            super::figures::stage_detail(
                staged,
                &p,
                &format!("{name}: tap {} read-out, every sample", taps[k].index),
                &detail_rows,
            )?;
            Some(p)
        }
        None => None,
    };

    // The report.
    let t_of = |row: u64| {
        // Uniform rate (checked): the first tap's start plus row / fs.
        sv.taps.first().map_or(0.0, |t| t.t0) + row as f64 / fs
    };
    let with: Vec<&DiveTap> = taps.iter().filter(|t| t.k_n_per_m > 0.0).collect();
    let stat = |f: &dyn Fn(&DiveTap) -> f64| {
        let mut s = Summary::default();
        for t in &with {
            s.add(f(t));
        }
        rep::Stat {
            mean: s.mean().into(),
            std: s.std().into(),
            min: Num(if s.n > 0 { s.min } else { f64::NAN }),
            max: Num(if s.n > 0 { s.max } else { f64::NAN }),
        }
    };
    let (_, _, counting) = element_count(opts, 0.0, 0.0, r, r);
    let j = rep::DiveReport {
        model: "cantilever first mode (2) on an aggregate Kelvin–Voigt contact (10), identified \
                per tap with the DIVE regression"
            .into(),
        cantilever: rep::CantileverJson::new(meta).used_from(cant_source),
        tip_radius_m: r,
        sample_rate_hz: fs,
        regressor: match opts.regressor {
            DiveRegressor::Offset => "offset: θ = [c, k, k·(h_bed − z₀)], no correction (32)",
            DiveRegressor::Paper => "paper (13): θ = [c, k], δ = h − Z, k per element by (32)",
        }
        .into(),
        segmentation: if sv.by_tap_column {
            "by the tap column"
        } else {
            "by contact detection (from one release of the sample to the next)"
        }
        .into(),
        per_element: rep::DivePerElement {
            element_pitch_m: opts.element_pitch_m,
            count: counting.into(),
            lattice_origin_m: opts.lattice_origin_m,
            how: "n elements under the tip at the read-out depth (continuum π a²/pitch² or \
                  the lattice's sites), c/n, and k/n (offset form) or (k/n)·δ/(δ − s̄) (32)"
                .into(),
        },
        replay: rep::DiveReplay {
            observer: replay::observer_json(&ocfg, replay::DIVE_MEMORY_S, &ocfg.dive_estimator),
            readout_s: opts.readout_s,
            dwell: "the samples around the deepest slow tip position (two 1 ms boxcars) within \
                    5 % of the depth (≥ 5 nm): the hold"
                .into(),
        },
        taps: taps.iter().map(|t| t.to_json(t_of)).collect(),
        summary: rep::DiveSummary {
            taps: taps.len() as u64,
            with_estimates: with.len() as u64,
            k_n_per_m: stat(&|t| t.k_n_per_m),
            c_ns_per_m: stat(&|t| t.c_ns_per_m),
            k_element_n_per_m: stat(&|t| t.k_element_n_per_m),
            c_element_ns_per_m: stat(&|t| t.c_element_ns_per_m),
            contact_height_m: stat(&|t| t.contact_height_m),
        },
        deflection_clipped: sv.clip.to_json(),
        notes: {
            let mut notes: Vec<String> = Vec::new();
            let none = taps.iter().filter(|t| t.contact.is_none()).count();
            if none > 0 {
                notes.push(format!("{none} tap(s) without contact: no estimates"));
            }
            if sv.clip.any() {
                notes.push(
                    "the deflection is clipped (ADC at full scale): those rows are skipped by \
                     the estimator and show in the misfit"
                        .into(),
                );
            }
            if opts.lattice_origin_m.is_none() {
                notes.push(
                    "per-element values use the continuum count π a²/pitch²; on a coarse \
                     lattice the sites under the tip differ from it by up to ~13 % (give \
                     --lattice-origin for the exact count)"
                        .into(),
                );
            }
            notes
        },
        rms_misfit_m: total.rms().into(),
        fit: rep::DiveFit {
            model: "the plant (cantilever, sphere, element bed) on a flat bed with each tap's \
                    per-element values and surface, driven by the recorded U, plus the tap's \
                    free deflection; noise and converters off"
                .into(),
            rms_misfit_m: total.rms().into(),
            series_csv: series_path.display().to_string(),
            series_stride_rows: stride,
            detail_csv: detail_path.map(|p| p.display().to_string()),
            figure_png: png.display().to_string(),
            detail_png: detail_png.map(|p| p.display().to_string()),
        },
    };
    Ok(DiveResult {
        json: j,
        rms_misfit_m: total.rms(),
        taps,
        observer: ocfg,
    })
}

/// The nominal plant of one tap and the free deflection to add to its D.
fn tap_plant(
    tap: &DiveTap,
    cant: &Cantilever,
    r: f64,
    fs: f64,
    opts: &Options,
) -> Result<(crate::plant::Plant, f64)> {
    let p = opts.element_pitch_m;
    let origin = opts.lattice_origin_m.unwrap_or([p / 2.0, p / 2.0]);
    let (x, y) = (tap.x_m, tap.y_m);
    let d0 = tap.contact.map_or(0.0, |c| c.d0_m);
    let margin = r + 2.0 * p;
    let i0 = ((x - margin - origin[0]) / p).floor();
    let j0 = ((y - margin - origin[1]) / p).floor();
    let n = ((2.0 * margin) / p).ceil() as usize + 2;
    let patch_origin = [origin[0] + i0 * p, origin[1] + j0 * p];
    let sample = if tap.k_n_per_m > 0.0 && tap.depth_m > 0.0 {
        let lattice = Lattice {
            pitch_x: p,
            pitch_y: p,
            origin_x: origin[0],
            origin_y: origin[1],
        };
        let delta = tap.depth_m;
        let fp = lattice.footprint(x, y, contact_radius(r, delta), r);
        let (n_el, sag) = if fp.count > 0 {
            (fp.count as f64, fp.mean_sag)
        } else {
            (tap.elements, tap.mean_sag_m)
        };
        let (surface, k_el) = match opts.regressor {
            DiveRegressor::Offset => (tap.bed_height_m + sag, tap.k_n_per_m / n_el),
            DiveRegressor::Paper => (
                tap.contact_height_m,
                tap.k_n_per_m / n_el * delta / (delta - sag),
            ),
        };
        Sample::flat(n, n, p, patch_origin, surface, tap.c_ns_per_m / n_el, k_el)
    } else {
        // No estimates: a free cantilever (the bed far below).
        Sample::flat(1, 1, p, [x, y], -1.0, 0.0, 0.0)
    }
    .map_err(|e| IdentifyError::new(Path::new("(nominal sample)"), e.to_string()))?;
    Ok((replay::fit_plant(cant, r, fs, sample)?, d0))
}
