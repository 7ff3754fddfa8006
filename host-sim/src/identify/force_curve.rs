//! Force curves: the Kelvin–Voigt element bed under a sphere, quasi-static.
//!
//! ## The model
//! A commercial force curve moves the base at µm/s and samples at kHz, far below the
//! cantilever's resonance: its inertia `M·Z̈` and damping `C·Ḋ` are negligible next to `K·D`
//! (the report computes both bounds), so the cantilever is a spring and the force on the tip is
//! `F = −K·(D − D₀(U))` with `D₀` the free deflection (offset, linear tilt and an interference
//! wave, from the free part of the approach). With a sphere of radius R pressed δ deep into the paper's bed of
//! spring–damper elements (per-area spring `k_a = k_element/pitch²`, damper
//! `c_a = c_element/pitch²`), summing the elements under the tip gives
//!
//! ```text
//! F = k_a·V(δ) + c_a·A(δ)·δ̇ = k_a·V(δ) + c_a·dV/dt,   δ = h − Z,  Z = U − (D − D₀)
//! ```
//!
//! with `V` the volume of the cap below the surface and `A = π a²` the contact area
//! ([`super::signal::cap_volume`], `dV/dδ = A`). It is linear in (k_a, c_a) once the contact
//! height h is known. As in the paper's (18), both sides are filtered instead of
//! differentiating: with `1/(λs + 1)`, `F_f = k_a·V_f + c_a·(V − V_f)/λ` holds exactly, and a
//! least-squares solve (f64 normal equations, `c_a ≥ 0`) gives (k_a, c_a). Samples out of
//! contact have `V = 0` and do not move the estimate.
//!
//! ## The contact point
//! 1. Baseline: `D₀ = b₀ + b₁·(U − U_ref)` fitted on the free part of the approach (offset
//!    only when that part is short), plus an optical-interference wave in U when the free part
//!    shows one ([`super::baseline`]); its robust σ is the noise.
//! 2. Threshold: going back from the end of the approach, the last sample still above
//!    `−n·σ` (n = `--contact-sigma`, 5) — the tip stays in contact from the next one on.
//! 3. Refined: h is the height that minimises the residual of the Kelvin–Voigt fit, searched
//!    between the threshold crossing (the force is past n·σ there, so the contact is no later)
//!    and twice the distance back to where the deflection left its free level.
//!    The free part is then redefined to end before the contact, and 1–3 repeat until stable.
//!
//! The rows of the fit are the approach and the retract while the sample still pushes. Holds
//! (`pause` segments) are left out: a Kelvin–Voigt bed cannot relax at constant depth, and a
//! stress-relaxation hold fitted with it gives a negative stiffness; the pull on the retract is
//! adhesion, which the model has no term for. Both stay in the misfit, where `diagnose` looks.
//!
//! The aggregate values at the deepest point are the tangent stiffness `k = k_a·A(δ_max)` and
//! `c = c_a·A(δ_max)` (what DIVE/SVE would identify there); per element `k_a·pitch²`.
//!
//! ## The fit
//! The same law simulated from the recorded U (quasi-static, semi-implicit in time): out of
//! contact D = D₀(U); in contact δ solves `K·(δ − h + U) + k_a·V(δ) + c_a·A·δ̇ = 0`; then
//! `D = δ − h + U + D₀(U)`, against the recorded D.

use std::ops::Range;
use std::path::Path;

use super::baseline::fit_baseline;
pub use super::baseline::{Baseline, Wave};
use super::error::{IdentifyError, Result};
use super::report as rep;
use super::signal::{cap_volume, contact_area, minimize, moving_average, FohLowPass};
use super::Options;
use crate::recording::{Metadata, Recording};

/// What `identify` finds in a force curve.
#[derive(Clone, Debug)]
pub struct ForceCurveFit {
    /// Rows of the approach (the first `extend` segment).
    pub approach: Range<usize>,
    /// The free deflection.
    pub baseline: Baseline,
    /// Contact height h: the tip position Z where the force starts (m).
    pub contact_height_m: f64,
    /// First row of the approach with the tip below h.
    pub contact_row: usize,
    /// Time of that row (s).
    pub contact_t_s: f64,
    /// U at that row (m).
    pub contact_u_m: f64,
    /// First row of the approach past the n·σ threshold (for good).
    pub threshold_row: usize,
    /// Per-area spring of the bed k_a (N/m³).
    pub k_a_n_per_m3: f64,
    /// Exponent p of F ∝ δ^p on the approach (10–90 % of its force); the element bed gives 2
    /// for δ ≪ R, Hertz 1.5.
    pub onset_exponent: f64,
    /// Per-area damper c_a (N·s/m³).
    pub c_a_ns_per_m3: f64,
    /// Largest depth reached, δ_max = h − Z (m), smoothed over 5 samples.
    pub max_depth_m: f64,
    /// Largest force −K·(D − D₀) (N), smoothed over 5 samples.
    pub max_force_n: f64,
    /// Force range max − min (N).
    pub force_range_n: f64,
    /// Deflection range of the recording (m).
    pub deflection_range_m: f64,
    /// Tangent stiffness at δ_max, k_a·A(δ_max) (N/m).
    pub k_n_per_m: f64,
    /// Damping at δ_max, c_a·A(δ_max) (N·s/m).
    pub c_ns_per_m: f64,
    /// Elements under the tip at δ_max, A/pitch².
    pub elements_at_max: f64,
    /// Element pitch used for per-element values (m).
    pub pitch_m: f64,
    /// Filter time constant λ of the regression (s).
    pub lambda_s: f64,
    /// Simulated D per row (m).
    pub simulated_d_m: Vec<f64>,
    /// RMS of recorded − simulated D over all rows (m).
    pub rms_misfit_m: f64,
    /// RMS misfit while the model or the data is in contact (m).
    pub rms_misfit_contact_m: f64,
    /// Per segment: number, kind, rows, RMS misfit (m).
    pub segments: Vec<(i64, String, usize, f64)>,
    /// Largest inertial and damping forces of the cantilever under the assumptions given.
    pub dynamics: Dynamics,
    /// The vendor's force channel against −K·D: largest difference (N) and channel range (N).
    pub vendor_force: Option<(f64, f64)>,
    /// Remarks for the report.
    pub notes: Vec<String>,
}

