//! The two-tone excitation over 10⁸ samples (100 s at 1 MHz, 28 h at 1 kHz), against the
//! requested tones over time: the reference phase is 2π·f·t computed in f64 from the sample
//! index, never from a phase accumulator.
//!
//! A 32-bit phase accumulator runs at a multiple of f_s/2³² (0.23 mHz at 1 MHz), the nearest
//! to the request; so against the requested f the phase must drift at exactly 2π·Δf, with
//! |Δf| ≤ f_s/2³³, and by nothing else. Checked (a) sample by sample against the f64 tones
//! at the nearest representable frequency, to the f32 resolution of the output; (b) by
//! lock-in on the requested frequencies at the start and after 10⁸ samples: amplitude
//! unchanged, phase moved by 2π·Δf·Δt and no more; (c) the rotating phasors themselves,
//! sample by sample: angle and modulus within the chunk bound of `visco_core::excitation`.

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
    // The phasor's bound (see `visco_core::excitation`), in units of the f32 rounding
    // u = 2⁻²⁴: set at a chunk's first sample from the table (sin and cos each within four
    // roundings: the entry, the two corrected products, their sum: 4√2·u as a vector), then
    // RESYNC − 1 rotations, each off by the rounding of the rotation constant (u) and of its
    // two products and sum per component (2u each, 2√2·u as a vector, since
    // |c·rc| + |s·rs| ≤ 1 for unit vectors). The table's truncation (1.5·10⁻⁸) and the f64
    // reference's phase (10⁻⁹ rad) are below it.
    let u = f64::from(f32::EPSILON) / 2.0;
    let rotations = f64::from(RESYNC - 1);
    let phasor_tol = u * (4.0 * 2f64.sqrt() + rotations * (1.0 + 2.0 * 2f64.sqrt()));
    // The output: each tone's phasor error times its amplitude, and three roundings of the
    // sum's magnitude (the two amplitude products, the sum of the tones).
    let tol = (phasor_tol + 3.0 * u) * (aa1 + aa2);

    let mut exc = Excitation::<f32>::default();
    exc.set_on(true);
    let mut worst = 0.0f64;
    let mut worst_at = 0;
    // (c): the worst angle (rad) and modulus error of either phasor.
    let (mut worst_angle, mut worst_modulus) = (0.0f64, 0.0f64);
    let lock = 1_000_000u64; // 1 s windows: whole periods of both requested tones
    let mut start = [0.0f64; 4];
    let mut end = [0.0f64; 4];
    for n in 0..N {
        let v = f64::from(exc.next(&p));
        let t = (n + 1) as f64 / FS;
        let (x1, x2) = (phase_at(f1, n), phase_at(f2, n));
        // (a) The tones at the representable frequencies: the requested phase plus 2π·Δf·t.
        let (th1, th2) = (x1 + two_pi * df1 * t, x2 + two_pi * df2 * t);
        let exact = aa1 * th1.sin() + aa2 * th2.sin();
        // (c) The phasors against the exact angles: the cross product with the exact unit
        // vector is the sine of the angle error, the dot product the modulus.
        let (ph1, ph2) = exc.phasors();
        for (ph, th) in [(ph1, th1), (ph2, th2)] {
            let (c, s) = (f64::from(ph[0]), f64::from(ph[1]));
            let (sin_t, cos_t) = th.sin_cos();
            worst_angle = worst_angle.max((s * cos_t - c * sin_t).abs());
            worst_modulus = worst_modulus.max((c * cos_t + s * sin_t - 1.0).abs());
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
        "phasors over {N} samples: worst angle error {worst_angle:.2e} rad, worst modulus error \
         {worst_modulus:.2e} (bound {phasor_tol:.2e}, for ever: every {RESYNC} samples the \
         phasors start again from the exact integer phase)"
    );
    assert!(
        worst_angle <= phasor_tol,
        "phasor angle error {worst_angle} rad > {phasor_tol}"
    );
    assert!(
        worst_modulus <= phasor_tol,
        "phasor modulus error {worst_modulus} > {phasor_tol}"
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
