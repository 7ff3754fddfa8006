//! The nominal model on recordings that start where the instrument was, not at rest.
//!
//! * A closed-form free ring-down (f64, no code shared with `diagnose/` or `plant/`) from a
//!   nonzero initial position and velocity is fitted to the noise: the initial state is
//!   estimated, not assumed. With the header's f₀ and Q off by 0.4 % and 4 % (within their
//!   stated tolerances) the calibration corrections recover the truth.
//! * A DIVE tap from the plant whose tones ran long before the recording starts (a pre-roll
//!   dropped) is fitted to within 1.5× its noise RMS and nothing is named.
//! * The same tap on the paper's own bed, discrete elements at 100 nm under the 300 nm tip,
//!   is fitted with the lattice bed (its pitch found) to the noise.

mod diagnose_support;

use diagnose_support::{
    held_out_rms, mid_oscillation_tap, mid_oscillation_tap_on, ring_down, TapProtocol,
};
use visco::diagnose::model::Bed;
use visco::diagnose::report::analyse;
use visco::diagnose::search::SearchOptions;

/// 0.1 nm of noise on a 30 nm, 2 µm/s ring-down of the paper's lever (20 kHz, Q 100) over
/// 10 ms at 500 kHz. The held-out RMS of recorded − nominal can only exceed the noise's by
/// the fit's own parameters' scatter (a handful over 2 500 held-out samples: < 1 %) and the
/// sampling of the noise's RMS (1/√(2·2500) ≈ 1.4 %); 1.05× allows 3 σ of both.
#[test]
fn free_ring_down_from_a_nonzero_state_is_fitted_to_the_noise() {
    let noise = 0.1e-9;
    for (f0_header, q_header, seed) in [(20e3, 100.0, 1u64), (20.08e3, 104.0, 2)] {
        let (rec, clean) = ring_down(
            20e3, 100.0, f0_header, q_header, 500e3, 5000, 30e-9, -2e-3, noise, seed,
        );
        let noise_rms = held_out_rms(&rec.d_m, &clean);
        let diag = analyse(&rec, &SearchOptions::default(), |_| {}).expect("diagnosed");
        let nom = &diag.search.nominal.nominal;
        let f0 = f0_header * nom.f0_scale;
        let q = q_header * nom.q_scale;
        println!(
            "header f0 {f0_header} Hz, Q {q_header}: rms {:.4e} m (noise {noise_rms:.4e}), z0 {:.3} nm, v0 {:.4} nm/µs, f0 {f0:.2} Hz, Q {q:.2}, named {:?}",
            diag.rms_before_m,
            nom.z0,
            nom.v0,
            diag.findings.iter().map(|f| f.kind.as_str()).collect::<Vec<_>>()
        );
        assert!(
            diag.rms_before_m <= 1.05 * noise_rms,
            "held-out RMS {} against the noise's {noise_rms}",
            diag.rms_before_m
        );
        // The fitted initial state: Z − U = 30 nm, Ż = −2 mm/s = −2 nm/µs (the velocity's
        // share of the ring, 2/ω₀ = 16 nm, is known to about the position's 0.05 nm).
        assert!((nom.z0 - 30.0).abs() < 0.05, "z0 {}", nom.z0);
        assert!((nom.v0 + 2.0).abs() < 0.01, "v0 {}", nom.v0);
        // f0 from 500 periods of a 30 nm ring at 0.1 nm of noise: to ~10⁻⁵; Q from the decay
        // over 3 time constants: to ~0.5 %.
        assert!((f0 / 20e3 - 1.0).abs() < 1e-4, "f0 {f0}");
        assert!((q / 100.0 - 1.0).abs() < 0.02, "Q {q}");
        assert!(diag.findings.is_empty(), "named on a clean ring-down");
    }
}