/// Bounds on the cantilever forces the quasi-static law leaves out.
#[derive(Clone, Debug)]
pub struct Dynamics {
    /// f₀ used (Hz) and where it comes from.
    pub f0_hz: f64,
    /// Q used.
    pub q: f64,
    /// Source of f₀ and Q.
    pub source: &'static str,
    /// Largest M·|Z̈| (N).
    pub inertial_n: f64,
    /// Largest C·|Ḋ| (N).
    pub damping_n: f64,
    /// The larger of the two over the force range of the curve.
    pub to_force_range: f64,
    /// The larger of the two as a deflection (F/K) over the deflection noise of the free
    /// approach: above 1 the recording could show what the quasi-static law leaves out.
    pub to_noise: f64,
    /// Whether the quasi-static law may neglect them: `to_noise < 1`.
    pub neglected: bool,
}

impl Dynamics {
    /// The larger of the inertial and damping bounds (N).
    pub fn worst_n(&self) -> f64 {
        self.inertial_n.max(self.damping_n)
    }

    /// Judges the bounds against the curve: its force range (N), the lever's spring
    /// constant (N/m) and the deflection noise (m). A force the noise hides cannot be told
    /// from it by any fit, so that is the line; the force-range ratio is reported beside.
    fn judge(mut self, force_range_n: f64, k_n_per_m: f64, noise_m: f64) -> Self {
        let worst = self.worst_n();
        self.to_force_range = worst / force_range_n;
        self.to_noise = worst / k_n_per_m / noise_m;
        // NaN (no noise measured) is not neglected.
        self.neglected = self.to_noise < 1.0;
        self
    }
}

/// A lower bound on f₀ and Q for levers used in force spectroscopy in liquid (soft levers of
/// 0.01–0.1 N/m have f₀ of a few kHz in water, Q ≈ 1–3): the worst case for the bounds.
const ASSUMED_F0_HZ: f64 = 1e3;
const ASSUMED_Q: f64 = 0.5;

/// Why a force curve's deflection has the wrong scale, if its approach spans more than 1.5×
/// the base's travel: pressed on a sample, a lever bends at most as far as its base moves (a
/// rigid sample: as far), so the spring constant a force column was divided by, or the
/// sensitivity a voltage was multiplied by, is wrong (an AFM Workshop curve given
/// k = 0.1 N/m spanned 8× its travel; the real files span 0.0002–0.08×). Spans between the
/// 1st and 99th percentiles, so that a spike does not count. identify and diagnose refuse it.
pub fn deflection_scale_error(rec: &Recording) -> Option<String> {
    let approach = find_approach(rec, Path::new("recording")).ok()?;
    let span = |v: &[f64]| -> f64 {
        let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        if s.len() < 2 {
            return 0.0;
        }
        s.sort_by(f64::total_cmp);
        let at = |q: f64| s[((s.len() - 1) as f64 * q).round() as usize];
        at(0.99) - at(0.01)
    };
    let (du, dd) = (span(&rec.u_m[approach.clone()]), span(&rec.d_m[approach]));
    (dd > 1.5 * du).then(|| {
        let k = rec.meta.cantilever_k_n_per_m;
        let k_from = rec
            .meta
            .get("spring_constant_source")
            .unwrap_or("the recording");
        format!(
            "on the approach the deflection spans {dd:.3e} m while the base travels {du:.3e} m \
             ({:.1}×): pressed on a sample a lever bends at most as far as its base moves, so \
             the deflection's scale is wrong — check the spring constant (k = {k} N/m, from \
             {k_from}) where the file gives a force, or the sensitivity where it gives a voltage",
            dd / du.max(1e-300)
        )
    })
}

