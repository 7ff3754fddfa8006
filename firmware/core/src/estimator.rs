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
//!
//! ## Block schedule
//! With `Config`'s `estimator.decimation` = N > 1 the loop does not update per sample: the
//! block's information, `A = Σ ω·φφᵀ`, `b = Σ ω·φ·w` (and `Σ ω·w²`, `Σ ω` for the divergence
//! watch), is accumulated with the law's weight `ω = T/m²` per sample ([`BlockStats::add`], by
//! the estimator task from the samples the loop hands over, see [`crate::schedule`]), and
//! [`Estimator::update_block`] applies the block in one step: forgetting `(1 + βNT)` once, then
//! `P ← (Q⁻¹ + A)⁻¹` as N ≤ 3 rank-one Sherman–Morrison updates along the columns of A's
//! `LDLᵀ` factors (the same stable step as per sample, P stays positive definite), and
//! `θ̂ ← θ̂ + P·(b − A·θ̂)`. That is the exact least-squares solution for the block's samples
//! with the prior (θ̂, Q): no sample is skipped; only the forgetting inside the block is
//! lumped (a relative weight error below N·β·T, 10⁻² for N = 32 and a 3 ms memory at 1 MHz),
//! and θ̂ is held over the block instead of moving per sample. The gradient law likewise:
//! `θ̂ ← θ̂ + Γ·(b − A·θ̂)`, stable for `N·T·γ/α ≤ 1` (what `Config::validate` checks).

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

/// The information of a block of samples for `w = θᵀφ`: `Σ ω·φφᵀ` (upper triangle), `Σ ω·φ·w`,
/// `Σ ω·w²` and `Σ ω`, with the least-squares law's weight `ω = T/m²`, `m² = 1 + α·φᵀφ`.
#[derive(Clone, Copy, Debug)]
pub struct BlockStats<T, const N: usize> {
    /// Σ ω·φφᵀ, upper triangle (`a[i][j]`, `i ≤ j`).
    pub a: [[T; N]; N],
    /// Σ ω·φ·w.
    pub b: [T; N],
    /// Σ ω·w².
    pub ww: T,
    /// Σ ω.
    pub weight: T,
    /// Samples in the block.
    pub samples: u32,
}

impl<T: Real, const N: usize> Default for BlockStats<T, N> {
    fn default() -> Self {
        Self {
            a: [[T::ZERO; N]; N],
            b: [T::ZERO; N],
            ww: T::ZERO,
            weight: T::ZERO,
            samples: 0,
        }
    }
}

impl<T: Real, const N: usize> BlockStats<T, N> {
    /// Adds one sample. `inv_period` is 1/T and `alpha_inv_period` α/T of the loop period T,
    /// so `ω = 1/(1/T + α/T·φᵀφ) = T/m²`.
    #[inline(always)]
    pub fn add(&mut self, inv_period: T, alpha_inv_period: T, w: T, phi: &[T; N]) {
        let mut phiphi = T::ZERO;
        for p in phi {
            phiphi += *p * *p;
        }
        let omega = T::ONE / (inv_period + alpha_inv_period * phiphi);
        let ow = omega * w;
        for i in 0..N {
            let oi = omega * phi[i];
            for j in i..N {
                self.a[i][j] += oi * phi[j];
            }
            self.b[i] += phi[i] * ow;
        }
        self.ww += ow * w;
        self.weight += omega;
        self.samples += 1;
    }

    /// Empty again. Every sum is stored from one opaque zero: stores of a constant zero
    /// become a `memset` call on the M7 (36 or 60 bytes, above the 8 stores LLVM inlines),
    /// ~90 instructions where the stores are ~10 (`cargo xtask profile`).
    #[inline(always)]
    pub fn clear(&mut self) {
        let z = core::hint::black_box(T::ZERO);
        self.a = [[z; N]; N];
        self.b = [z; N];
        self.ww = z;
        self.weight = z;
        self.samples = 0;
    }
}

