#![allow(clippy::needless_range_loop)]
//! Convergence of the estimators on data from the exact linear model (10) — (13) for DIVE and
//! (16) for SVE — with the paper's two-tone excitation, in f64 and in f32.

mod common;

use common::AggregatePlant;
use visco_core::config::{Config, EstimatorConfig};
use visco_core::estimator::{Estimator, EstimatorKind, EstimatorParams};
#[allow(unused_imports)]
use visco_core::excitation::{Excitation, ExcitationParams, SineTable, Tone};
use visco_core::regressor::{Regressor, RegressorParams};
use visco_core::{units, Real};

const FS: f64 = 1e6;
/// Aggregate contact of a fully submerged tip on the paper's nominal sample (SI).
const K_TRUE: f64 = 0.099;
const C_TRUE: f64 = 1.7e-5;
const H_TRUE_M: f64 = 120e-9;

struct Run {
    /// Time (s) and relative error of each parameter, every 100 samples.
    trace: Vec<(f64, [f64; 3])>,
    theta: [f64; 3],
    /// Mean of φφᵀ/m² over the run (internal units), scaled to the true parameters:
    /// diag(θ)⁻¹·R̄·diag(θ)⁻¹ is not needed; the gradient law's rate is λ_min(Γ·R̄).
    info: [[f64; 3]; 3],
}

fn regressor_params<T: Real>(cfg: &Config) -> RegressorParams<T> {
    let c = cfg.cantilever;
    RegressorParams::new(
        c.m_kg / units::MASS,
        c.c_ns_per_m / units::DAMPING,
        c.k_n_per_m / units::STIFFNESS,
        cfg.prefilter.lambda_s / units::TIME,
        1e6 / FS,
    )
}

/// Drive the exact plant open-loop with the two tones around a base position below the
/// surface, and run prefilters, regressor and estimator on its U and D.
fn run<T: SineTable, const N: usize>(
    est_cfg: &EstimatorConfig,
    exc: &visco_core::config::ExcitationConfig,
    depth_m: f64,
    seconds: f64,
    theta0: [f64; 3],
) -> Run {
    let cfg = Config::paper(FS);
    let rp = regressor_params::<T>(&cfg);
    // The per-sample law (blocks of one sample): this harness calls `update` every sample.
    let mut per_sample = *est_cfg;
    per_sample.decimation = 1;
    let ep: EstimatorParams<T, N> = per_sample.params(FS, 6e-6);
    let xp = ExcitationParams {
        tone1: Tone::new(exc.f1_hz, FS, exc.a1_m / units::LENGTH),
        tone2: Tone::new(exc.f2_hz, FS, exc.a2_m / units::LENGTH),
        ramp_step: 1.0,
    };
    let mut plant = AggregatePlant::paper(K_TRUE, C_TRUE, H_TRUE_M, 1.0 / FS);
    plant.always_in_contact = true;
    let h = H_TRUE_M / units::LENGTH;
    // Base position for the static depth δ: K·D = −k·δ (the sample pushes the tip up, D < 0),
    // so U = Z + D = (h − δ) − k·δ/K.
    let delta = depth_m / units::LENGTH;
    let z_eq = h - delta;
    let u0 = z_eq - K_TRUE * delta / plant.k_cant;
    plant.settle_at(u0);
    let mut exc_state = Excitation::<f64>::default();
    exc_state.set_on(true);
    let mut reg = Regressor::<T>::at_rest(T::from_f64(plant.z), T::from_f64(u0));
    let mut th0 = [T::ZERO; N];
    for i in 0..N {
        th0[i] = T::from_f64(theta0[i]);
    }
    let mut est = Estimator::<T, N>::new(&ep, th0);
    let truth = [C_TRUE / units::DAMPING, K_TRUE, K_TRUE * (h - z_eq.round())];
    // The regressor is centred at z₀ (SVE form) or uses δ = h − Z (DIVE form) with the true h.
    let z0 = if N == 3 { z_eq.round() } else { h };
    let n = (seconds * FS) as usize;
    let settle = (0.002 * FS) as usize;
    let mut u = u0;
    let mut trace = Vec::new();
    let mut info = [[0.0f64; 3]; 3];
    let mut info_n = 0.0;
    for k in 0..n {
        let d = plant.step(u);
        let u_applied = plant.u;
        let z = u_applied - d;
        reg.update(&rp, T::from_f64(u_applied), T::from_f64(z));
        if k >= settle {
            let w = reg.w(&rp);
            let mut ph = [T::ZERO; N];
            if N == 3 {
                ph.copy_from_slice(&reg.phi_sve(T::from_f64(z0))[..N]);
            } else {
                ph.copy_from_slice(&reg.phi_dive(T::from_f64(z0))[..N]);
            }
            est.update(&ep, w, &ph);
            let phf: Vec<f64> = ph.iter().map(|v| v.to_f64()).collect();
            let m2 = 1.0 + est_cfg.alpha * phf.iter().map(|v| v * v).sum::<f64>();
            for i in 0..N {
                for j in 0..N {
                    info[i][j] += phf[i] * phf[j] / m2;
                }
            }
            info_n += 1.0;
            if k % 100 == 0 {
                let th = est.theta();
                let mut err = [0.0; 3];
                for i in 0..N {
                    err[i] = (th[i].to_f64() - truth[i]) / truth[i];
                }
                trace.push(((k - settle) as f64 / FS, err));
            }
        }
        u = u0 + exc_state.next(&xp, &mut visco_core::excitation::NoTones);
    }
    let th = est.theta();
    let mut theta = [0.0; 3];
    for i in 0..N {
        theta[i] = th[i].to_f64();
    }
    for row in info.iter_mut() {
        for v in row.iter_mut() {
            *v /= info_n;
        }
    }
    Run { trace, theta, info }
}