/// Identifies a force curve held in memory.
pub fn identify(rec: &Recording, path: &Path, opts: &Options) -> Result<ForceCurveFit> {
    let n = rec.len();
    if n < 20 {
        return Err(IdentifyError::new(
            path,
            format!("a force curve needs at least 20 samples, the recording has {n}"),
        ));
    }
    if let Some(why) = deflection_scale_error(rec) {
        return Err(IdentifyError::new(path, why));
    }
    let k_cant = rec.meta.cantilever_k_n_per_m;
    let r = rec.meta.tip_radius_m;
    let t = &rec.t_s;
    let u = &rec.u_m;
    let d = &rec.d_m;
    let FreePart {
        approach,
        baseline,
        crossing,
    } = free_part(rec, path, opts.contact_sigma)?;
    let mut notes = Vec::new();
    let (i_cross, i_zero) = crossing;

    // Force and tip position against the baseline.
    let force: Vec<f64> = (0..n)
        .map(|i| -k_cant * (d[i] - baseline.under(u[i], d[i])))
        .collect();
    let z: Vec<f64> = (0..n)
        .map(|i| u[i] - (d[i] - baseline.under(u[i], d[i])))
        .collect();
    let z_s = moving_average(&z, 2);
    let dt_max = t.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
    // λ of the regression's filters: a few rows at least (the noise), 10 ms at most, and short
    // enough that their settling 3λ takes at most half of the approach's time in contact (a
    // JPK QI curve touches for ~1.5 ms of its 28 ms approach): a longer memory weighs the
    // contact's few rows against the retract's and leaves the fit ill-conditioned.
    let contact_s = t[approach.end.saturating_sub(1).max(i_zero)] - t[i_zero];
    let lambda = (4.0 * dt_max).max((contact_s / 6.0).min(0.01));

    // The contact height: search the residual between the threshold and twice the distance
    // back to where the deflection left zero.
    let z_lo = z_s[i_cross];
    let back = (2 * (i_cross - i_zero)).max(10);
    let i_hi = i_zero.saturating_sub(back).max(baseline.free_rows.end);
    let mut z_hi = z_s[i_hi];
    if !(z_hi > z_lo) {
        z_hi = z_lo + 10.0 * baseline.noise_m.max(1e-10);
    }
    // Rows of the fit: the approach, and the retract while the sample still pushes. Holds are
    // left out (a Kelvin–Voigt bed cannot relax at constant depth, and a hold is where that
    // shows), and so is the pull on the retract (adhesion, which the model has no term for);
    // both stay in the misfit.
    let kinds = row_kinds(rec, &approach);
    let mask: Vec<bool> = (0..n)
        .map(|i| match kinds[i] {
            RowKind::Approach => true,
            RowKind::Retract => force[i] > 0.0,
            RowKind::Hold | RowKind::Other => false,
        })
        .collect();
    let fit_at = |h: f64| regress(t, &force, &z, h, r, lambda, &mask);
    // Refined: the height that minimises the fit's residual, between the threshold crossing
    // (the force is past n·σ there: the contact is no later) and twice the distance back to
    // where the deflection left its free level.
    let h = minimize(|h| fit_at(h).2, z_lo, z_hi, 48);
    // The onset's power law F ∝ δ^p on the approach between 10 % and 90 % of its largest force.
    let exponent = onset_exponent(&force, &z, h, &approach);
    let (k_a, c_a, _) = fit_at(h);
    if !(k_a > 0.0) {
        return Err(IdentifyError::new(
            path,
            format!("the contact part gives no positive stiffness (k_a = {k_a:e} N/m³)"),
        ));
    }
    let span = z_hi - z_lo;
    if (h - z_hi).abs() < 0.02 * span {
        notes.push(
            "the contact height sits at the early end of its search range: the force rises \
             gradually before the threshold (long-range forces, a soft surface layer?)"
                .to_string(),
        );
    } else if (h - z_lo).abs() < 0.02 * span {
        notes.push(format!(
            "the contact height sits at the threshold crossing, the latest the data allow: \
             the element bed's V(δ) ∝ δ² onset would prefer a later contact, so the force \
             rises differently at first (F ∝ δ^{exponent:.2} on the approach, the bed gives 2)"
        ));
    }
    let contact_row = (approach.start..approach.end)
        .rev()
        .find(|&i| z_s[i] >= h)
        .map_or(approach.start, |i| i + 1);
    if contact_row <= baseline.free_rows.end || contact_row >= approach.end - 1 {
        return Err(IdentifyError::new(
            path,
            format!(
                "the contact point (row {}) is not inside the approach after its free part \
                 (rows {}–{})",
                contact_row + 1,
                baseline.free_rows.end + 1,
                approach.end
            ),
        ));
    }

    let depth: Vec<f64> = z.iter().map(|zz| h - zz).collect();
    let max_depth = moving_average(&depth, 2)
        .into_iter()
        .fold(f64::NEG_INFINITY, f64::max);
    let f_s = moving_average(&force, 2);
    let max_force = f_s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let min_force = f_s.iter().copied().fold(f64::INFINITY, f64::min);
    let area = contact_area(r, max_depth);
    let p = opts.element_pitch_m;

    // The fit: the quasi-static law driven by the recorded U.
    let (sim, sim_deflection) = simulate(t, u, &baseline, k_cant, h, k_a, c_a, r);
    let resid: Vec<f64> = (0..n).map(|i| d[i] - sim[i]).collect();
    let rms_all = super::signal::rms(resid.iter().copied());
    let in_contact = |i: usize| depth[i] > 0.0 || sim_deflection[i] < -1e-15;
    let rms_contact = super::signal::rms((0..n).filter(|&i| in_contact(i)).map(|i| resid[i]));
    let segments = segment_misfits(rec, &resid);
    let (dmin, dmax) = d
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });

    // What the quasi-static law leaves out: bounds on M·Z̈ and C·Ḋ.
    let dynamics = dynamics_bounds(rec, &z, &moving_average(d, 2)).judge(
        max_force - min_force,
        k_cant,
        baseline.noise_m,
    );
    let vendor_force = rec.extra_column("force_vendor_n").map(|f| {
        let diff = d
            .iter()
            .zip(f)
            .map(|(dd, fv)| (-k_cant * dd - fv).abs())
            .fold(0.0, f64::max);
        let range = f.iter().map(|x| x.abs()).fold(0.0, f64::max);
        (diff, range)
    });
    if baseline.linear
        && (baseline.tilt * (u[approach.start] - u[approach.end - 1])).abs()
            > 3.0 * baseline.noise_m
    {
        notes.push(format!(
            "the free deflection is tilted: {:.3e} m of D per m of U ({:.2} nm over the approach), \
             subtracted as part of the baseline",
            baseline.tilt,
            (baseline.tilt * (u[approach.start] - u[approach.end - 1])).abs() * 1e9
        ));
    }

    Ok(ForceCurveFit {
        approach,
        baseline,
        contact_height_m: h,
        contact_row,
        contact_t_s: t[contact_row],
        contact_u_m: u[contact_row],
        threshold_row: i_cross,
        k_a_n_per_m3: k_a,
        onset_exponent: exponent,
        c_a_ns_per_m3: c_a,
        max_depth_m: max_depth,
        max_force_n: max_force,
        force_range_n: max_force - min_force,
        deflection_range_m: dmax - dmin,
        k_n_per_m: k_a * area,
        c_ns_per_m: c_a * area,
        elements_at_max: area / (p * p),
        pitch_m: p,
        lambda_s: lambda,
        simulated_d_m: sim,
        rms_misfit_m: rms_all,
        rms_misfit_contact_m: rms_contact,
        segments,
        dynamics,
        vendor_force,
        notes,
    })
}

