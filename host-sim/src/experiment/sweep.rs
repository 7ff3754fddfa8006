//! Beyond the paper: how fast can each mode image before its accuracy breaks?
//!
//! * SVE: the line period from the paper's 2 s down, on the demo's frame: 20 lines of 50
//!   pixels, 250 nm apart, over the whole sample (the instrument scaling needs lines closer than
//!   the contact's diameter to see the topography across them; see [`super::run_sve`]). The
//!   slowest point is the demo's SVE image, so the sweep starts from the demo's figures; a strip
//!   of 5 lines through the cell's middle (the sweep's frame before) judged the nucleus's curved
//!   cap and its two one-sided edge lines rather than the speed: 3.2–3.6 % k RMS at every rate.
//! * DIVE: the tap time from the paper's 0.2 s down, on 5 × 5 taps across the cell.
//!
//! A user who images faster re-tunes the loop to the speed, and so does the sweep, by rules
//! stated here (not per-point tweaks):
//!
//! * estimator memory 1/β: SVE min(2 ms, a quarter of a pixel's time) — it must forget the
//!   previous pixel; DIVE a twentieth of the tap;
//! * estimator block (samples per block update, [`visco_core::schedule`]): the demo's 32 µs,
//!   shortened where the memory would span fewer than ten blocks (the core's validation rule:
//!   forgetting is lumped per block, so a block must be short against the memory). A shorter
//!   block costs the firmware more estimator updates per second, not accuracy;
//! * SVE depth controller kᵢ: the tracking error of an integral loop on a ramp is
//!   slope·speed/(kᵢ·g); kᵢ grows with the scan speed, `kᵢ = 2000/s · (v / 5 µm/s)^½`, capped at
//!   2.5 % of the loop rate (the discrete integrator's limit);
//! * SVE high-pass: the tones must pass and what the scan does to the contact must not. The
//!   scan's fastest change is the element lattice passing under the tip, at v/pitch (50 Hz on
//!   2 s lines, 1.7 kHz on 0.06 s lines), each element engaging and releasing at the rim, so the
//!   corner follows `v/pitch` (pitch: the bed's stated lattice) between f₂/8 and f₂/2.5 (a
//!   corner at f₂/8 left k̂ biased by −1 % of k_max on 0.06 s lines; at f₂/2.5 the tones still
//!   pass with both sides of the regression filtered alike). It followed `v/0.5 µm` (a feature
//!   crossed) up to f₂/4 before: 0.06 s lines k RMS 5.03 → 1.9 %;
//! * DIVE approach and retract speed: the vertical travel (~1 µm) in a fifth of the tap, at most
//!   the validation's limit of 1 nm per loop period; settle and read-out scale with the tap; the
//!   lateral move lasts at least three ring-down times 2Q/ω₀ of the free cantilever, so that the
//!   ringing left by the retract has died before the next approach.
//!
//! Errors as in the demo: instrument scaling, % of each property's maximum, steep from the
//! identified topography. A rate meets the goal when every RMS error is ≤ 2 % and every error
//! away from steep topography ≤ 5 % ([`meets_goal`]).

use super::metrics::{self, ImageErrors, PAPER_MAX};
use super::{run_dive, run_sve, ExperimentError, Setup};
use crate::sample::Sample;
use schemars::JsonSchema;
use serde::Serialize;
use visco_core::geometry::contact_radius;

/// One point of a sweep.
#[derive(Clone, Debug, Serialize, JsonSchema)]
pub struct SweepPoint {
    /// SVE line period or DIVE tap time (s).
    pub period_s: f64,
    /// Map pixels per second of imaging time.
    pub pixels_per_s: f64,
    /// RMS error h, c, k (% of max).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 3]")]
    pub rms_error_pct: [f64; 3],
    /// Largest error h, c, k (% of max).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 3]")]
    pub max_error_pct: [f64; 3],
    /// Largest error h, c, k away from steep topography (% of max).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 3]")]
    pub max_error_not_steep_pct: [f64; 3],
    /// RMS error h, c, k with the paper's scaling n = |W| (needs the simulator's contact count).
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "[Option<f64>; 3]")]
    pub paper_rms_error_pct: [f64; 3],
    /// The largest of the three RMS errors.
    // Non-finite when not computable: written null (serde_json), so the schema allows it.
    #[schemars(with = "Option<f64>")]
    pub worst_rms_pct: f64,
    /// Pixels or taps that failed.
    pub failed: usize,
    /// Simulated seconds.
    pub simulated_s: f64,
    /// Samples per estimator block update at this point (see the module's rules).
    pub block_samples: u32,
}