fn worst(e: &[f64; 3], n: usize) -> f64 {
    e[..n].iter().fold(0.0f64, |a, b| a.max(b.abs()))
}

/// Least-squares slope of ln(error) against time over the points with error in (lo, hi).
fn decay_rate(trace: &[(f64, [f64; 3])], n: usize, lo: f64, hi: f64) -> (f64, usize) {
    let pts: Vec<(f64, f64)> = trace
        .iter()
        .map(|(t, e)| (*t, worst(e, n)))
        .skip_while(|(_, e)| *e >= hi)
        .take_while(|(_, e)| *e > lo)
        .map(|(t, e)| (t, e.ln()))
        .collect();
    let m = pts.len() as f64;
    let (st, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mt, my) = (st / m, sy / m);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (t, y) in &pts {
        sxy += (t - mt) * (y - my);
        sxx += (t - mt) * (t - mt);
    }
    (-sxy / sxx, pts.len())
}

/// The paper's DIVE estimator with a prior worth 1/β of data: then, for exact data, the error
/// decays as e^{−βt} from the start (θ̃(t) = θ̃₀ / (1 + (P₀R/β)(e^{βt} − 1)), R the information
/// rate), so the fitted rate must be β.
fn strong_prior(mut e: EstimatorConfig, beta: f64, phi_typ: [f64; 3]) -> EstimatorConfig {
    let fresh = EstimatorConfig::derived(
        phi_typ,
        1.0 / beta,
        1.0 / beta,
        FS,
        Config::paper(FS).nominal_dive,
    );
    e.beta_per_s = beta;
    e.p0 = fresh.p0;
    e.r0 = fresh.r0;
    e
}

/// Typical regressor of the paper's DIVE form: filtered tip velocity (nm/µs) and the
/// uncentred depth (nm).
fn dive_phi_typ() -> [f64; 3] {
    [4.4, 450.0, 1.0]
}

/// Eigenvalues of a symmetric 3×3 matrix (cyclic Jacobi).
fn eig_sym3(mut a: [[f64; 3]; 3]) -> [f64; 3] {
    for _ in 0..50 {
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            let mut b = a;
            for k in 0..3 {
                b[k][p] = c * a[k][p] - s * a[k][q];
                b[k][q] = s * a[k][p] + c * a[k][q];
            }
            a = b;
            for k in 0..3 {
                let (x, y) = (a[p][k], a[q][k]);
                a[p][k] = c * x - s * y;
                a[q][k] = s * x + c * y;
            }
        }
    }
    [a[0][0], a[1][1], a[2][2]]
}

#[test]
fn least_squares_paper_dive_form_converges_exponentially_at_beta() {
    let cfg = Config::paper(FS);
    let beta = 500.0;
    let e = strong_prior(cfg.dive.estimator, beta, dive_phi_typ());
    let theta0 = [C_TRUE / units::DAMPING * 1.3, K_TRUE * 0.7, 0.0];
    for (name, r) in [
        (
            "f64",
            run::<f64, 2>(&e, &cfg.dive.excitation, 450e-9, 0.06, theta0),
        ),
        (
            "f32",
            run::<f32, 2>(&e, &cfg.dive.excitation, 450e-9, 0.06, theta0),
        ),
    ] {
        let (rate, n) = decay_rate(&r.trace, 2, 2e-3, 3e-2);
        let last = r.trace.last().unwrap().1;
        println!(
            "{name}: rate {rate:.1}/s over {n} points (β = {beta}), final errors c {:.2e} k {:.2e}",
            last[0], last[1]
        );
        assert!(n > 30, "{name}: too few points in the decay");
        assert!(
            (rate / beta - 1.0).abs() < 0.1,
            "{name}: decay rate {rate} vs β {beta}"
        );
        assert!(worst(&last, 2) < 1e-3, "{name}: final error {last:?}");
    }
}

