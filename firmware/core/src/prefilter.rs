//! The prefilter 1/Λ(s), Λ(s) = (λs + 1)², of the filtered system equations (18).
//!
//! One second-order state `[y, ẏ]` with `λ²ÿ + 2λẏ + y = x` gives, at each sample, the three
//! signals the regressors need without differentiating anything: `x/Λ = y`, `s·x/Λ = ẏ` and
//! `s²·x/Λ = (x − y − 2λẏ)/λ²`.
//!
//! ## Discretisation, and why there are two
//! The filter is discretised exactly at the loop period (no forward Euler), with the exact
//! matrices of [`crate::discretize`]. What "exactly" means depends on what the input does
//! between samples, and the estimator is very sensitive to getting this right:
//!
//! * **U, the DAC output, is a staircase** (zero-order hold): it jumps at each sample and is
//!   flat in between. [`Hold::Zero`] is then exact, to rounding.
//! * **Z = U − D, the tip position, is smooth** (the tip has mass); only its samples are
//!   known. Interpolating it linearly between samples (first-order hold) would be exact for a
//!   piecewise-linear Z, but for a smooth one the interpolant's mean over a period exceeds the
//!   signal's by `Z̈·T²/12`: every output would carry a gain `1 + T²s²/12` (0.13 % at 20 kHz
//!   and 1 MHz), and `s²Z/Λ`, which also uses the sample itself, an extra `T²/(12λ²)`
//!   (0.5 % at λ = 4T). Measured on the exact model, this biased k̂ by 0.3–0.5 % and ĉ by 0.1 %.
//!   [`Hold::Smooth`] therefore feeds the first-order hold with the sample minus a twelfth of
//!   its centred second difference, `x̃ₖ = xₖ − (xₖ₊₁ − 2xₖ + xₖ₋₁)/12`, which cancels the
//!   `T²s²/12` term (what remains is `0.011·(ωT)⁴`, 3·10⁻⁶ at 20 kHz), and forms `s²Z/Λ` with
//!   the true sample. The centred difference needs the next sample, so this filter's outputs
//!   describe the previous sample instant: **one sample of delay**, which the regressor gives
//!   the U filter too (see [`crate::regressor`]).
//!
//! Treating U like Z (smooth between samples) would shift it by half a sample against its true
//! staircase: at the paper's DIVE excitation (1 µm of U at 20 kHz) that error lands on the
//! spring term and biases the identified k by about 100 %. Treating both as staircases would
//! do the same to Z. Hence one filter of each kind.

use crate::discretize::discretize2;
use crate::real::Real;

/// What the filter's input does between two samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Hold {
    /// Held at the new sample's value over the whole period ending at that sample (a DAC);
    /// outputs at the new sample's instant.
    Zero,
    /// A smooth signal known at the samples; outputs one sample late (see the module docs).
    Smooth,
}

/// The discretised coefficients of 1/Λ(s) at one loop period.
#[derive(Clone, Copy, Debug)]
pub struct PrefilterCoeffs<T> {
    phi: [[T; 2]; 2],
    /// Input weights of the previous and of the new sample.
    g_prev: [T; 2],
    g_new: [T; 2],
    inv_lambda2: T,
    two_lambda: T,
    /// Weight of the centred second difference in the held input: 1/12 for a smooth signal.
    curvature: T,
    delayed: bool,
}

/// One period's recursion in f64: Φ and the weights of the held input at the period's start
/// and at its end (the per-sample coefficients before rounding to `T`).
fn per_sample_f64(lambda: f64, period: f64, hold: Hold) -> ([[f64; 2]; 2], [f64; 2], [f64; 2]) {
    let l2 = lambda * lambda;
    let a = [[0.0, 1.0], [-1.0 / l2, -2.0 / lambda]];
    let b = [0.0, 1.0 / l2];
    let d = discretize2(a, b, period);
    // Zero-order hold over (t_{k-1}, t_k] with the new value x_k: x(t) = x_k on the period.
    // First-order hold: x(t) = x_{k-1} + (x_k − x_{k-1})(t − t_{k-1})/h.
    let (g_prev, g_new) = match hold {
        Hold::Zero => ([0.0, 0.0], d.g0),
        Hold::Smooth => (
            [d.g0[0] - d.g1[0] / period, d.g0[1] - d.g1[1] / period],
            [d.g1[0] / period, d.g1[1] / period],
        ),
    };
    (d.phi, g_prev, g_new)
}

