//! Parameter estimators for the linear-in-the-parameters model `w = θᵀφ` (19).
//!
//! ## Least squares with forgetting factor, (20)–(25)
//! The paper's continuous law is
//! ```text
//! ε = (w − θ̂ᵀφ)/m²,  m² = 1 + α·φᵀφ,  dθ̂/dt = P·ε·φ,
//! dP/dt = β·P − P·φφᵀ·P/m²  while ‖P‖ ≤ R₀, else 0,  P(0) = P₀.
//! ```
//! In information form this is `d(P⁻¹)/dt = −β·P⁻¹ + φφᵀ/m²`. We discretise *that* exactly over
//! one loop period `T` for a sample-and-hold φ: `P⁻¹ ← (1 − βT)·P⁻¹ + T·φφᵀ/m²`, and apply the
//! rank-one update with the Sherman–Morrison formula:
//! ```text
//! Q = P/(1 − βT) ≈ (1 + βT)·P         (forgetting; skipped when tr Q would exceed R₀)
//! g = Q·φ,  den = m²/T + φᵀg
//! P ← Q − g·gᵀ/den,   θ̂ ← θ̂ + g·(w − θ̂ᵀφ)/den   (= θ̂ + T·P·φ·ε, the law above)
//! ```
//! This is the recursive least-squares algorithm with weight `T/m²` per sample. As `T → 0` it
//! is the paper's law; unlike its forward-Euler discretisation (which needs `T·R₀/α < 1` to
//! keep P positive definite and `< 2` to be stable) it is **stable for every loop rate and
//! every α, β, R₀, P₀**: P stays symmetric positive definite with `tr P ≤ R₀`, and the
//! parameter error is non-increasing in the `P⁻¹` norm up to the forgetting factor. The
//! tests check this at loop rates and gains where forward Euler diverges.
//!
//! The norm in the bound is the trace (cheap, and ≥ the spectral norm of a positive
//! semi-definite P, so `tr P ≤ R₀` implies `‖P‖₂ ≤ R₀`). The paper stops P entirely above R₀;
//! we stop only the forgetting there and keep the data term, which can only shrink P — this
//! keeps the bound invariant without freezing the gain.
//!
//! ## Normalised gradient law
//! `dθ̂/dt = Γ·ε·φ` with diagonal Γ, discretised by forward Euler: `θ̂ ← θ̂ + T·Γ·φ·ε`. Its error
//! dynamics `θ̃ ← (I − T·Γφφᵀ/m²)·θ̃` are stable when `T·γ_max·φᵀφ/m² < 2`, and since
//! `φᵀφ/m² < 1/α` for every φ, **`T·γ_max/α < 2` makes it stable for every input**
//! (`Config::validate` enforces `T·γ_max/α ≤ 1`, which also makes it monotone). A few
//! multiply–adds per parameter: the paper's "cheap alternative" (6.3).
//!
//! ## Projection
//! Each parameter is kept in a box `[θ_min, θ_max]` after every update; for the spring constant
//! this is the paper's projection of k̂ into `[k_min, k_max]` (SVE divides by k̂), for the others
//! it bounds the estimates for any input sequence, finite or not. For least squares a parameter
//! that leaves its bound is first brought back along the column of P (the orthogonal
//! projection in the P⁻¹ metric, as in Ioannou & Sun's projection for least squares), so the
//! other parameters stay consistent with the data; a plain clamp alone lets an early transient
//! pin k̂ at its bound while the offset θ̂₃ is still far off, which was measured to stall the
//! three-parameter fit for ~10 ms.

use crate::real::Real;

/// Which estimator runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EstimatorKind {
    /// Least squares with forgetting factor (20)–(25).
    LeastSquares,
    /// Normalised gradient law.
    Gradient,
}

