//! The two-tone excitation over 10⁸ samples (100 s at 1 MHz, 28 h at 1 kHz), against the
//! requested tones over time: the reference phase is 2π·f·t computed in f64 from the sample
//! index, never from a phase accumulator.
//!
//! A 32-bit phase accumulator runs at a multiple of f_s/2³² (0.23 mHz at 1 MHz), the nearest
//! to the request; so against the requested f the phase must drift at exactly 2π·Δf, with
//! |Δf| ≤ f_s/2³³, and by nothing else. Checked (a) sample by sample against the f64 tones
//! at the nearest representable frequency, to the f32 resolution of the output; (b) by
//! lock-in on the requested frequencies at the start and after 10⁸ samples: amplitude
//! unchanged, phase moved by 2π·Δf·Δt and no more; (c) each tone's recursive oscillator,
//! sample by sample, within the chunk bound of `visco_core::excitation`.

use visco_core::excitation::{Excitation, ExcitationParams, Tone, RESYNC};

const N: u64 = 100_000_000;
const FS: f64 = 1e6;
/// The frequency step of a 32-bit phase accumulator (Hz).
const QUANTUM: f64 = FS / 4_294_967_296.0;

/// 2π·frac(f·t) at sample n for a frequency f in Hz (an integer here, so f·n is exact in
/// f64 and the cycle count is rounded once: error ≤ 2·10⁶ cycles · 2⁻⁵³ ≈ 2·10⁻¹⁰ cycles).
/// The synthesiser advances before it outputs: sample n is at t = (n + 1)/f_s.
fn phase_at(f: f64, n: u64) -> f64 {
    let cycles = f * (n + 1) as f64 / FS;
    2.0 * std::f64::consts::PI * (cycles - cycles.floor())
}