/// The approach, its free part's baseline and the contact's threshold crossing
/// `(i_cross, i_zero)`.
pub struct FreePart {
    pub approach: Range<usize>,
    pub baseline: Baseline,
    pub crossing: (usize, usize),
}

/// Finds the approach and fits the baseline on its free part, iterated with the contact's
/// threshold crossing (`contact_sigma` σ): the free part ends before the contact found (steps
/// 1–2 of the module docs). `diagnose` takes a force curve's interference wave from here.
pub fn free_part(rec: &Recording, path: &Path, contact_sigma: f64) -> Result<FreePart> {
    let u = &rec.u_m;
    let d = &rec.d_m;
    let approach = find_approach(rec, path)?;
    // Without segments the approach counts from the first row, which may be the base at rest:
    // the free part then starts once the base is under way, since at rest (or while it speeds
    // up) the lever does not carry the drag offset C·v/K it carries while moving, a step in D at
    // one U that no function of U describes. A vendor's `extend` segment is the ramp itself.
    let free_start = if has_segments(rec) {
        approach.start
    } else {
        under_way(rec, &approach)
    };

    // Baseline and threshold, iterated: the free part ends before the contact found.
    let len = approach.len();
    let mut free_end = approach.start + len / 2;
    let mut baseline;
    let mut crossing;
    let mut iterations = 0;
    loop {
        baseline = fit_baseline(u, d, free_start..free_end.max(free_start));
        crossing = threshold_crossing(u, d, &baseline, &approach, contact_sigma)
            .map_err(|e| IdentifyError::new(path, e))?;
        let (i_cross, i_zero) = crossing;
        let guard = (2 * (i_cross - i_zero)).max(len / 20).max(10);
        let new_end = i_zero.saturating_sub(guard).max(approach.start);
        iterations += 1;
        if new_end < free_start + 5 {
            return Err(IdentifyError::new(
                path,
                format!(
                    "no free baseline before contact: the deflection leaves its free level \
                     {} rows into the approach (row {})",
                    i_zero - approach.start,
                    i_zero + 1
                ),
            )
            .with_fix("record the approach from further away from the sample"));
        }
        if new_end.abs_diff(free_end) <= len / 200 || iterations >= 6 {
            free_end = new_end;
            baseline = fit_baseline(u, d, free_start..free_end.max(free_start));
            crossing = threshold_crossing(u, d, &baseline, &approach, contact_sigma)
                .map_err(|e| IdentifyError::new(path, e))?;
            break;
        }
        free_end = new_end;
    }
    Ok(FreePart {
        approach,
        baseline,
        crossing,
    })
}