/// The estimator's constants, in the core's internal units.
#[derive(Clone, Copy, Debug)]
pub struct EstimatorParams<T, const N: usize> {
    /// Which law.
    pub kind: EstimatorKind,
    /// Loop period T.
    pub period: T,
    /// 1/T.
    pub inv_period: T,
    /// α of m² = 1 + α·φᵀφ.
    pub alpha: T,
    /// 1 + β·T, the per-sample forgetting factor.
    pub forget: T,
    /// R₀, bound on tr P.
    pub r0: T,
    /// Diagonal of P₀.
    pub p0: [T; N],
    /// T·Γ (diagonal) of the gradient law.
    pub gain: [T; N],
    /// Lower bounds of θ.
    pub theta_min: [T; N],
    /// Upper bounds of θ.
    pub theta_max: [T; N],
}

/// What one update did, for the status word and for fault detection.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UpdateInfo {
    /// The covariance was at its bound, so forgetting was skipped.
    pub at_bound: bool,
    /// A parameter hit its projection limit.
    pub projected: bool,
    /// The update was rejected (non-finite data or lost positive definiteness) and P reset.
    pub reset: bool,
}

/// A recursive estimator of `N` parameters.
///
/// P is symmetric: only its upper triangle (`p[i][j]`, `i ≤ j`) is kept up to date;
/// [`Estimator::covariance`] returns the whole matrix.
#[derive(Clone, Copy, Debug)]
pub struct Estimator<T, const N: usize> {
    theta: [T; N],
    p: [[T; N]; N],
    last_error: T,
}

/// `x` is finite: `x − x` is 0 for every finite x and NaN for ±∞ and NaN (two float
/// instructions, where the bit test moves the value to an integer register first).
#[inline(always)]
#[allow(clippy::eq_op)] // x − x is the point: 0 for finite x, NaN otherwise.
fn finite<T: Real>(x: T) -> bool {
    x - x == T::ZERO
}

impl<T: Real, const N: usize> Estimator<T, N> {
    /// Start at `theta0` with covariance P₀.
    pub fn new(params: &EstimatorParams<T, N>, theta0: [T; N]) -> Self {
        let mut e = Self {
            theta: theta0,
            p: [[T::ZERO; N]; N],
            last_error: T::ZERO,
        };
        e.reset_covariance(params);
        e.theta = e.project(params, theta0).0;
        e
    }

    /// P ← P₀.
    pub fn reset_covariance(&mut self, params: &EstimatorParams<T, N>) {
        for i in 0..N {
            for j in 0..N {
                self.p[i][j] = if i == j { params.p0[i] } else { T::ZERO };
            }
        }
    }

    /// Restart from `theta0` with P₀ (start of a tap).
    pub fn restart(&mut self, params: &EstimatorParams<T, N>, theta0: [T; N]) {
        self.reset_covariance(params);
        self.theta = self.project(params, theta0).0;
        self.last_error = T::ZERO;
    }

    /// The current estimate θ̂.
    #[inline(always)]
    pub fn theta(&self) -> [T; N] {
        self.theta
    }

    /// The covariance P (for tests and telemetry).
    pub fn covariance(&self) -> [[T; N]; N] {
        let mut p = self.p;
        for i in 0..N {
            for j in 0..i {
                p[i][j] = self.p[j][i];
            }
        }
        p
    }

    /// P[i][j] from the upper triangle.
    #[inline(always)]
    fn pij(&self, i: usize, j: usize) -> T {
        if i <= j {
            self.p[i][j]
        } else {
            self.p[j][i]
        }
    }

    /// The last prediction error w − θ̂ᵀφ (before the update).
    pub fn last_error(&self) -> T {
        self.last_error
    }

    /// tr P.
    #[inline(always)]
    pub fn trace(&self) -> T {
        let mut t = T::ZERO;
        for i in 0..N {
            t += self.p[i][i];
        }
        t
    }