// One field per argument of the row it builds; a struct for them would be the row again.
#[allow(clippy::too_many_arguments)]
fn point(
    period_s: f64,
    pixels: usize,
    imaging_s: f64,
    e: &ImageErrors,
    paper: &ImageErrors,
    failed: usize,
    simulated_s: f64,
    block_samples: u32,
) -> SweepPoint {
    let rms = [e.h.rms_pct, e.c.rms_pct, e.k.rms_pct];
    SweepPoint {
        period_s,
        pixels_per_s: pixels as f64 / imaging_s,
        rms_error_pct: rms,
        max_error_pct: [e.h.max_pct, e.c.max_pct, e.k.max_pct],
        max_error_not_steep_pct: [
            e.h.max_not_steep_pct,
            e.c.max_not_steep_pct,
            e.k.max_not_steep_pct,
        ],
        paper_rms_error_pct: [paper.h.rms_pct, paper.c.rms_pct, paper.k.rms_pct],
        worst_rms_pct: rms.iter().cloned().fold(f64::NAN, f64::max),
        failed,
        simulated_s,
        block_samples,
    }
}

/// The estimator's block shortened so that its memory 1/β spans at least ten blocks (the
/// core's validation rule), never lengthened.
fn block_for_memory(
    e: visco_core::config::EstimatorConfig,
    sample_rate_hz: f64,
) -> visco_core::config::EstimatorConfig {
    // Largest N with β·N < 0.1·f_s, kept strictly inside by a hair for the float comparison.
    let fit = (0.1 * sample_rate_hz / e.beta_per_s * (1.0 - 1e-9)).floor() as u32;
    let n = e.decimation.min(fit).max(1);
    e.in_blocks(n, sample_rate_hz)
}

/// The SVE setup at `line_period_s`, tuned by the module's rules.
pub fn sve_setup(line_period_s: f64, sample_rate_hz: f64, seed: u64) -> Setup {
    let mut setup = Setup::paper(Sample::cell_phantom(), sample_rate_hz, seed);
    let c = &mut setup.config;
    // The paper's frame (20 lines, 250 nm apart, over the whole sample), as the demo.
    c.sve.line_period_s = line_period_s;
    c.sve.turn_s = (0.01 * line_period_s).max(1e-3);
    let half = (line_period_s - c.sve.turn_s) / 2.0;
    let pixel_s = half / c.sve.pixels as f64;
    let speed = (c.sve.x1_m - c.sve.x0_m) / half;
    c.sve.estimator.beta_per_s = 1.0 / (2e-3f64).min(pixel_s / 4.0);
    c.sve.estimator = block_for_memory(c.sve.estimator, sample_rate_hz);
    c.sve.ki_per_s = (2000.0 * (speed / 5e-6).sqrt()).min(0.025 * sample_rate_hz);
    let f2 = c.sve.excitation.f2_hz;
    c.sve.highpass_hz = (speed / setup.sample.pitch_m()).clamp(f2 / 8.0, f2 / 2.5);
    setup
}

/// The DIVE setup at `tap_s`, tuned by the module's rules.
pub fn dive_setup(tap_s: f64, sample_rate_hz: f64, seed: u64) -> Setup {
    let mut setup = Setup::paper(Sample::cell_phantom(), sample_rate_hz, seed);
    let c = &mut setup.config;
    let n = 5u32;
    c.dive.nx = n;
    c.dive.ny = n;
    c.dive.dx_m = 5e-6 / n as f64;
    c.dive.dy_m = 5e-6 / n as f64;
    c.dive.x0_m = 2.5e-6 / n as f64;
    c.dive.y0_m = 2.5e-6 / n as f64;
    let scale = tap_s / 0.2;
    c.dive.tap_s = tap_s;
    // The free cantilever rings down with τ = 2Q/ω₀ (1.6 ms for the paper's) after a retract;
    // the next approach must not start before three of them, or the ringing reads as contact.
    let ring_s = 2.0 * c.cantilever.q() / (2.0 * std::f64::consts::PI * c.cantilever.f0_hz());
    c.dive.move_s = (2e-3 * scale).max(3.0 * ring_s);
    c.dive.settle_s = 5e-3 * scale;
    c.dive.readout_s = 10e-3 * scale;
    c.dive.excitation.ramp_s = (2e-3 * scale).max(2e-4);
    c.dive.estimator.beta_per_s = 20.0 / tap_s;
    c.dive.estimator = block_for_memory(c.dive.estimator, sample_rate_hz);
    // About 1 µm of travel down and back within a fifth of the tap, ≤ 1 nm per period.
    let v = (1e-6 / (0.2 * tap_s))
        .max(100e-6)
        .min(0.9e-9 * sample_rate_hz);
    c.approach.speed_m_per_s = v;
    c.approach.retract_speed_m_per_s = (2.0 * v).min(0.9e-9 * sample_rate_hz);
    setup
}