/// The first row of the approach at which the base moves at 95 % of its median speed over the
/// approach's first half: rows before it are the rest and the start of the ramp. Speeds are
/// taken over windows of 2 % of the approach (at least 5 rows), so that a height sensor's noise
/// or a DAC's staircase does not read as a change of speed.
fn under_way(rec: &Recording, approach: &Range<usize>) -> usize {
    let (t, u) = (&rec.t_s, &rec.u_m);
    let w = (approach.len() / 50).max(5);
    let end = approach.start + approach.len() / 2;
    if end < approach.start + 2 * w {
        return approach.start;
    }
    let speed = |i: usize| {
        let dt = t[i + w] - t[i];
        if dt > 0.0 {
            (u[i + w] - u[i]).abs() / dt
        } else {
            0.0
        }
    };
    let mut all: Vec<f64> = (approach.start..end - w).map(speed).collect();
    all.sort_by(f64::total_cmp);
    let median = all[all.len() / 2];
    if !(median > 0.0) {
        return approach.start;
    }
    (approach.start..end - w)
        .find(|&i| speed(i) >= 0.95 * median)
        .unwrap_or(approach.start)
}

/// Whether the recording names its segments (`segment` column and `# segments:` line).
fn has_segments(rec: &Recording) -> bool {
    matches!(segment_kinds(rec), Some((_, kinds)) if !kinds.is_empty())
}

/// The `segment` column and the `# segments:` line's (number, kind) pairs.
type Segments = (Vec<f64>, Vec<(i64, String)>);

/// Segment numbers and kinds from the `segment` column and the `# segments:` line.
fn segment_kinds(rec: &Recording) -> Option<Segments> {
    let seg = rec.extra_column("segment")?.to_vec();
    let kinds = rec
        .meta
        .get("segments")
        .map(|s| {
            s.split(',')
                .filter_map(|p| {
                    let (num, kind) = p.split_once('=')?;
                    Some((num.trim().parse::<i64>().ok()?, kind.trim().to_string()))
                })
                .collect()
        })
        .unwrap_or_default();
    Some((seg, kinds))
}

/// The approach: the first `extend` segment, or, without segments, the rows from the start to
/// the lowest base position.
fn find_approach(rec: &Recording, path: &Path) -> Result<Range<usize>> {
    let n = rec.len();
    let range = match segment_kinds(rec) {
        Some((seg, kinds)) if !kinds.is_empty() => {
            let extend: Vec<i64> = kinds
                .iter()
                .filter(|(_, k)| k == "extend" || k == "approach")
                .map(|(num, _)| *num)
                .collect();
            let Some(start) = seg.iter().position(|s| extend.contains(&(*s as i64))) else {
                let list: Vec<String> = kinds.iter().map(|(n, k)| format!("{n}={k}")).collect();
                return Err(IdentifyError::new(
                    path,
                    format!(
                        "a force curve without an approach: no `extend` segment among {}",
                        list.join(",")
                    ),
                )
                .with_fix("identify needs the approach to find the contact point"));
            };
            let s0 = seg[start];
            let end = start + seg[start..].iter().take_while(|&&s| s == s0).count();
            start..end
        }
        _ => {
            let us = moving_average(&rec.u_m, 5);
            let (imin, _) = us
                .iter()
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |acc, (i, &v)| if v < acc.1 { (i, v) } else { acc },
                );
            0..imin + 1
        }
    };
    let u = &rec.u_m[range.clone()];
    let travel = u.first().copied().unwrap_or(0.0) - u.last().copied().unwrap_or(0.0);
    if range.len() < 20 || !(travel > 0.0) {
        return Err(IdentifyError::new(
            path,
            format!(
                "a force curve without an approach: {} rows in which U falls by {:.3e} m",
                range.len(),
                travel
            ),
        )
        .with_fix("the approach moves the base towards the sample (U decreasing, z up)"));
    }
    debug_assert!(range.end <= n);
    Ok(range)
}

/// `(i_cross, i_zero)`: the first row of the approach from which the deflection stays below
/// −n·σ to the end, and the last row before it at or above the baseline.
fn threshold_crossing(
    u: &[f64],
    d: &[f64],
    b: &Baseline,
    approach: &Range<usize>,
    n_sigma: f64,
) -> std::result::Result<(usize, usize), String> {
    let thr = -n_sigma * b.noise_m.max(1e-13);
    let dt = |i: usize| d[i] - b.under(u[i], d[i]);
    let last = approach.end - 1;
    if dt(last) >= thr {
        return Err(format!(
            "no contact on the approach: the deflection at its end ({:.3e} m below the free \
             level) does not pass {n_sigma}σ = {:.3e} m",
            -dt(last),
            -thr
        ));
    }
    let Some(i_above) = (approach.start..last).rev().find(|&i| dt(i) >= thr) else {
        return Err(
            "the approach starts in contact: its deflection is past the threshold from \
                    its first row"
                .to_string(),
        );
    };
    let i_cross = i_above + 1;
    let i_zero = (approach.start..i_cross)
        .rev()
        .find(|&i| dt(i) >= 0.0)
        .unwrap_or(approach.start);
    Ok((i_cross, i_zero))
}