impl<T: Real> PrefilterCoeffs<T> {
    /// Coefficients for time constant `lambda` and period `period` (the same time unit), for an
    /// input held as `hold` between samples.
    pub fn new(lambda: f64, period: f64, hold: Hold) -> Self {
        let l2 = lambda * lambda;
        let (phi, g_prev, g_new) = per_sample_f64(lambda, period, hold);
        let t = |v: f64| T::from_f64(v);
        Self {
            phi: [[t(phi[0][0]), t(phi[0][1])], [t(phi[1][0]), t(phi[1][1])]],
            g_prev: [t(g_prev[0]), t(g_prev[1])],
            g_new: [t(g_new[0]), t(g_new[1])],
            inv_lambda2: t(1.0 / l2),
            two_lambda: t(2.0 * lambda),
            curvature: t(if hold == Hold::Smooth {
                1.0 / 12.0
            } else {
                0.0
            }),
            delayed: hold == Hold::Smooth,
        }
    }
}

impl<T: Real> PrefilterCoeffs<T> {
    /// `s²·x/Λ` of a [`Hold::Smooth`] filter from the sample its state describes (`x2`, the
    /// one before the latest) and the state `y`, `ẏ`: [`Prefilter::ddx_smooth`]'s
    /// operations, for a pass that keeps them apart.
    #[inline(always)]
    pub fn ddx(&self, x2: T, y: T, dy: T) -> T {
        (x2 - y - self.two_lambda * dy) * self.inv_lambda2
    }
}

/// Samples one group step advances a filter by ([`SmoothGroup`], [`HeldGroup`]): DIVE's
/// information sums take one sample in 4 at 1 MHz, and between two of them no output of the
/// filters is read (issue 14, round 12).
pub const GROUP: usize = 4;

/// Linear forms over a basis of `N` values, for unrolling a recursion exactly in f64.
type Form<const N: usize> = [f64; N];

fn unit<const N: usize>(i: usize) -> Form<N> {
    let mut f = [0.0; N];
    if let Some(v) = f.get_mut(i) {
        *v = 1.0;
    }
    f
}

/// `Σ aᵢ·fᵢ`.
fn comb<const N: usize>(terms: &[(f64, &Form<N>)]) -> Form<N> {
    let mut out = [0.0; N];
    for (a, f) in terms {
        for (o, v) in out.iter_mut().zip(f.iter()) {
            *o += a * v;
        }
    }
    out
}

/// [`GROUP`] samples of a [`Hold::Smooth`] filter in one step: the per-sample recursion
/// ([`Prefilter::advance_smooth`]) unrolled in f64, the new state a linear form of the old
/// state `[y, ẏ]`, the held input, the two samples before the group and the group's four.
/// Mathematically the per-sample steps; in f32 fewer roundings (9 products a state where the
/// per-sample steps chain 4 × 4).
#[derive(Clone, Copy, Debug)]
pub struct SmoothGroup<T> {
    /// Φ⁴.
    phi: [[T; 2]; 2],
    /// Weights of the held input, of x_{k−1}, x_k (before the group) and of the group's
    /// samples x_{k+1} … x_{k+4}, per state.
    w: [[T; 7]; 2],
    /// 1/12: the held input after the group, formed as the per-sample step forms it.
    curvature: T,
}

