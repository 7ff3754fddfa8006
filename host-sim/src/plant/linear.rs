//! Exact propagation of `M·z̈ + c·ż + k·z = F` (F constant) over an interval τ.
//!
//! Between changes of the active set the tip obeys this equation with `c = C + S_c`,
//! `k = K + S_k` and `F = K·U + S_kt (+ noise and extra terms)`, all constant over the DAC
//! period (the input is held). Written as a deviation from the equilibrium `z_eq = F/k`:
//!
//! ```text
//! [z(τ) − z_eq, ż(τ)] = Φ(τ) · [z(0) − z_eq, ż(0)],   Φ(τ) = e^{Aτ},  A = [[0, 1], [−k/M, −c/M]]
//! ```
//!
//! which needs no input vector at all (`g0 = (I − Φ)·[1/k, 0]ᵀ` is implied). `Φ` has a closed
//! form from Cayley–Hamilton, `(A − μI)² = s²I` with `μ = −c/2M`, `s² = μ² − k/M`:
//!
//! ```text
//! Φ(τ) = e^{μτ} [ cosh(sτ)·I + sinh(sτ)/s · (A − μI) ]
//! ```
//!
//! evaluated in the form that is accurate in each regime: with the two real eigenvalues
//! `λ₂ = μ − s`, `λ₁ = (k/M)/λ₂` (no cancellation in the slow one) when `sτ > 1/2` — the stiff,
//! heavily damped contact, c/M ≈ 1 µs⁻¹ —, with `cosh` and `sinh(x)/x` for small `sτ` (near
//! critical damping, where the eigenvalue form would cancel), with `cos`/`sin` when underdamped
//! (the free cantilever). It costs one `exp` and one `sinh`/`cosh` or `sin`/`cos` pair, so the
//! plant can afford it at every active-set change inside a step, where τ is arbitrary. The
//! whole-step matrices are cached per active set. `visco_core::discretize::discretize2` (Van
//! Loan) is the reference the unit tests check this against.

/// `Φ(τ)` for one (M, c, k, τ).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Propagator {
    pub phi: [[f64; 2]; 2],
}

/// `sinh(x)/x`, accurate for all x (series near 0, where the quotient would lose digits).
#[inline]
fn sinhc(x: f64) -> f64 {
    let x2 = x * x;
    if x2 < 0.01 {
        // Error of the truncated series below x¹⁰/11! < 3e-18 for |x| < 0.1.
        1.0 + x2 / 6.0 * (1.0 + x2 / 20.0 * (1.0 + x2 / 42.0 * (1.0 + x2 / 72.0)))
    } else {
        x.sinh() / x
    }
}

/// `sin(x)/x`, accurate for all x.
#[inline]
fn sinc(x: f64) -> f64 {
    let x2 = x * x;
    if x2 < 0.01 {
        1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0)))
    } else {
        x.sin() / x
    }
}

impl Propagator {
    /// Closed-form `e^{Aτ}` for `M·z̈ + c·ż + k·z = F`; requires `m > 0`, `c ≥ 0`, `k > 0`,
    /// `tau ≥ 0` (the plant validates its configuration so these hold).
    pub fn new(m: f64, c: f64, k: f64, tau: f64) -> Self {
        Self::from_rates(k / m, -0.5 * c / m, tau)
    }

    /// [`Self::new`] from `a0 = k/M` and `mu = −c/(2M)`, for a caller that holds 1/M (the
    /// divisions are a fair share of the cost where every τ is new).
    pub fn from_rates(a0: f64, mu: f64, tau: f64) -> Self {
        let s2 = mu * mu - a0;
        let phi = if s2 > 0.0 && s2.sqrt() * tau > 0.05 {
            // Overdamped, well separated eigenvalues.
            let s = s2.sqrt();
            let l2 = mu - s;
            let l1 = a0 / l2;
            let (e1, e2) = ((l1 * tau).exp(), (l2 * tau).exp());
            let inv_d = 1.0 / (l1 - l2);
            let p01 = (e1 - e2) * inv_d;
            [
                [(l1 * e2 - l2 * e1) * inv_d, p01],
                [-a0 * p01, (l1 * e1 - l2 * e2) * inv_d],
            ]
        } else {
            // e^{μτ}·(cosh or cos)(|s|τ) and e^{μτ}·τ·(sinh(x)/x or sin(x)/x).
            let e = (mu * tau).exp();
            let (ch, shc) = if s2 >= 0.0 {
                // sτ ≤ 0.05 here: the series are exact to rounding, no libm call.
                let x2 = s2 * tau * tau;
                let ch = 1.0 + x2 / 2.0 * (1.0 + x2 / 12.0 * (1.0 + x2 / 30.0 * (1.0 + x2 / 56.0)));
                (ch, sinhc(x2.sqrt()))
            } else {
                let x = (-s2).sqrt() * tau;
                let (sn, cs) = x.sin_cos();
                (cs, if x * x < 0.01 { sinc(x) } else { sn / x })
            };
            let ech = e * ch;
            let esh = e * tau * shc; // e^{μτ} sinh(sτ)/s
            [[ech - mu * esh, esh], [-a0 * esh, ech + mu * esh]]
        };
        Propagator { phi }
    }

    /// Advance `(z, ż)` with the equilibrium `z_eq`.
    #[inline(always)]
    pub fn apply(&self, z: f64, v: f64, z_eq: f64) -> (f64, f64) {
        let dz = z - z_eq;
        let p = &self.phi;
        (
            z_eq + p[0][0] * dz + p[0][1] * v,
            p[1][0] * dz + p[1][1] * v,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use visco_core::discretize::{discretize2, mass_spring_damper};

    /// Against Van Loan's exponential over the regimes the plant meets: the free cantilever
    /// (Q = 100), near-critical damping, the stiff submerged tip, a huge damping, tiny τ.
    #[test]
    fn matches_van_loan() {
        let m = 11.8;
        let cases = [
            (0.0148, 0.18),
            (0.0148, 0.0),
            (2.0 * (11.8f64 * 0.2).sqrt(), 0.2), // critical
            (2.0 * (11.8f64 * 0.2).sqrt() * 1.0001, 0.2),
            (2.0 * (11.8f64 * 0.2).sqrt() * 0.9999, 0.2),
            (3.0, 0.2),
            (14.0, 0.26),
            (500.0, 3.0),
        ];
        for &(c, k) in &cases {
            for &tau in &[1e-9, 1e-4, 0.1, 0.5, 1.0, 2.0, 7.3] {
                let k = if k == 0.0 { 1e-12 } else { k };
                let p = Propagator::new(m, c, k, tau);
                let (a, b) = mass_spring_damper(m, c, k);
                let d = discretize2(a, b, tau);
                for i in 0..2 {
                    for j in 0..2 {
                        let err = (p.phi[i][j] - d.phi[i][j]).abs();
                        assert!(
                            err < 1e-12 * (1.0 + d.phi[i][j].abs()),
                            "c={c} k={k} tau={tau} [{i}][{j}]: {} vs {}",
                            p.phi[i][j],
                            d.phi[i][j]
                        );
                    }
                }
                // The equilibrium form reproduces Van Loan's input response g0 for F = 1.
                let (z, v) = p.apply(0.0, 0.0, 1.0 / k);
                assert!((z - d.g0[0]).abs() < 1e-9 * (1.0 + d.g0[0].abs()) + 1e-12 / k);
                assert!((v - d.g0[1]).abs() < 1e-12 * (1.0 + d.g0[1].abs()));
            }
        }
    }
}
