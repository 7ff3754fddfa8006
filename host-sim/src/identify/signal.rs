//! Small signal tools shared by the modes: smoothing, robust statistics, the sphere-on-bed
//! geometry of the quasi-static law, and a running summary.

use visco_core::geometry::{contact_radius, mean_sag};

/// Volume of the sphere's part below the surface when the apex is `delta` deep in a flat
/// element bed: what the bed's springs are compressed by, summed over the footprint.
///
/// `V = π δ² (R − δ/3)` (a spherical cap) for δ ≤ R; beyond the equator the elements under
/// the tip stay those of the disk of radius R, each pressed by `δ − s(r)`, so
/// `V = π R² (δ − R/3)`. Always `V = A(δ)·(δ − s̄(δ))` with `A = π a²` the contact area and `s̄`
/// the mean sag of [`visco_core::geometry::mean_sag`]; `dV/dδ = A`.
pub fn cap_volume(r: f64, delta: f64) -> f64 {
    if delta <= 0.0 {
        0.0
    } else if delta <= r {
        std::f64::consts::PI * delta * delta * (r - delta / 3.0)
    } else {
        std::f64::consts::PI * r * r * (delta - r / 3.0)
    }
}

/// Contact area `π a²` of the sphere at apex depth `delta` (m²), `dV/dδ`.
pub fn contact_area(r: f64, delta: f64) -> f64 {
    let a = contact_radius(r, delta);
    std::f64::consts::PI * a * a
}

/// The apex depth δ whose effective depth `δ − s̄(δ)` (= V/A, the depth an aggregate spring
/// would need to carry the bed's force) is `effective`.
pub fn apex_depth_from_effective(r: f64, effective: f64) -> f64 {
    if !(effective > 0.0) {
        return 0.0;
    }
    // δ − s̄ grows monotonically from δ/2 (shallow) to δ − R/3 (submerged).
    if effective >= 2.0 * r / 3.0 {
        return effective + r / 3.0;
    }
    let (mut lo, mut hi) = (effective, 2.0 * effective + 1e-30);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if mid - mean_sag(r, mid) < effective {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Centred moving average with half-width `half` (window `2·half + 1`, shortened at the ends).
pub fn moving_average(v: &[f64], half: usize) -> Vec<f64> {
    let n = v.len();
    let mut prefix = Vec::with_capacity(n + 1);
    prefix.push(0.0);
    let mut s = 0.0;
    for x in v {
        s += x;
        prefix.push(s);
    }
    (0..n)
        .map(|i| {
            let a = i.saturating_sub(half);
            let b = (i + half + 1).min(n);
            (prefix[b] - prefix[a]) / (b - a) as f64
        })
        .collect()
}

/// The grid-and-golden-section minimiser, which lives with the other shared numerics.
pub use crate::numerics::minimize;

/// Least squares of `y = a·x₁ + b·x₂` with `b ≥ 0`, from the normal-equation sums
/// (Σx₁², Σx₁x₂, Σx₂², Σx₁y, Σx₂y, Σy²), solved with both columns scaled to unit norm and
/// projected onto `b = 0` when it would be negative: (a, b, residual sum of squares).
pub fn two_column_nonneg(
    s11: f64,
    s12: f64,
    s22: f64,
    s1y: f64,
    s2y: f64,
    syy: f64,
) -> (f64, f64, f64) {
    if !(s11 > 0.0) {
        return (0.0, 0.0, syy);
    }
    let (n1, n2) = (s11.sqrt(), s22.sqrt().max(f64::MIN_POSITIVE));
    let (a11, a12, a22) = (1.0, s12 / (n1 * n2), s22 / (n2 * n2));
    let (b1, b2) = (s1y / n1, s2y / n2);
    let det = a11 * a22 - a12 * a12;
    let (mut a, mut b) = if det > 1e-12 {
        (
            (a22 * b1 - a12 * b2) / det / n1,
            (a11 * b2 - a12 * b1) / det / n2,
        )
    } else {
        (b1 / n1, 0.0)
    };
    if b < 0.0 {
        b = 0.0;
        a = s1y / s11;
    }
    let rss = syy - 2.0 * (a * s1y + b * s2y) + a * a * s11 + 2.0 * a * b * s12 + b * b * s22;
    (a, b, rss.max(0.0))
}

/// Median of a copy of `v` (NaN-free input).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut w = v.to_vec();
    w.sort_by(|a, b| a.total_cmp(b));
    let m = w.len() / 2;
    if w.len() % 2 == 1 {
        w[m]
    } else {
        0.5 * (w[m - 1] + w[m])
    }
}

/// Robust standard deviation: 1.4826 × the median absolute deviation from the median.
pub fn robust_sigma(v: &[f64]) -> f64 {
    let m = median(v);
    let dev: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    1.4826 * median(&dev)
}

/// Root mean square.
pub fn rms(v: impl IntoIterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x * x;
        n += 1;
    }
    if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    }
}