impl<T: Real> SmoothGroup<T> {
    /// For time constant `lambda` and period `period`, as [`PrefilterCoeffs::new`].
    pub fn new(lambda: f64, period: f64) -> Self {
        let (phi, gp, gn) = per_sample_f64(lambda, period, Hold::Smooth);
        let c = 1.0 / 12.0;
        // Basis: y, ẏ, held, x_{k−1}, x_k, x_{k+1} … x_{k+4}.
        let (mut y, mut dy, mut held) = (unit::<9>(0), unit::<9>(1), unit::<9>(2));
        let (mut x2, mut x1) = (unit::<9>(3), unit::<9>(4));
        for i in 0..GROUP {
            let x = unit::<9>(5 + i);
            // end = x1 − c·((x − x1) − (x1 − x2)).
            let end = comb(&[(1.0 + 2.0 * c, &x1), (-c, &x), (-c, &x2)]);
            let ny = comb(&[
                (phi[0][0], &y),
                (phi[0][1], &dy),
                (gp[0], &held),
                (gn[0], &end),
            ]);
            let ndy = comb(&[
                (phi[1][0], &y),
                (phi[1][1], &dy),
                (gp[1], &held),
                (gn[1], &end),
            ]);
            (y, dy, held, x2, x1) = (ny, ndy, end, x1, x);
        }
        let t = |v: f64| T::from_f64(v);
        let w = |f: &Form<9>| {
            [
                t(f[2]),
                t(f[3]),
                t(f[4]),
                t(f[5]),
                t(f[6]),
                t(f[7]),
                t(f[8]),
            ]
        };
        Self {
            phi: [[t(y[0]), t(y[1])], [t(dy[0]), t(dy[1])]],
            w: [w(&y), w(&dy)],
            curvature: t(c),
        }
    }

    /// Φ⁴ and the inputs' weights (held, x_{k−1}, x_k, x_{k+1} … x_{k+4}), per state: for
    /// error bounds in tests.
    pub fn coefficients(&self) -> ([[T; 2]; 2], [[T; 7]; 2]) {
        (self.phi, self.w)
    }
}

/// [`GROUP`] samples of a [`Hold::Zero`] filter in one step ([`Prefilter::update_held`]
/// unrolled in f64): the new state a linear form of the old and of the four held inputs.
#[derive(Clone, Copy, Debug)]
pub struct HeldGroup<T> {
    /// Φ⁴.
    phi: [[T; 2]; 2],
    /// Weights of the four inputs, per state.
    w: [[T; 4]; 2],
}

impl<T: Real> HeldGroup<T> {
    /// For time constant `lambda` and period `period`, as [`PrefilterCoeffs::new`].
    pub fn new(lambda: f64, period: f64) -> Self {
        let (phi, _, gn) = per_sample_f64(lambda, period, Hold::Zero);
        // Basis: y, ẏ, the four inputs.
        let (mut y, mut dy) = (unit::<6>(0), unit::<6>(1));
        for i in 0..GROUP {
            let x = unit::<6>(2 + i);
            let ny = comb(&[(phi[0][0], &y), (phi[0][1], &dy), (gn[0], &x)]);
            let ndy = comb(&[(phi[1][0], &y), (phi[1][1], &dy), (gn[1], &x)]);
            (y, dy) = (ny, ndy);
        }
        let t = |v: f64| T::from_f64(v);
        let w = |f: &Form<6>| [t(f[2]), t(f[3]), t(f[4]), t(f[5])];
        Self {
            phi: [[t(y[0]), t(y[1])], [t(dy[0]), t(dy[1])]],
            w: [w(&y), w(&dy)],
        }
    }

    /// Φ⁴ and the four inputs' weights, per state: for error bounds in tests.
    pub fn coefficients(&self) -> ([[T; 2]; 2], [[T; 4]; 2]) {
        (self.phi, self.w)
    }
}

/// The filtered signal and its first two derivatives: `x/Λ`, `s·x/Λ`, `s²·x/Λ`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Filtered<T> {
    /// x/Λ
    pub x: T,
    /// s·x/Λ
    pub dx: T,
    /// s²·x/Λ
    pub ddx: T,
}