#[test]
fn excitation_follows_the_requested_tones_over_1e8_samples() {
    let (f1, f2) = (19_660.0, 4_915.0);
    let (a1, a2) = (1000.0f32, 70.0f32); // nm: the paper's DIVE base amplitudes
    let p = ExcitationParams {
        tone1: Tone::new(f1, FS, a1),
        tone2: Tone::new(f2, FS, a2),
        ramp_step: 1.0f32,
    };
    // The nearest representable frequencies, by the test's own rounding.
    let df1 = (f1 / QUANTUM).round() * QUANTUM - f1;
    let df2 = (f2 / QUANTUM).round() * QUANTUM - f2;
    assert!(df1.abs() <= QUANTUM / 2.0 && df2.abs() <= QUANTUM / 2.0);
    let two_pi = 2.0 * std::f64::consts::PI;
    let (aa1, aa2) = (f64::from(a1), f64::from(a2));
    // The recursion's bound (see `visco_core::excitation`), in units of the f32 rounding
    // u = 2⁻²⁴, for a tone of amplitude a and increment angle Δ: set at a chunk's first
    // sample from the table, a·sin of that sample and of the one before, each within 6u·a
    // (the table read's four roundings, its truncation 1.5·10⁻⁸ < u/4, the amplitude's
    // product), then RESYNC − 1 recursions, each adding the rounding of its product and
    // difference (≤ 3u·a, as |2cos Δ·y| ≤ 2a) and of the constant 2cos Δ ∈ [1, 2) (≤ u, times
    // |y| ≤ a); an error made at one sample reappears n samples later times
    // sin((n + 1)Δ)/sin Δ, at most 1/sin Δ. The f64 reference's phase (10⁻⁹ rad) is below it.
    let u = f64::from(f32::EPSILON) / 2.0;
    let recursions = f64::from(RESYNC - 1);
    let osc_tol = |a: f64, tone: &Tone<f32>| {
        let delta = two_pi * f64::from(tone.increment) / 4_294_967_296.0;
        (12.0 + 4.0 * recursions) * u * a / delta.sin()
    };
    let (tol1, tol2) = (osc_tol(aa1, &p.tone1), osc_tol(aa2, &p.tone2));
    // The output: the tones' errors and the rounding of their sum.
    let tol = tol1 + tol2 + u * (aa1 + aa2);

    let mut exc = Excitation::<f32>::default();
    exc.set_on(true);
    let mut worst = 0.0f64;
    let mut worst_at = 0;
    // (c): the worst error of each tone's oscillator, as a fraction of its bound.
    let mut worst_osc = [0.0f64; 2];
    let lock = 1_000_000u64; // 1 s windows: whole periods of both requested tones
    let mut start = [0.0f64; 4];
    let mut end = [0.0f64; 4];
    for n in 0..N {
        let v = f64::from(exc.next(&p, &mut visco_core::excitation::NoTones));
        let t = (n + 1) as f64 / FS;
        let (x1, x2) = (phase_at(f1, n), phase_at(f2, n));
        // (a) The tones at the representable frequencies: the requested phase plus 2π·Δf·t.
        let (th1, th2) = (x1 + two_pi * df1 * t, x2 + two_pi * df2 * t);
        let exact = aa1 * th1.sin() + aa2 * th2.sin();
        // (c) Each tone's oscillator against the exact tone.
        let (y1, y2) = exc.tone_values();
        for (k, (y, a, th, tol_k)) in [(y1, aa1, th1, tol1), (y2, aa2, th2, tol2)]
            .into_iter()
            .enumerate()
        {
            worst_osc[k] = worst_osc[k].max((f64::from(y) - a * th.sin()).abs() / tol_k);
        }
        let err = (v - exact).abs();
        if err > worst {
            worst = err;
            worst_at = n;
        }
        // (b) Lock-in on the requested tones.
        let acc = if n < lock {
            Some(&mut start)
        } else if n >= N - lock {
            Some(&mut end)
        } else {
            None
        };
        if let Some(acc) = acc {
            acc[0] += v * x1.sin();
            acc[1] += v * x1.cos();
            acc[2] += v * x2.sin();
            acc[3] += v * x2.cos();
        }
    }
    let amp_phase = |i: f64, q: f64| (2.0 * i.hypot(q) / lock as f64, q.atan2(i));
    let (s1, e1) = (amp_phase(start[0], start[1]), amp_phase(end[0], end[1]));
    let (s2, e2) = (amp_phase(start[2], start[3]), amp_phase(end[2], end[3]));
    // The windows' centres, where a lock-in reads the phase that drifts linearly across it.
    let (t_start, t_end) = (0.5 * lock as f64 / FS, (N - lock / 2) as f64 / FS);
    let (drift1, drift2) = (two_pi * df1 * t_end, two_pi * df2 * t_end);
    println!(
        "worst sample error {worst:.3e} nm at n = {worst_at} ({:.2e} of the amplitude, bound \
         {:.2e}); against the requested tones: tone 1 amplitude {:.6}→{:.6} nm, phase \
         {:.3e}→{:.3e} rad (expected drift {drift1:.3e} rad, Δf {df1:.3e} Hz); tone 2 \
         amplitude {:.6}→{:.6} nm, phase {:.3e}→{:.3e} rad (expected drift {drift2:.3e} rad, \
         Δf {df2:.3e} Hz)",
        worst / (aa1 + aa2),
        tol / (aa1 + aa2),
        s1.0,
        e1.0,
        s1.1,
        e1.1,
        s2.0,
        e2.0,
        s2.1,
        e2.1
    );
    println!(
        "oscillators over {N} samples: worst error {:.3} of the bound for tone 1 ({:.2e} nm of \
         {a1} nm), {:.3} for tone 2 ({:.2e} nm of {a2} nm); bounded for ever: every {RESYNC} \
         samples they start again from the exact integer phase",
        worst_osc[0],
        worst_osc[0] * tol1,
        worst_osc[1],
        worst_osc[1] * tol2
    );
    assert!(
        worst_osc[0] <= 1.0 && worst_osc[1] <= 1.0,
        "oscillator error above its bound: {worst_osc:?} of it"
    );
    assert!(worst <= tol, "worst error {worst} nm > {tol} nm");
    // A sample error of at most `tol` moves a lock-in's amplitude by at most 2·tol and its
    // phase by at most 2·tol/a (its in-phase and quadrature sums average the error).
    for (s, e, a, drift) in [(s1, e1, aa1, drift1), (s2, e2, aa2, drift2)] {
        let phase_tol = 2.0 * tol / a;
        assert!((s.0 - a).abs() <= 2.0 * tol && (e.0 - a).abs() <= 2.0 * tol);
        let df = drift / t_end;
        for (at, got) in [(t_start, s.1), (t_end, e.1)] {
            println!(
                "tone of {a} nm at {at} s: phase − 2π·Δf·t = {:.2e} rad (tolerance {phase_tol:.2e})",
                got - df * at
            );
            assert!(
                (got - df * at).abs() <= phase_tol,
                "phase at {at} s: {got} rad, expected 2π·Δf·t = {} ± {phase_tol} rad",
                df * at
            );
        }
    }
}