/// The first-order low-pass `1/(λs + 1)` for samples at arbitrary times, exact for a signal
/// that is linear between samples (first-order hold). Used on both sides of a
/// linear-in-the-parameters identity, so that nothing is differentiated: `s·x/(λs + 1) =
/// (x − x_f)/λ`.
#[derive(Clone, Copy, Debug)]
pub struct FohLowPass {
    lambda: f64,
    y: f64,
    x: f64,
}

impl FohLowPass {
    /// At rest at `x0`.
    pub fn new(lambda: f64, x0: f64) -> Self {
        Self {
            lambda,
            y: x0,
            x: x0,
        }
    }

    /// Takes the sample `x` after `dt` and returns the filtered value.
    pub fn update(&mut self, dt: f64, x: f64) -> f64 {
        let r = dt / self.lambda;
        let a = (-r).exp();
        // y' = (x − y)/λ with x linear from self.x to x over dt.
        let b = if r > 1e-6 {
            1.0 - (1.0 - a) / r
        } else {
            0.5 * r
        };
        self.y = a * self.y + (1.0 - a) * self.x + (x - self.x) * b;
        self.x = x;
        self.y
    }
}

/// Running count, mean, minimum and maximum.
#[derive(Clone, Copy, Debug)]
pub struct Summary {
    /// Values seen.
    pub n: u64,
    sum: f64,
    sum2: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
}

impl Default for Summary {
    fn default() -> Self {
        Summary {
            n: 0,
            sum: 0.0,
            sum2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }
}

impl Summary {
    /// Adds a value (non-finite values are skipped).
    pub fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.n += 1;
            self.sum += v;
            self.sum2 += v * v;
            self.min = self.min.min(v);
            self.max = self.max.max(v);
        }
    }

    /// Mean (NaN when empty).
    pub fn mean(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            self.sum / self.n as f64
        }
    }

    /// Standard deviation (population; NaN when empty).
    pub fn std(&self) -> f64 {
        if self.n == 0 {
            return f64::NAN;
        }
        let m = self.mean();
        (self.sum2 / self.n as f64 - m * m).max(0.0).sqrt()
    }

    /// Root mean square (NaN when empty).
    pub fn rms(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.sum2 / self.n as f64).sqrt()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn volume_is_area_times_effective_depth_and_its_derivative_is_the_area() {
        let r = 300e-9;
        for delta in [1e-9, 50e-9, 150e-9, 299e-9, 300e-9, 450e-9] {
            let v = cap_volume(r, delta);
            let a = contact_area(r, delta);
            let eff = delta - mean_sag(r, delta);
            assert!((v / (a * eff) - 1.0).abs() < 1e-9, "δ = {delta}");
            let h = 1e-12;
            let dv = (cap_volume(r, delta + h) - cap_volume(r, delta - h)) / (2.0 * h);
            assert!(
                (dv / a - 1.0).abs() < 1e-5,
                "δ = {delta}: dV/dδ {dv} vs A {a}"
            );
            assert!((apex_depth_from_effective(r, eff) / delta - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn foh_lowpass_is_exact_for_a_ramp() {
        // x = t: y = t − λ(1 − e^{−t/λ}) from rest at 0.
        let lambda = 0.01;
        let mut f = FohLowPass::new(lambda, 0.0);
        let mut t = 0.0;
        for k in 0..200 {
            let dt = if k % 3 == 0 { 1e-3 } else { 2.5e-4 };
            t += dt;
            let y = f.update(dt, t);
            let exact = t - lambda * (1.0 - (-t / lambda).exp());
            assert!((y - exact).abs() < 1e-12, "{y} vs {exact}");
        }
    }
}