/// The state of one prefilter.
#[derive(Clone, Copy, Debug, Default)]
pub struct Prefilter<T> {
    y: T,
    dy: T,
    /// x_{k-1} and x_{k-2} (raw samples).
    x1: T,
    x2: T,
    /// The held input at the start of the current period (compensated for a smooth signal).
    held: T,
}

impl<T: Real> Prefilter<T> {
    /// A filter at rest at the input level `x0` (steady state: y = x0, ẏ = 0), so that starting
    /// on a signal with a large offset does not ring.
    pub fn at_rest(x0: T) -> Self {
        Self {
            y: x0,
            dy: T::ZERO,
            x1: x0,
            x2: x0,
            held: x0,
        }
    }

    /// Take the new sample `x` and return the filtered outputs: at its instant for
    /// [`Hold::Zero`], at the previous sample's instant for [`Hold::Smooth`].
    #[inline(always)]
    pub fn update(&mut self, c: &PrefilterCoeffs<T>, x: T) -> Filtered<T> {
        // For a smooth signal the period just completed is (t_{k-2}, t_{k-1}]: its end value is
        // x_{k-1} less a twelfth of its centred second difference; for a staircase it is x_k.
        let (end, sample) = if c.delayed {
            (
                self.x1 - c.curvature * ((x - self.x1) - (self.x1 - self.x2)),
                self.x1,
            )
        } else {
            (x, x)
        };
        let y = c.phi[0][0] * self.y
            + c.phi[0][1] * self.dy
            + c.g_prev[0] * self.held
            + c.g_new[0] * end;
        let dy = c.phi[1][0] * self.y
            + c.phi[1][1] * self.dy
            + c.g_prev[1] * self.held
            + c.g_new[1] * end;
        self.y = y;
        self.dy = dy;
        self.held = end;
        self.x2 = self.x1;
        self.x1 = x;
        Filtered {
            x: y,
            dx: dy,
            ddx: (sample - y - c.two_lambda * dy) * c.inv_lambda2,
        }
    }

    /// [`Self::update`] for [`Hold::Smooth`] coefficients (the Z filter's path, without the
    /// run-time test of the hold): the new state, and `s²·x/Λ` of the previous sample.
    #[inline(always)]
    pub fn update_smooth(&mut self, c: &PrefilterCoeffs<T>, x: T) -> T {
        self.advance_smooth(c, x);
        self.ddx_smooth(c)
    }

    /// The state of [`Self::update_smooth`] alone: `s²·x/Λ` is left to
    /// [`Self::ddx_smooth`], for the samples that need it (the regressor's w, only while
    /// estimating), with the same operations on the same values.
    #[inline(always)]
    pub fn advance_smooth(&mut self, c: &PrefilterCoeffs<T>, x: T) {
        let end = self.x1 - c.curvature * ((x - self.x1) - (self.x1 - self.x2));
        let y = c.phi[0][0] * self.y
            + c.phi[0][1] * self.dy
            + c.g_prev[0] * self.held
            + c.g_new[0] * end;
        let dy = c.phi[1][0] * self.y
            + c.phi[1][1] * self.dy
            + c.g_prev[1] * self.held
            + c.g_new[1] * end;
        self.y = y;
        self.dy = dy;
        self.held = end;
        self.x2 = self.x1;
        self.x1 = x;
    }

    /// `s²·x/Λ` at the instant of the current state of a [`Hold::Smooth`] filter, i.e. of the
    /// sample before the latest (held in `x2` since [`Self::advance_smooth`]).
    #[inline(always)]
    pub fn ddx_smooth(&self, c: &PrefilterCoeffs<T>) -> T {
        c.ddx(self.x2, self.y, self.dy)
    }

