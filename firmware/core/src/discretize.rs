//! Exact discretisation of second-order linear systems.
//!
//! Both the prefilter 1/Λ(s) of the estimator and the simulated cantilever of the host
//! are second-order linear systems `ẋ = A·x + b·u`. Between samples the input is either held
//! (a DAC: zero-order hold) or, for a smooth signal known only at the samples, interpolated
//! linearly (first-order hold). For both the exact solution over one period `h` is
//!
//! ```text
//! x(t+h) = Φ·x(t) + g0·u(t) + g1·u̇        with u(τ) = u(t) + u̇·(τ − t) on [t, t+h)
//! ```
//!
//! where `Φ = e^{A h}`, `g0 = ∫₀ʰ e^{Aτ} b dτ` and `g1 = ∫₀ʰ e^{Aτ} b (h − τ) dτ`. All three come
//! from one exponential of the augmented matrix `[[A, b, 0], [0, 0, 1], [0, 0, 0]]·h`
//! (Van Loan's method), computed here by scaling and squaring of a Taylor series in f64.
//!
//! This runs once when a configuration is validated (and, in the simulator, when the contact
//! changes), never at loop rate, so it may be slow; it must be accurate: the Taylor series is
//! summed to machine precision after scaling the matrix to a norm below 1/2.

/// The weight `a` of a one-pole low-pass `y += a·(x − y)` stepped every period: the exact
/// discretisation of `τ·ẏ = x − y` with a held input, `a = 1 − e^{−ω·h}`, from `ω·h` (the
/// corner's angular frequency times the period, 2π·f_c·h).
pub fn one_pole_weight(omega_h: f64) -> f64 {
    1.0 - libm::exp(-omega_h)
}

/// One period of an exactly discretised two-state linear system with a scalar input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Discrete2 {
    /// State transition `e^{A h}`.
    pub phi: [[f64; 2]; 2],
    /// Response to the input's value at the start of the period.
    pub g0: [f64; 2],
    /// Response to the input's slope over the period.
    pub g1: [f64; 2],
}

impl Discrete2 {
    /// Advance the state by one period with the input held at `u0` (zero-order hold).
    #[inline]
    pub fn step_zoh(&self, x: [f64; 2], u0: f64) -> [f64; 2] {
        [
            self.phi[0][0] * x[0] + self.phi[0][1] * x[1] + self.g0[0] * u0,
            self.phi[1][0] * x[0] + self.phi[1][1] * x[1] + self.g0[1] * u0,
        ]
    }

    /// Advance the state by one period with the input going linearly from `u0` to `u1`
    /// (first-order hold); `h` is the period the system was discretised at.
    #[inline]
    pub fn step_foh(&self, x: [f64; 2], u0: f64, u1: f64, h: f64) -> [f64; 2] {
        let slope = (u1 - u0) / h;
        [
            self.phi[0][0] * x[0] + self.phi[0][1] * x[1] + self.g0[0] * u0 + self.g1[0] * slope,
            self.phi[1][0] * x[0] + self.phi[1][1] * x[1] + self.g0[1] * u0 + self.g1[1] * slope,
        ]
    }
}

/// Discretise `ẋ = A·x + b·u` exactly over a period `h` (see the module docs).
pub fn discretize2(a: [[f64; 2]; 2], b: [f64; 2], h: f64) -> Discrete2 {
    let mut m = [[0.0f64; 4]; 4];
    for i in 0..2 {
        for j in 0..2 {
            m[i][j] = a[i][j] * h;
        }
        m[i][2] = b[i] * h;
    }
    m[2][3] = h;
    let e = expm4(&m);
    // The augmented state is [x, u, u̇·h/h]: column 3 multiplies u̇ (the slope), because the
    // (2,3) entry carries the factor h.
    Discrete2 {
        phi: [[e[0][0], e[0][1]], [e[1][0], e[1][1]]],
        g0: [e[0][2], e[1][2]],
        g1: [e[0][3], e[1][3]],
    }
}

/// The mass–spring–damper `m·ÿ + c·ẏ + k·y = u` as `ẋ = A x + b u` with `x = [y, ẏ]`.
pub fn mass_spring_damper(m: f64, c: f64, k: f64) -> ([[f64; 2]; 2], [f64; 2]) {
    ([[0.0, 1.0], [-k / m, -c / m]], [0.0, 1.0 / m])
}

