//! The block update of the estimators (`Estimator::update_block`) against an independent
//! oracle: the least-squares solution of the normal equations, solved by Gaussian
//! elimination in f64, for the prior (θ̂₀, P₀) and the block's weighted samples.

// The oracle's elimination and products index rows and columns together, as the textbook
// writes them; iterators would hide the algebra it is checked against.
#![allow(clippy::needless_range_loop)]

use visco_core::estimator::{BlockStats, Estimator, EstimatorKind, EstimatorParams};

const T_US: f64 = 1.0;

fn params(kind: EstimatorKind, n_block: u32) -> EstimatorParams<f64, 3> {
    let period = T_US * n_block as f64;
    EstimatorParams {
        kind,
        period,
        inv_period: 1.0 / period,
        alpha: 0.5,
        forget: 1.0, // β = 0: the block is then exactly the batch solution
        r0: 1e9,
        p0: [4.0, 0.5, 2.0],
        gain: [0.02 * period, 0.01 * period, 0.03 * period],
        theta_min: [-1e6; 3],
        theta_max: [1e6; 3],
    }
}

/// A reproducible pseudo-random sequence in [−1, 1) (xorshift; no shared code with the core).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

fn solve3(mut a: [[f64; 3]; 3], mut b: [f64; 3]) -> [f64; 3] {
    for c in 0..3 {
        let p = (c..3)
            .max_by(|&i, &j| a[i][c].abs().partial_cmp(&a[j][c].abs()).unwrap())
            .unwrap();
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..3 {
            let f = a[r][c] / a[c][c];
            for k in c..3 {
                a[r][k] -= f * a[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 3];
    for r in (0..3).rev() {
        let mut s = b[r];
        for k in r + 1..3 {
            s -= a[r][k] * x[k];
        }
        x[r] = s / a[r][r];
    }
    x
}

#[test]
fn least_squares_block_is_the_batch_solution() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    for n in [1usize, 2, 3, 8, 32, 64] {
        let p = params(EstimatorKind::LeastSquares, n as u32);
        let theta0 = [0.3, -0.2, 0.1];
        let mut est = Estimator::new(&p, theta0);
        let truth = [1.5, 0.7, -0.4];
        // Normal equations of the oracle: (P₀⁻¹ + Σ ω φφᵀ)·θ = P₀⁻¹·θ₀ + Σ ω φ w.
        let mut m = [[0.0; 3]; 3];
        let mut r = [0.0; 3];
        for i in 0..3 {
            m[i][i] = 1.0 / p.p0[i];
            r[i] = theta0[i] / p.p0[i];
        }
        let mut stats = BlockStats::<f64, 3>::default();
        for _ in 0..n {
            let phi = [rng.next(), rng.next(), 1.0 + 0.1 * rng.next()];
            let w: f64 = (0..3).map(|i| truth[i] * phi[i]).sum::<f64>() + 0.05 * rng.next();
            let m2 = 1.0 + p.alpha * phi.iter().map(|x| x * x).sum::<f64>();
            let omega = T_US / m2;
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += omega * phi[i] * phi[j];
                }
                r[i] += omega * phi[i] * w;
            }
            stats.add(1.0 / T_US, p.alpha / T_US, w, &phi);
        }
        let want = solve3(m, r);
        est.update_block(&p, &stats);
        let got = est.theta();
        for i in 0..3 {
            assert!(
                (got[i] - want[i]).abs() < 1e-9 * (1.0 + want[i].abs()),
                "N = {n}, θ{i}: block {} vs batch {}",
                got[i],
                want[i]
            );
        }
        // And P is the inverse of the oracle's information matrix.
        let pm = est.covariance();
        for i in 0..3 {
            for j in 0..3 {
                let prod: f64 = (0..3).map(|k| pm[i][k] * m[k][j]).sum();
                let id = if i == j { 1.0 } else { 0.0 };
                assert!(
                    (prod - id).abs() < 1e-9,
                    "N = {n}: (P·P⁻¹)[{i}][{j}] = {prod}"
                );
            }
        }
    }
}

#[test]
fn gradient_block_is_the_sum_of_the_steps_with_theta_held() {
    let mut rng = Rng(12345);
    let n = 32;
    let p = params(EstimatorKind::Gradient, n);
    let theta0 = [0.3, -0.2, 0.1];
    let mut est = Estimator::new(&p, theta0);
    let mut stats = BlockStats::<f64, 3>::default();
    let mut step = [0.0; 3];
    for _ in 0..n {
        let phi = [rng.next(), rng.next(), 1.0];
        let w = 2.0 * phi[0] - phi[1] + 0.5;
        let m2 = 1.0 + p.alpha * phi.iter().map(|x| x * x).sum::<f64>();
        let e = w - (0..3).map(|i| theta0[i] * phi[i]).sum::<f64>();
        for i in 0..3 {
            // Γ·T·φ·e/m² per sample, Γ = gain / (N·T).
            step[i] += p.gain[i] / p.period * T_US * phi[i] * e / m2;
        }
        stats.add(1.0 / T_US, p.alpha / T_US, w, &phi);
    }
    est.update_block(&p, &stats);
    for i in 0..3 {
        let want = theta0[i] + step[i];
        assert!((est.theta()[i] - want).abs() < 1e-12, "θ{i}");
    }
}

#[test]
fn block_divergence_inputs_are_the_mean_squares() {
    let p = params(EstimatorKind::LeastSquares, 4);
    let theta0 = [1.0, 2.0, 3.0];
    let mut est = Estimator::new(&p, theta0);
    let mut stats = BlockStats::<f64, 3>::default();
    let (mut ee, mut ww, mut wsum) = (0.0, 0.0, 0.0);
    for k in 0..4 {
        let phi = [k as f64 * 0.1, 1.0 - k as f64 * 0.2, 1.0];
        let w = 5.0 + k as f64;
        let m2 = 1.0 + p.alpha * phi.iter().map(|x| x * x).sum::<f64>();
        let e = w - (0..3).map(|i| theta0[i] * phi[i]).sum::<f64>();
        ee += T_US / m2 * e * e;
        ww += T_US / m2 * w * w;
        wsum += T_US / m2;
        stats.add(1.0 / T_US, p.alpha / T_US, w, &phi);
    }
    let bi = est.update_block(&p, &stats);
    assert!((bi.e_ms - ee / wsum).abs() < 1e-12 * (ee / wsum));
    assert!((bi.w_ms - ww / wsum).abs() < 1e-12 * (ww / wsum));
}