    /// Take the new sample `x` of a staircase ([`Hold::Zero`] coefficients) and return `x/Λ` and
    /// `s·x/Λ` only: the U filter's path, which needs neither the previous sample nor the
    /// second derivative.
    #[inline(always)]
    pub fn update_held(&mut self, c: &PrefilterCoeffs<T>, x: T) -> (T, T) {
        let y = c.phi[0][0] * self.y + c.phi[0][1] * self.dy + c.g_new[0] * x;
        let dy = c.phi[1][0] * self.y + c.phi[1][1] * self.dy + c.g_new[1] * x;
        self.y = y;
        self.dy = dy;
        (y, dy)
    }

    /// [`GROUP`] samples `x` of a smooth signal at once ([`SmoothGroup`]): the state
    /// [`Self::advance_smooth`] leaves after the four, to the rounding of fewer operations.
    #[inline(always)]
    pub fn advance_smooth_group(&mut self, g: &SmoothGroup<T>, x: [T; GROUP]) {
        let [a1, a2, a3, a4] = x;
        let (w0, w1) = (&g.w[0], &g.w[1]);
        let y = g.phi[0][0] * self.y
            + g.phi[0][1] * self.dy
            + w0[0] * self.held
            + w0[1] * self.x2
            + w0[2] * self.x1
            + w0[3] * a1
            + w0[4] * a2
            + w0[5] * a3
            + w0[6] * a4;
        let dy = g.phi[1][0] * self.y
            + g.phi[1][1] * self.dy
            + w1[0] * self.held
            + w1[1] * self.x2
            + w1[2] * self.x1
            + w1[3] * a1
            + w1[4] * a2
            + w1[5] * a3
            + w1[6] * a4;
        self.y = y;
        self.dy = dy;
        // The last period's held input, as the per-sample step forms it.
        self.held = a3 - g.curvature * ((a4 - a3) - (a3 - a2));
        self.x2 = a3;
        self.x1 = a4;
    }

    /// [`GROUP`] held inputs `x` of a staircase at once ([`HeldGroup`]): the state four
    /// [`Self::update_held`] steps leave, returned as `x/Λ`, `s·x/Λ`.
    #[inline(always)]
    pub fn update_held_group(&mut self, g: &HeldGroup<T>, x: [T; GROUP]) -> (T, T) {
        let [a1, a2, a3, a4] = x;
        let (w0, w1) = (&g.w[0], &g.w[1]);
        let y = g.phi[0][0] * self.y
            + g.phi[0][1] * self.dy
            + w0[0] * a1
            + w0[1] * a2
            + w0[2] * a3
            + w0[3] * a4;
        let dy = g.phi[1][0] * self.y
            + g.phi[1][1] * self.dy
            + w1[0] * a1
            + w1[1] * a2
            + w1[2] * a3
            + w1[3] * a4;
        self.y = y;
        self.dy = dy;
        (y, dy)
    }

    /// The held input and the last two samples (for error bounds in tests).
    #[cfg(test)]
    pub(crate) fn inputs(&self) -> [T; 3] {
        [self.held, self.x2, self.x1]
    }