    #[inline(always)]
    fn project(&self, params: &EstimatorParams<T, N>, mut theta: [T; N]) -> ([T; N], bool) {
        let mut hit = false;
        for i in 0..N {
            let v = theta[i].clamp_to(params.theta_min[i], params.theta_max[i]);
            // `!=` is also true for a NaN that clamp_to replaced.
            hit |= v != theta[i];
            theta[i] = v;
        }
        (theta, hit)
    }

    /// One update with the measurement `w` and regressor `phi`.
    #[inline(always)]
    pub fn update(&mut self, params: &EstimatorParams<T, N>, w: T, phi: &[T; N]) -> UpdateInfo {
        let mut pred = T::ZERO;
        let mut phiphi = T::ZERO;
        for i in 0..N {
            pred += self.theta[i] * phi[i];
            phiphi += phi[i] * phi[i];
        }
        let e = w - pred;
        self.last_error = e;
        let m2 = T::ONE + params.alpha * phiphi;
        let mut info = UpdateInfo::default();
        match params.kind {
            EstimatorKind::LeastSquares => {
                let trace = self.trace();
                let f = if trace * params.forget <= params.r0 {
                    params.forget
                } else {
                    info.at_bound = true;
                    T::ONE
                };
                let mut g = [T::ZERO; N];
                let mut phig = T::ZERO;
                for i in 0..N {
                    let mut s = T::ZERO;
                    for j in 0..N {
                        s += self.pij(i, j) * phi[j];
                    }
                    g[i] = f * s;
                    phig += phi[i] * g[i];
                }
                let den = m2 * params.inv_period + phig;
                // den > 0 for a positive definite P; anything else (NaN, overflow, lost
                // definiteness through rounding) restarts P rather than poison θ.
                let inf = T::from_f64(f64::INFINITY);
                if !(den > T::ZERO && den < inf && finite(e)) {
                    self.reset_covariance(params);
                    info.reset = true;
                    return info;
                }
                let inv = T::ONE / den;
                let mut definite = true;
                for i in 0..N {
                    let gi = g[i] * inv;
                    for j in i..N {
                        self.p[i][j] = f * self.p[i][j] - gi * g[j];
                    }
                    definite &= self.p[i][i] > T::ZERO;
                }
                if !definite {
                    self.reset_covariance(params);
                    info.reset = true;
                    return info;
                }
                let k = e * inv;
                let mut theta = self.theta;
                let mut inside = true;
                for i in 0..N {
                    theta[i] += g[i] * k;
                    // False for NaN as well.
                    inside &= theta[i] >= params.theta_min[i] && theta[i] <= params.theta_max[i];
                }
                if inside {
                    // Nothing to project (what follows would leave θ as it is).
                    self.theta = theta;
                    return info;
                }
                // A parameter beyond its bound is brought back along P's column, the projection
                // in the P⁻¹ metric: the others move as the least-squares fit with that
                // parameter fixed would move them, instead of keeping an update that was
                // computed for a value the bound forbids. The box clamp then catches the rest.
                for i in 0..N {
                    let excess = if theta[i] > params.theta_max[i] {
                        theta[i] - params.theta_max[i]
                    } else if theta[i] < params.theta_min[i] {
                        theta[i] - params.theta_min[i]
                    } else {
                        T::ZERO
                    };
                    if excess != T::ZERO {
                        let s = excess / self.p[i][i];
                        for j in 0..N {
                            theta[j] -= self.pij(j, i) * s;
                        }
                        info.projected = true;
                    }
                }
                let (theta, hit) = self.project(params, theta);
                self.theta = theta;
                info.projected |= hit;
            }
            EstimatorKind::Gradient => {
                if !(m2 > T::ZERO) || !m2.is_finite() || !e.is_finite() {
                    info.reset = true;
                    return info;
                }
                let eps = e / m2;
                let mut theta = self.theta;
                for i in 0..N {
                    theta[i] += params.gain[i] * phi[i] * eps;
                }
                let (theta, hit) = self.project(params, theta);
                self.theta = theta;
                info.projected = hit;
            }
        }
        info
    }
}