/// (k_a, c_a, residual sum of squares) of the filtered regression at contact height `h`.
fn regress(
    t: &[f64],
    force: &[f64],
    z: &[f64],
    h: f64,
    r: f64,
    lambda: f64,
    mask: &[bool],
) -> (f64, f64, f64) {
    let n = t.len();
    let mut ff = FohLowPass::new(lambda, force[0]);
    let v0 = cap_volume(r, h - z[0]);
    let mut vf = FohLowPass::new(lambda, v0);
    // Normal equations for y = a·x1 + b·x2, accumulated with y², in scaled units.
    let (mut s11, mut s12, mut s22, mut s1y, mut s2y, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let warm = t[0] + 3.0 * lambda;
    for i in 1..n {
        let dt = t[i] - t[i - 1];
        let v = cap_volume(r, h - z[i]);
        let y = ff.update(dt, force[i]);
        let x1 = vf.update(dt, v);
        let x2 = (v - x1) / lambda;
        if t[i] < warm || !mask[i] {
            continue;
        }
        s11 += x1 * x1;
        s12 += x1 * x2;
        s22 += x2 * x2;
        s1y += x1 * y;
        s2y += x2 * y;
        syy += y * y;
    }
    if !(s11 > 0.0) {
        return (0.0, 0.0, syy);
    }
    super::signal::two_column_nonneg(s11, s12, s22, s1y, s2y, syy)
}

/// The quasi-static law driven by U: D per row (m), and the lever's deflection from its free
/// level (m).
#[allow(clippy::too_many_arguments)]
fn simulate(
    t: &[f64],
    u: &[f64],
    b: &Baseline,
    k: f64,
    h: f64,
    k_a: f64,
    c_a: f64,
    r: f64,
) -> (Vec<f64>, Vec<f64>) {
    let n = t.len();
    let mut out = Vec::with_capacity(n);
    let mut deflection = Vec::with_capacity(n);
    let mut delta = 0.0f64; // apex depth, ≥ 0 (0 when free)
    for i in 0..n {
        let dt = if i == 0 {
            f64::INFINITY
        } else {
            t[i] - t[i - 1]
        };
        // Damping coefficient over this step, from the area at the start of it (semi-implicit).
        let cd = if dt.is_finite() {
            c_a * contact_area(r, delta) / dt
        } else {
            0.0
        };
        let g = |x: f64| k * (x - h + u[i]) + k_a * cap_volume(r, x) + cd * (x - delta);
        let new = if g(0.0) < 0.0 {
            // g increases with x: bracket and solve.
            let mut hi = (h - u[i]).max(delta).max(1e-12);
            while g(hi) < 0.0 {
                hi *= 2.0;
            }
            let mut lo = 0.0;
            let mut x = delta.clamp(lo, hi);
            for _ in 0..100 {
                let gx = g(x);
                if gx > 0.0 {
                    hi = x;
                } else {
                    lo = x;
                }
                let slope = k + k_a * contact_area(r, x) + cd;
                let mut next = x - gx / slope;
                if !(next > lo && next < hi) {
                    next = 0.5 * (lo + hi);
                }
                if (next - x).abs() <= 1e-15 * (1.0 + x.abs()) || hi - lo < 1e-16 {
                    x = next;
                    break;
                }
                x = next;
            }
            x
        } else {
            0.0
        };
        delta = new;
        let d_true = if new > 0.0 { new - h + u[i] } else { 0.0 };
        out.push(d_true + b.at(u[i], d_true));
        deflection.push(d_true);
    }
    (out, deflection)
}

/// RMS misfit per segment: (number, kind, rows, rms).
fn segment_misfits(rec: &Recording, resid: &[f64]) -> Vec<(i64, String, usize, f64)> {
    let Some((seg, kinds)) = segment_kinds(rec) else {
        return Vec::new();
    };
    let mut out: Vec<(i64, String, usize, f64)> = Vec::new();
    let mut i = 0;
    while i < seg.len() {
        let s = seg[i];
        let j = i + seg[i..].iter().take_while(|&&x| x == s).count();
        let num = s as i64;
        let kind = kinds
            .iter()
            .find(|(n, _)| *n == num)
            .map(|(_, k)| k.clone())
            .unwrap_or_else(|| "unknown".into());
        out.push((
            num,
            kind,
            j - i,
            super::signal::rms(resid[i..j].iter().copied()),
        ));
        i = j;
    }
    out
}

fn dynamics_bounds(rec: &Recording, z: &[f64], d_s: &[f64]) -> Dynamics {
    let k = rec.meta.cantilever_k_n_per_m;
    let (f0, q, source) = match (
        rec.meta.cantilever_m_kg,
        rec.meta.cantilever_c_ns_per_m,
        rec.meta.cantilever_f0_hz,
        rec.meta.cantilever_q,
    ) {
        (Some(m), Some(c), _, _) if c > 0.0 => {
            let w = (k / m).sqrt();
            (
                w / (2.0 * std::f64::consts::PI),
                (k * m).sqrt() / c,
                "recording",
            )
        }
        (_, _, Some(f0), Some(q)) => (f0, q, "recording"),
        _ => (ASSUMED_F0_HZ, ASSUMED_Q, "assumed (worst case for liquid)"),
    };
    let w0 = 2.0 * std::f64::consts::PI * f0;
    let m = k / (w0 * w0);
    let c = (k * m).sqrt() / q;
    // Derivatives over ±5 ms of smoothed signals: the motions are slow, the noise is not.
    let t = &rec.t_s;
    let n = t.len();
    let dt = (t[n - 1] - t[0]) / (n - 1).max(1) as f64;
    let w = ((5e-3 / dt).round() as usize).clamp(1, n / 4 + 1);
    let zs = moving_average(z, w);
    let ds = moving_average(d_s, w);
    let deriv = |x: &[f64], i: usize| {
        let (a, b) = (i.saturating_sub(w), (i + w).min(n - 1));
        (x[b] - x[a]) / (t[b] - t[a])
    };
    let vz: Vec<f64> = (0..n).map(|i| deriv(&zs, i)).collect();
    let (mut acc, mut vel) = (0.0f64, 0.0f64);
    for i in 0..n {
        acc = acc.max(deriv(&vz, i).abs());
        vel = vel.max(deriv(&ds, i).abs());
    }
    Dynamics {
        f0_hz: f0,
        q,
        source,
        inertial_n: m * acc,
        damping_n: c * vel,
        to_force_range: f64::NAN,
        to_noise: f64::NAN,
        neglected: false,
    }
}

impl ForceCurveFit {
    /// The report's mode-specific part (the fit's file names and the notes are the caller's).
    pub fn to_report(&self, rec: &Recording, meta: &Metadata) -> rep::ForceCurveReport {
        let b = &self.baseline;
        let dyn_ = &self.dynamics;
        let p2 = self.pitch_m * self.pitch_m;
        rep::ForceCurveReport {
            model:
                "quasi-static sphere on a Kelvin–Voigt element bed: F = k_a·V(δ) + c_a·A(δ)·dδ/dt, \
                 V = πδ²(R − δ/3) (πR²(δ − R/3) past the equator), A = πa², F = −K·(D − D₀(U))"
                    .into(),
            cantilever_dynamics: rep::CantileverDynamics {
                neglected: dyn_.neglected,
                why: format!(
                    "{}: the largest inertial force M·|Z̈| ({:.2e} N) and damping force \
                     C·|Ḋ| ({:.2e} N) bend the lever by {:.2} times the deflection \
                     noise ({:.2e} m) and are {:.1e} of the force range ({:.2e} N); \
                     f0 = {} Hz, Q = {} ({})",
                    if dyn_.neglected {
                        "quasi-static, the noise hides the lever's dynamics"
                    } else {
                        "NOT quasi-static, the lever's dynamics exceed the noise and \
                         the fit leaves them out"
                    },
                    dyn_.inertial_n,
                    dyn_.damping_n,
                    dyn_.to_noise,
                    self.baseline.noise_m,
                    dyn_.to_force_range,
                    self.force_range_n,
                    dyn_.f0_hz,
                    dyn_.q,
                    dyn_.source
                ),
                to_noise: dyn_.to_noise.into(),
                to_force_range: dyn_.to_force_range.into(),
                inertial_force_max_n: dyn_.inertial_n.into(),
                damping_force_max_n: dyn_.damping_n.into(),
                f0_hz: dyn_.f0_hz.into(),
                q: dyn_.q.into(),
                f0_q_source: dyn_.source.into(),
            },
            approach: rep::RowSpan {
                rows: rep::rows(self.approach.start as u64, self.approach.end as u64),
                t_start_s: rec.t_s[self.approach.start],
                t_end_s: rec.t_s[self.approach.end - 1],
            },
            baseline: rep::Baseline {
                kind: b.describe().into(),
                offset_m: b.offset_m.into(),
                tilt_m_per_m: b.tilt.into(),
                u_ref_m: b.u_ref_m.into(),
                noise_m: b.noise_m.into(),
                free_rows: rep::rows(b.free_rows.start as u64, b.free_rows.end as u64),
                wave: rep::BaselineWave::of(b),
            },
            contact: rep::ForceCurveContact {
                height_m: self.contact_height_m.into(),
                row: self.contact_row as u64 + 1,
                t_s: self.contact_t_s.into(),
                u_m: self.contact_u_m.into(),
                threshold_row: self.threshold_row as u64 + 1,
                method: "baseline on the free approach, last crossing of n·σ, refined by the \
                         least-squares residual of the full Kelvin–Voigt fit"
                    .into(),
                inside_approach: true,
            },
            k_a_n_per_m3: self.k_a_n_per_m3.into(),
            fit_rows: "the approach and the retract while the sample pushes; holds and pull-off \
                       are left to the misfit"
                .into(),
            approach_force_depth_exponent: self.onset_exponent.into(),
            c_a_ns_per_m3: self.c_a_ns_per_m3.into(),
            relaxation_time_s: if self.k_a_n_per_m3 > 0.0 {
                self.c_a_ns_per_m3 / self.k_a_n_per_m3
            } else {
                f64::NAN
            }
            .into(),
            max_depth_m: self.max_depth_m.into(),
            max_force_n: self.max_force_n.into(),
            force_range_n: self.force_range_n.into(),
            element_pitch_m: self.pitch_m,
            filter_lambda_s: self.lambda_s,
            vendor_force: self.vendor_force.map(|(diff, range)| rep::VendorForce {
                column: "force_vendor_n".into(),
                max_abs_difference_n: diff.into(),
                max_abs_vendor_n: range.into(),
                matches: diff <= 1e-9 * range.max(1e-30),
            }),
            cantilever: rep::CantileverJson::new(meta),
            tip_radius_m: meta.tip_radius_m,
            taps: vec![rep::ForceCurveTap {
                contact_height_m: self.contact_height_m.into(),
                c_ns_per_m: self.c_ns_per_m.into(),
                k_n_per_m: self.k_n_per_m.into(),
                depth_m: self.max_depth_m.into(),
                elements_under_tip: self.elements_at_max.into(),
                c_element_ns_per_m: (self.c_a_ns_per_m3 * p2).into(),
                k_element_n_per_m: (self.k_a_n_per_m3 * p2).into(),
                note: "aggregate values are the tangent k = k_a·A and c = c_a·A at the deepest \
                       point"
                    .into(),
            }],
            rms_misfit_m: self.rms_misfit_m.into(),
            fit: rep::ForceCurveFitJson {
                model: "the quasi-static law with the identified h, k_a, c_a and baseline, \
                        driven by the recorded U"
                    .into(),
                rms_misfit_m: self.rms_misfit_m.into(),
                rms_misfit_contact_m: self.rms_misfit_contact_m.into(),
                rms_misfit_over_noise: (self.rms_misfit_m / self.baseline.noise_m).into(),
                deflection_range_m: self.deflection_range_m.into(),
                segments: self
                    .segments
                    .iter()
                    .map(|(n, k, rows, rms)| rep::SegmentFit {
                        segment: *n,
                        kind: k.clone(),
                        rows: *rows as u64,
                        rms_misfit_m: (*rms).into(),
                    })
                    .collect(),
                series_csv: String::new(),
                figure_png: String::new(),
            },
            notes: Vec::new(),
        }
    }

    /// The recorded and simulated series, one row per sample.
    pub fn series_csv(&self, rec: &Recording) -> String {
        let seg = rec.extra_column("segment");
        let mut s = String::from(
            "# visco identify: force-curve fit, recorded vs simulated deflection\n\
             t_s,u_m,d_recorded_m,d_simulated_m,residual_m,segment\n",
        );
        for i in 0..rec.len() {
            for v in [
                rec.t_s[i],
                rec.u_m[i],
                rec.d_m[i],
                self.simulated_d_m[i],
                rec.d_m[i] - self.simulated_d_m[i],
            ] {
                super::files::push_num(&mut s, v);
                s.push(',');
            }
            super::files::push_num(&mut s, seg.map_or(f64::NAN, |c| c[i]));
            s.push('\n');
        }
        s
    }
}

/// What a row of a force curve is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RowKind {
    Approach,
    Hold,
    Retract,
    Other,
}