/// What one block update did, beyond [`UpdateInfo`]: the divergence watch's inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlockInfo<T> {
    /// The update's flags.
    pub info: UpdateInfo,
    /// Weighted mean square of the a-priori prediction error `w − θ̂ᵀφ` over the block.
    pub e_ms: T,
    /// Weighted mean square of w over the block.
    pub w_ms: T,
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

    /// A parameter beyond its bound brought back along P's column (see "Projection"); true
    /// when one was.
    #[inline(always)]
    fn project_along_p(&self, params: &EstimatorParams<T, N>, theta: &mut [T; N]) -> bool {
        let mut projected = false;
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
                projected = true;
            }
        }
        projected
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

    /// One block update with the information `s` of N samples (see "Block schedule").
    pub fn update_block(
        &mut self,
        params: &EstimatorParams<T, N>,
        s: &BlockStats<T, N>,
    ) -> BlockInfo<T> {
        let mut out = BlockInfo::default();
        if s.samples == 0 || !(s.weight > T::ZERO) {
            return out;
        }
        // r = b − A·θ̂ (A symmetric from its upper triangle).
        let a = |i: usize, j: usize| if i <= j { s.a[i][j] } else { s.a[j][i] };
        let mut r = s.b;
        for i in 0..N {
            for j in 0..N {
                r[i] -= a(i, j) * self.theta[j];
            }
        }
        // Σω·e² = Σω·w² − 2θ̂ᵀb + θ̂ᵀAθ̂ = Σω·w² − θ̂ᵀ(b + r).
        let mut ee = s.ww;
        for i in 0..N {
            ee -= self.theta[i] * (s.b[i] + r[i]);
        }
        let inv_weight = T::ONE / s.weight;
        // Rounding can leave a tiny negative sum of squares.
        let ee0 = if ee > T::ZERO { ee } else { T::ZERO };
        out.e_ms = ee0 * inv_weight;
        out.w_ms = s.ww * inv_weight;
        self.last_error = out.e_ms;
        let inf = T::from_f64(f64::INFINITY);
        if !(finite(ee) && s.ww < inf) {
            // Non-finite data restart P rather than poison θ (as per sample).
            if params.kind == EstimatorKind::LeastSquares {
                self.reset_covariance(params);
            }
            out.info.reset = true;
            return out;
        }
        let mut theta = self.theta;
        match params.kind {
            EstimatorKind::LeastSquares => {
                let f = if self.trace() * params.forget <= params.r0 {
                    params.forget
                } else {
                    out.info.at_bound = true;
                    T::ONE
                };
                for i in 0..N {
                    for j in i..N {
                        self.p[i][j] *= f;
                    }
                }
                // A = L·D·Lᵀ; a pivot that is not clearly positive (a direction the block
                // holds no information in, up to rounding) is dropped with its column.
                let mut l = [[T::ZERO; N]; N];
                let mut d = [T::ZERO; N];
                let tiny = T::from_f64(1e-6);
                for j in 0..N {
                    let mut dj = s.a[j][j];
                    for k in 0..j {
                        dj -= l[j][k] * l[j][k] * d[k];
                    }
                    if !(dj > tiny * s.a[j][j]) || !(dj > T::ZERO) {
                        continue;
                    }
                    d[j] = dj;
                    l[j][j] = T::ONE;
                    let inv = T::ONE / dj;
                    for i in j + 1..N {
                        let mut v = s.a[j][i];
                        for k in 0..j {
                            v -= l[i][k] * l[j][k] * d[k];
                        }
                        l[i][j] = v * inv;
                    }
                }
                // P ← (P⁻¹ + Σ d_j·l_j·l_jᵀ)⁻¹, one Sherman–Morrison step per column.
                for j in 0..N {
                    if d[j] == T::ZERO {
                        continue;
                    }
                    let mut g = [T::ZERO; N];
                    let mut lg = T::ZERO;
                    for i in 0..N {
                        let mut acc = T::ZERO;
                        for k in j..N {
                            acc += self.pij(i, k) * l[k][j];
                        }
                        g[i] = acc;
                    }
                    for k in j..N {
                        lg += l[k][j] * g[k];
                    }
                    let den = T::ONE + d[j] * lg;
                    if !(den >= T::ONE && den < inf) {
                        self.reset_covariance(params);
                        out.info.reset = true;
                        return out;
                    }
                    let c = d[j] / den;
                    let mut definite = true;
                    for i in 0..N {
                        let gi = g[i] * c;
                        for k in i..N {
                            self.p[i][k] -= gi * g[k];
                        }
                        definite &= self.p[i][i] > T::ZERO;
                    }
                    if !definite {
                        self.reset_covariance(params);
                        out.info.reset = true;
                        return out;
                    }
                }
                // θ̂ ← θ̂ + P·r with the updated P.
                let mut inside = true;
                for i in 0..N {
                    let mut dt = T::ZERO;
                    for k in 0..N {
                        dt += self.pij(i, k) * r[k];
                    }
                    theta[i] += dt;
                    inside &= theta[i] >= params.theta_min[i] && theta[i] <= params.theta_max[i];
                }
                if inside {
                    self.theta = theta;
                    return out;
                }
                out.info.projected = self.project_along_p(params, &mut theta);
                let (theta, hit) = self.project(params, theta);
                self.theta = theta;
                out.info.projected |= hit;
            }
            EstimatorKind::Gradient => {
                // Γ = gain/T_block: θ̂ ← θ̂ + Γ·(b − Aθ̂), the sum of the per-sample steps with
                // θ̂ held over the block.
                for i in 0..N {
                    theta[i] += params.gain[i] * params.inv_period * r[i];
                }
                let (theta, hit) = self.project(params, theta);
                self.theta = theta;
                out.info.projected = hit;
            }
        }
        out
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
                info.projected = self.project_along_p(params, &mut theta);
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