#[test]
fn a_tap_recorded_mid_oscillation_is_fitted_near_the_noise() {
    let p = TapProtocol::short();
    for (seed, offset) in [(3u64, [0.3, 0.7]), (4, [0.5, 0.1])] {
        let (rec, clean) = mid_oscillation_tap(&p, seed, offset);
        let noise_rms = held_out_rms(&rec.d_m, &clean);
        let diag = analyse(&rec, &SearchOptions::default(), |_| {}).expect("diagnosed");
        let nom = &diag.search.nominal.nominal;
        println!(
            "seed {seed}: nominal against the noise-free D {:.4e} m",
            held_out_rms(&diag.nominal_d_m, &clean)
        );
        println!(
            "seed {seed}: nominal held-out rms {:.4e} m = {:.2}× the noise {noise_rms:.4e}, input {:?}, z0 {:.2} nm, v0 {:.4} nm/µs, f0 ×{:.5}, Q ×{:.4}, named {:?}",
            diag.rms_before_m,
            diag.rms_before_m / noise_rms,
            nom.input,
            nom.z0,
            nom.v0,
            nom.f0_scale,
            nom.q_scale,
            diag.findings.iter().map(|f| f.kind.as_str()).collect::<Vec<_>>()
        );
        assert!(
            diag.rms_before_m <= 1.5 * noise_rms,
            "held-out RMS {} against the noise's {noise_rms}",
            diag.rms_before_m
        );
        assert!(diag.findings.is_empty(), "named on a clean tap");
        // Where the simulations went: every phase of the search, in order, adding up.
        let phases = &diag.search.phases;
        assert!(
            phases[0].0.starts_with("nominal fit")
                && phases
                    .iter()
                    .any(|(p, n)| p == "stage 1: screens" && *n > 0)
        );
        let total: usize = phases.iter().map(|(_, n)| n).sum();
        assert_eq!(total, diag.search.simulations, "{phases:?}");
    }
}

/// The paper's bed (pitch R/3: about 28 elements under the tip, each engaging with a step of
/// the contact's stiffness and damping) under a tap recorded mid-oscillation. The lattice
/// nominal has the plant's physics exactly, so the held-out RMS can exceed the noise's only
/// by the fit's parameters' scatter and the noise RMS's own sampling (as the ring-down's:
/// 1.05×); the continuum alone misfits at each engagement.
#[test]
fn a_tap_on_the_papers_discrete_bed_is_fitted_with_the_lattice_to_the_noise() {
    let p = TapProtocol::short();
    for (seed, offset) in [(5u64, [0.3, 0.7]), (6, [0.0, 0.5])] {
        let (rec, clean) = mid_oscillation_tap_on(&p, seed, offset, 3);
        let noise_rms = held_out_rms(&rec.d_m, &clean);
        let diag = analyse(&rec, &SearchOptions::default(), |_| {}).expect("diagnosed");
        let nom = &diag.search.nominal.nominal;
        println!(
            "seed {seed}: nominal held-out rms {:.4e} m = {:.3}× the noise {noise_rms:.4e}, bed {}, input {:?}, named {:?}",
            diag.rms_before_m,
            diag.rms_before_m / noise_rms,
            nom.bed.describe(),
            nom.input,
            diag.findings.iter().map(|f| f.kind.as_str()).collect::<Vec<_>>()
        );
        match nom.bed {
            Bed::Lattice { pitch_nm, .. } => {
                assert!((pitch_nm - 100.0).abs() < 1e-9, "pitch {pitch_nm} nm")
            }
            Bed::Continuum => panic!("the continuum kept on the paper's lattice"),
        }
        // The report says why, with its figures: the lattice's gain over the continuum above
        // the margin it had to clear.
        let why = &diag.search.bed_reason;
        println!("seed {seed}: bed {why}");
        assert!(why.starts_with("chosen over the continuum limit"), "{why}");
        let figure = |after: &str| -> f64 {
            let tail = &why[why
                .find(after)
                .unwrap_or_else(|| panic!("{after:?} in {why}"))
                + after.len()..];
            tail.split(' ')
                .next()
                .and_then(|x| x.parse().ok())
                .unwrap_or_else(|| panic!("{why}"))
        };
        let (gain, margin) = (figure("fits the fit samples "), figure("above the margin "));
        assert!(gain > margin && margin > 0.0, "{why}");
        assert!(
            diag.rms_before_m <= 1.05 * noise_rms,
            "held-out RMS {} against the noise's {noise_rms}",
            diag.rms_before_m
        );
        assert!(diag.findings.is_empty(), "named on a clean tap");
    }
}