/// Each row's kind: the approach found, `pause`/`hold`/`dwell` segments, `retract` segments;
/// without segments, everything after the approach is the retract.
fn row_kinds(rec: &Recording, approach: &Range<usize>) -> Vec<RowKind> {
    let n = rec.len();
    match segment_kinds(rec) {
        Some((seg, kinds)) if !kinds.is_empty() => (0..n)
            .map(|i| {
                if approach.contains(&i) {
                    return RowKind::Approach;
                }
                match kinds.iter().find(|(num, _)| *num == seg[i] as i64) {
                    Some((_, k)) if k == "retract" => RowKind::Retract,
                    Some((_, k)) if k == "pause" || k == "hold" || k == "dwell" => RowKind::Hold,
                    _ => RowKind::Other,
                }
            })
            .collect(),
        _ => (0..n)
            .map(|i| {
                if approach.contains(&i) {
                    RowKind::Approach
                } else if i >= approach.end {
                    RowKind::Retract
                } else {
                    RowKind::Other
                }
            })
            .collect(),
    }
}

/// Least-squares slope of log F against log δ on the approach where F is between 10 % and
/// 90 % of its largest value (NaN with fewer than 5 such rows).
fn onset_exponent(force: &[f64], z: &[f64], h: f64, approach: &Range<usize>) -> f64 {
    let f_top = approach.clone().map(|i| force[i]).fold(0.0, f64::max);
    let pts: Vec<(f64, f64)> = approach
        .clone()
        .filter(|&i| force[i] > 0.1 * f_top && force[i] < 0.9 * f_top && h - z[i] > 0.0)
        .map(|i| ((h - z[i]).ln(), force[i].ln()))
        .collect();
    if pts.len() < 5 {
        return f64::NAN;
    }
    let m = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / m,
        pts.iter().map(|p| p.1).sum::<f64>() / m,
    );
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (x, y) in &pts {
        sxx += (x - mx) * (x - mx);
        sxy += (x - mx) * (y - my);
    }
    if sxx > 0.0 {
        sxy / sxx
    } else {
        f64::NAN
    }
}