    /// The current outputs `x/Λ` and `s·x/Λ` without a new sample.
    #[inline(always)]
    pub fn state(&self) -> (T, T) {
        (self.y, self.dy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steady-state complex response of the discrete filter to a sampled sinusoid, measured by
    /// correlating the output against the input over an integer number of periods.
    fn measure(hold: Hold, f_per_sample: f64, lambda: f64) -> [(f64, f64); 3] {
        let delay = if hold == Hold::Smooth { 1.0 } else { 0.0 };
        let c = PrefilterCoeffs::<f64>::new(lambda, 1.0, hold);
        let mut p = Prefilter::<f64>::at_rest(0.0);
        let w = 2.0 * core::f64::consts::PI * f_per_sample;
        let n_settle = (40.0 * lambda) as usize + 1000;
        let periods = 200.0;
        let n = (periods / f_per_sample) as usize;
        let mut acc = [(0.0f64, 0.0f64); 3];
        for k in 0..n_settle + n {
            let t = k as f64;
            let out = p.update(&c, libm::sin(w * t));
            if k >= n_settle {
                // Correlate against the input at the instant the outputs describe.
                let (s, co) = (libm::sin(w * (t - delay)), libm::cos(w * (t - delay)));
                for (i, v) in [out.x, out.dx, out.ddx].iter().enumerate() {
                    acc[i].0 += v * s;
                    acc[i].1 += v * co;
                }
            }
        }
        let scale = 2.0 / n as f64;
        acc.map(|(a, b)| (a * scale, b * scale))
    }

    #[test]
    fn smooth_hold_matches_continuous_response() {
        // λ = 4 samples (corner 40 kHz at a 1 MHz loop), and 16 samples; frequencies up to 5 %
        // of the sample rate (50 kHz at 1 MHz), magnitude and phase of all three outputs.
        for (lambda, f) in [4.0, 16.0]
            .iter()
            .flat_map(|l| [1e-4, 1e-3, 5e-3, 1e-2, 2e-2, 5e-2].map(|f| (*l, f)))
        {
            let w = 2.0 * core::f64::consts::PI * f;
            let meas = measure(Hold::Smooth, f, lambda);
            // H(jω) = (jω)^k / (1 + jωλ)²
            let den_re = 1.0 - w * w * lambda * lambda;
            let den_im = 2.0 * w * lambda;
            let den2 = den_re * den_re + den_im * den_im;
            let h0 = (den_re / den2, -den_im / den2);
            let expected = [h0, (-w * h0.1, w * h0.0), (-w * w * h0.0, -w * w * h0.1)];
            for k in 0..3 {
                let (re, im) = (meas[k].0, meas[k].1); // output = re·sin + im·cos
                let (er, ei) = expected[k];
                let mag = libm::hypot(re, im);
                let emag = libm::hypot(er, ei);
                let phase = libm::atan2(im, re);
                let ephase = libm::atan2(ei, er);
                assert!(
                    (mag / emag - 1.0).abs() < 1e-3,
                    "f={f} k={k} mag {mag} vs {emag}"
                );
                let dphi = (phase - ephase + core::f64::consts::PI)
                    .rem_euclid(2.0 * core::f64::consts::PI)
                    - core::f64::consts::PI;
                assert!(dphi.abs() < 1e-3, "f={f} k={k} phase error {dphi}");
            }
        }
    }

    #[test]
    fn zero_order_hold_is_exact_for_a_staircase() {
        // Filter a staircase with the ZOH coefficients at period 1 and, as reference, with
        // coefficients at period 1/8 fed the same staircase 8 times per step: both exact.
        let lambda = 3.0;
        let c1 = PrefilterCoeffs::<f64>::new(lambda, 1.0, Hold::Zero);
        let c8 = PrefilterCoeffs::<f64>::new(lambda, 0.125, Hold::Zero);
        let mut p1 = Prefilter::at_rest(0.0);
        let mut p8 = Prefilter::at_rest(0.0);
        let mut ph = Prefilter::at_rest(0.0);
        for k in 0..2000 {
            let x = libm::sin(0.05 * k as f64) + if k % 7 == 0 { 1.0 } else { 0.0 };
            let o1 = p1.update(&c1, x);
            let mut o8 = Filtered::default();
            for _ in 0..8 {
                o8 = p8.update(&c8, x);
            }
            assert!((o1.x - o8.x).abs() < 1e-12 && (o1.dx - o8.dx).abs() < 1e-12);
            assert!((o1.ddx - o8.ddx).abs() < 1e-11);
            let (y, dy) = ph.update_held(&c1, x);
            assert!(
                y == o1.x && dy == o1.dx,
                "the held path must equal the general one"
            );
        }
    }

    #[test]
    fn smooth_path_equals_the_general_one() {
        let c = PrefilterCoeffs::<f32>::new(8.0, 1.0, Hold::Smooth);
        let (mut a, mut b) = (
            Prefilter::<f32>::at_rest(3.0),
            Prefilter::<f32>::at_rest(3.0),
        );
        for k in 0..5000 {
            let x = 3.0 + (k as f32 * 0.013).sin() * 40.0 + if k % 9 == 0 { 1.5 } else { 0.0 };
            let o = a.update(&c, x);
            let ddx = b.update_smooth(&c, x);
            assert_eq!(o.ddx.to_bits(), ddx.to_bits());
            let (y, dy) = b.state();
            assert_eq!((o.x.to_bits(), o.dx.to_bits()), (y.to_bits(), dy.to_bits()));
        }
    }

    #[test]
    fn unit_dc_gain_and_rest_start() {
        let c = PrefilterCoeffs::<f32>::new(4.0, 1.0, Hold::Smooth);
        let mut p = Prefilter::<f32>::at_rest(1234.5);
        for _ in 0..10 {
            let o = p.update(&c, 1234.5);
            assert!((o.x - 1234.5).abs() < 1e-3 && o.dx.abs() < 1e-4 && o.ddx.abs() < 1e-3);
        }
    }
}

/// A second-order high-pass `(sτ/(1 + sτ))²`, two first-order sections discretised by matched
/// poles. The decoupled SVE regression applies it alike to w and to φ (see
/// [`crate::config::SveRegressor::Decoupled`]): a filter applied to both sides of a
/// linear-in-the-parameters identity keeps it exact, and this one removes the slowly varying
/// offset `k·(h − z₀)` that the topography puts into w under a scanning tip.
#[derive(Clone, Copy, Debug, Default)]
pub struct HighPass<T> {
    x1: T,
    y1: T,
    y2: T,
}

impl<T: Real> HighPass<T> {
    /// The pole factor e^{−T/τ} for corner `corner_hz` at `sample_rate_hz`.
    pub fn coefficient(corner_hz: f64, sample_rate_hz: f64) -> T {
        T::from_f64(libm::exp(
            -2.0 * core::f64::consts::PI * corner_hz / sample_rate_hz,
        ))
    }

    /// At rest with the input at `x0` (both outputs zero).
    pub fn at_rest(x0: T) -> Self {
        Self {
            x1: x0,
            y1: T::ZERO,
            y2: T::ZERO,
        }
    }

    /// One sample.
    #[inline(always)]
    pub fn update(&mut self, a: T, x: T) -> T {
        let y1 = a * (self.y1 + x - self.x1);
        let y2 = a * (self.y2 + y1 - self.y1);
        self.x1 = x;
        self.y1 = y1;
        self.y2 = y2;
        y2
    }
}

#[cfg(test)]
mod highpass_tests {
    use super::*;

    #[test]
    fn highpass_rejects_slow_offsets_and_passes_tones() {
        let a = HighPass::<f64>::coefficient(600.0, 1e6);
        let gain = |f: f64| {
            let mut h = HighPass::<f64>::at_rest(0.0);
            let w = 2.0 * core::f64::consts::PI * f / 1e6;
            let mut peak = 0.0f64;
            for k in 0..2_000_000 {
                let y = h.update(a, libm::sin(w * k as f64) + 300.0);
                if k > 1_000_000 {
                    peak = peak.max(y.abs());
                }
            }
            peak
        };
        // Each section is H(z) = a(1 − z⁻¹)/(1 − a·z⁻¹); two in cascade: |H|².
        let exact = |f: f64| {
            let w = 2.0 * core::f64::consts::PI * f / 1e6;
            let num = 2.0 - 2.0 * libm::cos(w);
            let den = 1.0 - 2.0 * a * libm::cos(w) + a * a;
            a * a * num / den
        };
        for f in [50.0, 600.0, 4915.0, 19660.0] {
            let g = gain(f);
            assert!(
                (g / exact(f) - 1.0).abs() < 2e-3,
                "gain at {f} Hz: {g} vs {}",
                exact(f)
            );
        }
        // The tones pass, a 50 Hz drift of the operating point is cut 140-fold.
        assert!(gain(4915.0) > 0.98 && gain(50.0) < 0.0075);
    }
}