fn matmul4(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut r = [[0.0f64; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            let mut s = 0.0;
            for k in 0..4 {
                s += a[i][k] * b[k][j];
            }
            r[i][j] = s;
        }
    }
    r
}

/// Matrix exponential of a 4×4 matrix by scaling and squaring with a Taylor series.
pub fn expm4(m: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    // Infinity norm, then halve until below 1/2.
    let mut norm = 0.0f64;
    for row in m {
        let s: f64 = row.iter().map(|v| if *v < 0.0 { -*v } else { *v }).sum();
        if s > norm {
            norm = s;
        }
    }
    let mut squarings = 0u32;
    let mut scale = 1.0f64;
    while norm * scale > 0.5 && squarings < 200 {
        scale *= 0.5;
        squarings += 1;
    }
    let mut a = [[0.0f64; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            a[i][j] = m[i][j] * scale;
        }
    }
    // Taylor series: with ‖a‖ ≤ 1/2, 20 terms reach 2^-20/20! ≪ f64 epsilon.
    let mut result = [[0.0f64; 4]; 4];
    let mut term = [[0.0f64; 4]; 4];
    for i in 0..4 {
        result[i][i] = 1.0;
        term[i][i] = 1.0;
    }
    for k in 1..=20u32 {
        term = matmul4(&term, &a);
        let inv_k = 1.0 / k as f64;
        for i in 0..4 {
            for j in 0..4 {
                term[i][j] *= inv_k;
                result[i][j] += term[i][j];
            }
        }
    }
    for _ in 0..squarings {
        result = matmul4(&result, &result);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_order_lag_matches_closed_form() {
        // ẋ1 = -x1/τ + u/τ embedded in a 2-state system with a decoupled second state.
        let tau = 3.0;
        let h = 0.7;
        let a = [[-1.0 / tau, 0.0], [0.0, -2.0]];
        let b = [1.0 / tau, 0.0];
        let d = discretize2(a, b, h);
        let e = libm::exp(-h / tau);
        assert!((d.phi[0][0] - e).abs() < 1e-14);
        assert!((d.g0[0] - (1.0 - e)).abs() < 1e-14);
        // Ramp response of a first-order lag: ∫₀ʰ e^{-τ'/τ}/τ (h−τ') dτ' = h − τ(1 − e^{-h/τ}).
        assert!((d.g1[0] - (h - tau * (1.0 - e))).abs() < 1e-14);
    }

    #[test]
    fn undamped_oscillator_rotates() {
        let w = 2.0;
        let h = 0.1;
        let d = discretize2([[0.0, 1.0], [-w * w, 0.0]], [0.0, 0.0], h);
        let (s, c) = (libm::sin(w * h), libm::cos(w * h));
        assert!((d.phi[0][0] - c).abs() < 1e-14);
        assert!((d.phi[0][1] - s / w).abs() < 1e-14);
        assert!((d.phi[1][0] + w * s).abs() < 1e-13);
    }

    #[test]
    fn stiff_damped_system_is_accurate() {
        // c/m·h ≈ 1.2 as in a cantilever in contact with the element bed (nm, nN, µs units).
        let (a, b) = mass_spring_damper(11.8, 14.0, 0.26);
        let d = discretize2(a, b, 1.0);
        // Step response with zero-order hold against the closed form of the two real poles.
        let (m, c, k) = (11.8f64, 14.0f64, 0.26f64);
        let disc = libm::sqrt(c * c - 4.0 * m * k);
        let p1 = (-c + disc) / (2.0 * m);
        let p2 = (-c - disc) / (2.0 * m);
        // y(t) = 1/k · (1 + (p2 e^{p1 t} − p1 e^{p2 t})/(p1 − p2)) for a unit step from rest.
        let y = |t: f64| (1.0 + (p2 * libm::exp(p1 * t) - p1 * libm::exp(p2 * t)) / (p1 - p2)) / k;
        let mut x = [0.0, 0.0];
        for n in 1..=500 {
            x = d.step_zoh(x, 1.0);
            let exact = y(n as f64);
            assert!((x[0] - exact).abs() <= 1e-10 * (1.0 + exact.abs()), "n={n}");
        }
    }
}