#[test]
fn least_squares_sve_form_converges_exponentially_at_beta() {
    let cfg = Config::paper(FS);
    let beta = 500.0;
    let e = strong_prior(cfg.sve.estimator, beta, [4.4, 40.0, 1.0]);
    let theta0 = [C_TRUE / units::DAMPING * 0.6, K_TRUE * 1.5, 0.0];
    for (name, r) in [
        (
            "f64",
            run::<f64, 3>(&e, &cfg.dive.excitation, 450e-9, 0.06, theta0),
        ),
        (
            "f32",
            run::<f32, 3>(&e, &cfg.dive.excitation, 450e-9, 0.06, theta0),
        ),
    ] {
        let (rate, n) = decay_rate(&r.trace, 3, 2e-3, 3e-2);
        let last = r.trace.last().unwrap().1;
        println!("{name}: rate {rate:.1}/s over {n} points (β = {beta}), final errors c {:.2e} k {:.2e} kh {:.2e}", last[0], last[1], last[2]);
        assert!(n > 30, "{name}: too few points in the decay");
        assert!(
            (rate / beta - 1.0).abs() < 0.1,
            "{name}: decay rate {rate} vs β {beta}"
        );
        assert!(worst(&last, 3) < 1e-3, "{name}: final error {last:?}");
    }
}

#[test]
fn f32_agrees_with_f64_after_convergence() {
    // The default (weak-prior) tuning of both modes, on the same exact data.
    let cfg = Config::paper(FS);
    let theta0 = [C_TRUE / units::DAMPING * 1.2, K_TRUE * 0.8, 0.0];
    let cases = [
        ("dive", cfg.dive.estimator, cfg.dive.excitation, 450e-9),
        ("sve", cfg.sve.estimator, cfg.sve.excitation, 150e-9),
    ];
    for (name, e, x, depth) in cases {
        let a = run::<f64, 3>(&e, &x, depth, 0.05, theta0);
        let b = run::<f32, 3>(&e, &x, depth, 0.05, theta0);
        // Over the converged second half, every sample of θ̂ in f32 within 0.1 % of f64.
        let half = a.trace.len() / 2;
        let mut worst_diff = 0.0f64;
        for (pa, pb) in a.trace[half..].iter().zip(&b.trace[half..]) {
            for i in 0..3 {
                // Relative errors against the truth: their difference is the f32–f64 gap.
                worst_diff = worst_diff.max((pa.1[i] - pb.1[i]).abs());
            }
        }
        let fa = a.trace.last().unwrap().1;
        let fb = b.trace.last().unwrap().1;
        println!("{name}: max |f32 − f64| over the converged half {worst_diff:.2e}; final f64 {fa:?} f32 {fb:?}; θ f64 {:?} f32 {:?}", a.theta, b.theta);
        assert!(
            worst_diff < 1e-3,
            "{name}: f32 and f64 differ by {worst_diff}"
        );
        assert!(
            worst(&fa, 3) < 1e-3 && worst(&fb, 3) < 1e-3,
            "{name}: not converged: {fa:?} {fb:?}"
        );
    }
}

#[test]
fn gradient_law_converges_at_its_predicted_rate() {
    let cfg = Config::paper(FS);
    let mut e = cfg.sve.estimator;
    e.kind = EstimatorKind::Gradient;
    let theta0 = [C_TRUE / units::DAMPING * 1.2, K_TRUE * 0.8, 0.0];
    // 0.3 s: the paper's Γ is capped for the loop's blocks of 32 samples (`in_blocks`), so the
    // slowest direction takes longer than with the per-sample cap.
    let r = run::<f64, 3>(&e, &cfg.dive.excitation, 450e-9, 0.3, theta0);
    let (rate, n) = decay_rate(&r.trace, 3, 2e-3, 0.05);
    let last = r.trace.last().unwrap().1;
    // Averaged error dynamics dθ̃/dt = −Γ·R̄·θ̃: the slowest mode decays at λ_min(Γ^½ R̄ Γ^½).
    let g: Vec<f64> = e.gamma.iter().map(|v| v.sqrt()).collect();
    let mut s = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            s[i][j] = g[i] * r.info[i][j] * g[j];
        }
    }
    let ev = eig_sym3(s);
    let predicted = ev.iter().cloned().fold(f64::INFINITY, f64::min) * 1e6; // 1/µs → 1/s
    println!("gradient: rate {rate:.1}/s over {n} points, predicted λ_min(ΓR̄) = {predicted:.1}/s, final errors {last:?}");
    assert!(n > 20);
    assert!(
        (rate / predicted - 1.0).abs() < 0.2,
        "rate {rate} vs predicted {predicted}"
    );
    assert!(worst(&last, 3) < 1e-3, "final error {last:?}");
}