/// Run the SVE sweep over `periods`; `progress` gets each finished point.
pub fn sve_sweep(
    periods: &[f64],
    sample_rate_hz: f64,
    seed: u64,
    mut progress: impl FnMut(&SweepPoint),
) -> Result<Vec<SweepPoint>, ExperimentError> {
    let mut out = Vec::new();
    for &p in periods {
        let setup = sve_setup(p, sample_rate_hz, seed);
        let c = &setup.config;
        let o = run_sve(&setup, &mut (), |_| {})?;
        let steep = metrics::steep_slope(
            c.sve.depth_ref_m,
            contact_radius(c.tip_radius_m, c.sve.depth_ref_m),
        );
        let e = metrics::image_errors(
            o.pixels
                .iter()
                .map(|px| (&px.scaled.instrument, &px.touched.reference, px.slope)),
            &PAPER_MAX,
            steep,
        );
        let paper = metrics::image_errors(
            o.pixels
                .iter()
                .map(|px| (&px.scaled.paper, &px.touched.reference, px.slope)),
            &PAPER_MAX,
            steep,
        );
        let expected = (c.sve.pixels * c.sve.lines) as usize;
        let pt = point(
            p,
            o.pixels.len(),
            c.sve_imaging_s(),
            &e,
            &paper,
            expected - o.pixels.len(),
            o.simulated_s,
            c.sve.estimator.decimation,
        );
        progress(&pt);
        out.push(pt);
    }
    Ok(out)
}

/// Run the DIVE sweep over `taps`; `progress` gets each finished point.
pub fn dive_sweep(
    taps: &[f64],
    sample_rate_hz: f64,
    seed: u64,
    mut progress: impl FnMut(&SweepPoint),
) -> Result<Vec<SweepPoint>, ExperimentError> {
    let mut out = Vec::new();
    for &t in taps {
        let setup = dive_setup(t, sample_rate_hz, seed);
        let c = &setup.config;
        let o = run_dive(&setup, &mut (), |_| {})?;
        let steep = metrics::steep_slope(c.dive.indent_depth_m, c.tip_radius_m);
        let ok = o.taps.iter().filter(|t| !t.failed);
        let e = metrics::image_errors(
            ok.clone()
                .map(|t| (&t.scaled.instrument, &t.touched.reference, t.slope)),
            &PAPER_MAX,
            steep,
        );
        let paper = metrics::image_errors(
            ok.map(|t| (&t.scaled.paper, &t.touched.reference, t.slope)),
            &PAPER_MAX,
            steep,
        );
        let failed = o.taps.iter().filter(|t| t.failed).count() + (c.dive.nx * c.dive.ny) as usize
            - o.taps.len();
        let pt = point(
            t,
            o.taps.len() - o.taps.iter().filter(|t| t.failed).count(),
            c.dive_imaging_s(),
            &e,
            &paper,
            failed,
            o.simulated_s,
            c.dive.estimator.decimation,
        );
        progress(&pt);
        out.push(pt);
    }
    Ok(out)
}

/// The accuracy goal: every RMS error ≤ 2 % and every error away from steep topography ≤ 5 %
/// (instrument scaling), no pixel lost.
pub fn meets_goal(p: &SweepPoint) -> bool {
    p.failed == 0
        && p.rms_error_pct.iter().all(|v| *v <= 2.0)
        && p.max_error_not_steep_pct.iter().all(|v| *v <= 5.0)
}

/// The fastest point that meets the goal ([`meets_goal`]).
pub fn fastest_meeting_goal(points: &[SweepPoint]) -> Option<&SweepPoint> {
    points
        .iter()
        .filter(|p| meets_goal(p))
        .max_by(|a, b| a.pixels_per_s.total_cmp(&b.pixels_per_s))
}

/// The sweep report's `schema_version`.
pub const SCHEMA_VERSION: u32 = 1;

/// `sweep.json` of `visco sweep --out DIR`.
#[derive(Clone, Debug, Default, Serialize, JsonSchema)]
pub struct SweepReport {
    /// Version of this report's layout (1): raised when a field is removed or renamed or changes
    /// meaning or unit; adding a field keeps it.
    pub schema_version: u32,
    /// SVE: one point per line period.
    pub sve: Vec<SweepPoint>,
    /// DIVE: one point per tap time.
    pub dive: Vec<SweepPoint>,
    /// The fastest SVE point that meets the goal, if any.
    pub sve_fastest_meeting_goal: Option<SweepPoint>,
    /// The fastest DIVE point that meets the goal, if any.
    pub dive_fastest_meeting_goal: Option<SweepPoint>,
    /// The excitation study's candidates.
    pub excitation: Vec<crate::experiment::excitation_study::Candidate>,
    /// How to read the figures.
    pub notes: Vec<String>,
}
