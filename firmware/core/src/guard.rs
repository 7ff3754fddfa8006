//! Faults: what the loop does with bad input, a runaway force, a lost sample surface and an
//! estimator that is being misled. Each has a defined behaviour and a status bit.
//!
//! ## Input (every sample)
//! * **Non-finite** (a bus glitch, or a *missing* sample, which the board reports as NaN):
//!   rejected, flag `INPUT_INVALID`.
//! * **Saturated** (at or beyond the ADC's full scale): rejected, flag `INPUT_SATURATED`.
//! * **Spiking**: the tip has mass, so its position Z = U − D cannot change its velocity
//!   abruptly; a sample whose Z is further than `spike` from the straight-line prediction from
//!   the last two good ones (a bound on the second difference, from the excitation, a free
//!   ringing at f₀ and the noise) is rejected, flag `INPUT_SPIKE`. A test on the first
//!   difference would reject a legitimately fast tip (a cantilever ringing after it lost the
//!   sample); the prediction follows it. The allowed distance grows by `spike` with every
//!   sample since the last good one, plus the coasting velocity (the prediction coasts while
//!   the input is bad, and that velocity may be as wrong as itself), so the
//!   check re-locks after a burst of bad samples however the tip moved meanwhile, and a
//!   lasting offset is accepted after `offset / spike` samples instead of rejected forever.
//!
//! A rejected sample is replaced by the last good **tip position** Z (so D = U − Z follows the
//! DAC, and the prefilters see a held Z rather than a jump), and the estimator is frozen while
//! the input is bad and for `hold` samples after (ten prefilter time constants, until the held
//! values have left the filters); it resumes by itself.
//!
//! ## Force (every sample in contact)
//! The static tip force F = K·(D_free − D_lp) — the contact detector's low-passed deflection
//! against the free one — above `force_max` retracts the tip at once: U jumps up by the
//! indentation plus the clearance in the same sample, the excitation stops, flag `FORCE_LIMIT`.
//! The low-pass (5 kHz) is the only delay between the force and the retract.
//!
//! ## Contact (SVE)
//! F below the contact threshold for `lost` samples while scanning is a lost surface (a pit, a
//! cell edge): flag `CONTACT_LOST`, estimator and depth integrator frozen (no windup), the
//! excitation ramped out, and the tip re-approaches at the approach speed while the scan goes on;
//! a confirmed contact resumes everything (the depth integrator restarts from the U where the
//! contact was found).
//!
//! ## Estimator divergence (every update)
//! Three signs, each counted over consecutive updates: the covariance at its bound R₀
//! (forgetting has no information to forget into), a parameter pinned at a projection bound,
//! and a residual far beyond what the model leaves (a running mean of |w − θ̂ᵀφ| above
//! `residual_ratio` times the running mean of |w|: the model explains almost nothing). When
//! one lasts `diverge` updates (two estimator memories) the policy is: flag `EST_DIVERGED` and
//! reset P to P₀, keeping θ̂ — a fresh covariance lets the data take over again within a few
//! samples, where forgetting alone would need many memories.

use crate::estimator::UpdateInfo;
use crate::real::Real;
use core::num::NonZeroU32;

/// Constants of the fault handling (internal units).
#[derive(Clone, Copy, Debug)]
pub struct GuardParams<T> {
    /// Largest believable distance of Z from its straight-line prediction (nm).
    pub spike: T,
    /// Samples the estimator stays frozen after bad input.
    pub hold: u32,
    /// Static force limit (nN).
    pub force_max: T,
    /// Samples without contact force before SVE declares the surface lost (≥ 1: a sample
    /// with force is never a lost surface, and the check says so without a comparison).
    pub lost: NonZeroU32,
    /// Consecutive updates before a divergence sign triggers the reset.
    pub diverge: u32,
    /// Residual-to-measurement ratio beyond which the model explains nothing.
    pub residual_ratio: T,
    /// Weight of the running means of |e| and |w| (per block: of e² and w²) per update.
    pub mean_weight: T,
}

/// State of the fault handling.
#[derive(Clone, Copy, Debug, Default)]
pub struct Guard<T> {
    z_good: T,
    /// Z per sample at the last good sample (its difference from the one before).
    velocity: T,
    /// Prediction of Z for this sample: z_good coasting at `velocity`.
    predicted: T,
    /// Samples since the last good one (≥ 1 once a good sample was seen).
    elapsed: T,
    /// Largest believable |Z − predicted| now: `spike` per sample since the last good one.
    reach: T,
    /// Good samples seen since (re)priming, up to 2: position, then velocity known.
    known: u8,
    /// The last two samples were good and the hold is over: `known` is 2, `elapsed` 1, `hold`
    /// 0 and `predicted` is `z_good` in value (`predicted` itself is not stored while this
    /// holds), so a good sample needs neither their loads and stores nor the division by 1.
    steady: bool,
    hold: u32,
    lost_count: u32,
}

/// State of the estimator's divergence watch (it runs where the estimator runs: in the loop
/// per sample, or in the estimator task per block).
#[derive(Clone, Copy, Debug, Default)]
pub struct Watch<T> {
    bound_count: u32,
    projected_count: u32,
    residual_count: u32,
    e_mean: T,
    w_mean: T,
}

/// What the input check decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Input<T> {
    /// The deflection to use (m converted to internal units by the caller).
    pub d: T,
    /// True when the estimator may use this sample.
    pub ok: bool,
    /// Status bits raised.
    pub flags: u32,
}

impl<T: Real> Guard<T> {
    /// Check one ADC reading `d` (internal units) with the base at `u` (the DAC value held
    /// over the period that ends now); `d_max` is the ADC's full scale. Before a call with
    /// another `p.spike` than the last, call [`Self::leave_steady`].
    #[inline(always)]
    pub fn input(
        &mut self,
        p: &GuardParams<T>,
        d: T,
        u: T,
        d_max: T,
        flags: &FaultBits,
    ) -> Input<T> {
        self.input_with(p.spike, p.hold, d, u, d_max, flags)
    }

    /// [`Self::input`] with the two constants it uses, `spike` and `hold` of [`GuardParams`]
    /// (the controller keeps the running mode's next to its per-sample state). Before a call
    /// with another `spike` than the last, call [`Self::leave_steady`].
    #[inline(always)]
    pub fn input_with(
        &mut self,
        spike: T,
        hold: u32,
        d: T,
        u: T,
        d_max: T,
        flags: &FaultBits,
    ) -> Input<T> {
        self.input_by(|| (spike, hold), d, u, d_max, flags)
    }

    /// [`Self::input_with`] with `spike` and `hold` read by `consts` only off the steady path,
    /// which does not use them (issue 14, round 15: the loop's two loads of them per sample,
    /// hoisted ahead of the steady path's test, were dead there).
    #[inline(always)]
    pub fn input_by(
        &mut self,
        consts: impl FnOnce() -> (T, u32),
        d: T,
        u: T,
        d_max: T,
        flags: &FaultBits,
    ) -> Input<T> {
        let z = u - d;
        // In range (false for NaN), and not a jump of the tip.
        let in_range = d.abs_lt(d_max);
        if self.steady {
            // The path below with known = 2, elapsed = 1, predicted = z_good.
            let predicted = self.z_good + self.velocity;
            if in_range && (z - predicted).abs_lt(self.reach) {
                // (z − z_good)/1 = z − z_good exactly (both finite: d in range, U a DAC value).
                self.velocity = z - self.z_good;
                self.z_good = z;
                // `reach = spike` is stored already: the path below stored this `spike` when it
                // entered the steady path, and a caller that changes `spike` leaves the
                // steady path first ([`Self::leave_steady`]).
                return Input {
                    d,
                    ok: true,
                    flags: 0,
                };
            }
            // A bad sample: the stored state the path below expects, which finds it bad too.
            self.predicted = self.z_good;
            self.steady = false;
        }
        let (spike, hold) = consts();
        self.predicted += self.velocity;
        let jump = z - self.predicted;
        let plausible = self.known < 2 || jump.abs_lt(self.reach);
        if in_range && plausible {
            // The mean velocity since the last good sample (over the bad ones in between).
            self.velocity = if self.known == 0 {
                T::ZERO
            } else if !T::CHEAP_DIV && self.elapsed == T::ONE {
                // The usual case, a good sample after a good one: x/1 = x exactly, without
                // the fixed-point long division.
                z - self.z_good
            } else {
                (z - self.z_good) / self.elapsed
            };
            self.elapsed = T::ONE;
            self.z_good = z;
            self.predicted = z;
            self.reach = spike;
            let ok = self.hold == 0;
            if !ok {
                self.hold -= 1;
            }
            self.steady = self.known > 0 && self.hold == 0;
            self.known = if self.known > 0 { 2 } else { 1 };
            return Input { d, ok, flags: 0 };
        }
        let f = if !in_range {
            if d.is_finite() {
                flags.saturated
            } else {
                flags.invalid
            }
        } else {
            flags.spike
        };
        self.hold = hold;
        // The prediction coasts at the last velocity, which may itself be off by as much.
        self.reach += spike + self.velocity.abs();
        self.elapsed += T::ONE;
        // Hold the tip where it was: D follows the DAC.
        Input {
            d: u - self.z_good,
            ok: false,
            flags: f,
        }
    }

    /// Leave the steady path for the general one, which computes the same (call before
    /// [`Self::input_with`] takes another `spike`: the steady path does not store it).
    #[inline(always)]
    pub fn leave_steady(&mut self) {
        if self.steady {
            self.predicted = self.z_good;
            self.steady = false;
        }
    }

    /// Forget the last good tip position (after a jump of U that moves the tip legitimately
    /// fast, such as the force-limit retract).
    pub fn reprime(&mut self) {
        if self.steady {
            self.predicted = self.z_good;
            self.steady = false;
        }
        self.known = 0;
    }

    /// The SVE surface check: `no_force` when the low-passed force is below the contact
    /// threshold this sample; true once it has been so for `lost` samples.
    #[inline(always)]
    pub fn surface_lost(&mut self, p: &GuardParams<T>, no_force: bool) -> bool {
        if no_force {
            self.lost_count = self.lost_count.saturating_add(1);
        } else {
            self.lost_count = 0;
            return false;
        }
        self.lost_count >= p.lost.get()
    }

    /// Reset the surface check (contact found again).
    pub fn surface_found(&mut self) {
        self.lost_count = 0;
    }
}

impl<T: Real> Watch<T> {
    /// Watch one estimator update; true when the reset policy triggers (the counters restart).
    #[inline(always)]
    pub fn diverging(&mut self, p: &GuardParams<T>, info: UpdateInfo, e: T, w: T) -> bool {
        self.e_mean += p.mean_weight * (e.abs() - self.e_mean);
        self.w_mean += p.mean_weight * (w.abs() - self.w_mean);
        let far = self.e_mean > p.residual_ratio * self.w_mean;
        self.tally(p, info, far)
    }

    /// The reset policy shared by the per-sample and the per-block watch: `diverge` updates in a
    /// row at a bound, projected or far off; a trigger restarts the counters.
    #[inline(always)]
    fn tally(&mut self, p: &GuardParams<T>, info: UpdateInfo, far: bool) -> bool {
        let count = |c: &mut u32, on: bool| {
            *c = if on { c.saturating_add(1) } else { 0 };
            *c >= p.diverge
        };
        let a = count(&mut self.bound_count, info.at_bound);
        let b = count(&mut self.projected_count, info.projected);
        let c = count(&mut self.residual_count, far);
        if a || b || c {
            self.bound_count = 0;
            self.projected_count = 0;
            self.residual_count = 0;
            true
        } else {
            false
        }
    }

    /// Restart the divergence watch (a new tap or scan).
    pub fn restart(&mut self) {
        self.bound_count = 0;
        self.projected_count = 0;
        self.residual_count = 0;
        self.e_mean = T::ZERO;
        self.w_mean = T::ZERO;
    }

    /// Watch one block update: as [`Self::diverging`] with the block's mean squares of the
    /// prediction error and of w (running means of the squares, compared with the ratio
    /// squared: the RMS residual against `residual_ratio` times the RMS of w).
    #[inline(always)]
    pub fn diverging_ms(&mut self, p: &GuardParams<T>, info: UpdateInfo, e_ms: T, w_ms: T) -> bool {
        self.e_mean += p.mean_weight * (e_ms - self.e_mean);
        self.w_mean += p.mean_weight * (w_ms - self.w_mean);
        let far = self.e_mean > p.residual_ratio * p.residual_ratio * self.w_mean;
        self.tally(p, info, far)
    }
}

/// The status bits the guard raises (from [`crate::controller::status`]).
#[derive(Clone, Copy, Debug)]
pub struct FaultBits {
    /// Non-finite input.
    pub invalid: u32,
    /// Input at full scale.
    pub saturated: u32,
    /// Input jump.
    pub spike: u32,
}

/// The DIVE force limit decided on the low-passed deflection alone: the highest `lp` at which
/// `K·(d_free − lp) > force_max` in `T`'s arithmetic, so that the per-sample test
/// `!(lp > threshold)` fires for exactly the same `lp` (NaN included) as the force it replaces
/// — a comparison instead of a subtraction, a product and a comparison per sample.
///
/// Exact: the force is non-increasing in `lp` (a subtraction and a product by `K > 0`, each
/// correctly rounded or rounded half away and saturated, are monotone), so the values at which it
/// fires are all those up to one; that one is found by a search over the ranks of `T`'s values
/// ([`Real::rank`]): outward from the real-number threshold in doubling steps until bracketed,
/// then bisection (a few evaluations, at most ~130; once per tap, at the approach's start).
/// With `K` and `force_max` positive and finite (validated) the force does not fire at
/// `T::HIGHEST`, and it fires at `T::LOWEST` — the floats' K·∞ = ∞; Q31.32's saturated
/// K·(d_free − MIN) ≈ K·2³¹ nN, far above any force limit. Were it not to (a force limit that
/// can never fire), the threshold is `T::LOWEST` and differs from the force at that one value.
/// A NaN `d_free` fires everywhere: the threshold is then `T::HIGHEST`.
pub fn force_limit_lp<T: Real>(k: T, d_free: T, force_max: T) -> T {
    let fires = |lp: T| !(k * (d_free - lp) <= force_max);
    let (lowest, highest) = (T::LOWEST.rank(), T::HIGHEST.rank());
    let guess = d_free.to_f64() - force_max.to_f64() / k.to_f64();
    let guess = if guess.is_finite() {
        T::from_f64(guess).rank().clamp(lowest, highest)
    } else {
        0
    };
    // lo fires, hi does not.
    let (mut lo, mut hi);
    let mut step: i64 = 1;
    if fires(T::from_rank(guess)) {
        lo = guess;
        loop {
            if lo == highest {
                return T::HIGHEST;
            }
            let next = lo.saturating_add(step).min(highest);
            if !fires(T::from_rank(next)) {
                hi = next;
                break;
            }
            lo = next;
            step = step.saturating_mul(2);
        }
    } else {
        hi = guess;
        loop {
            if hi == lowest {
                // Fires nowhere (excluded by the validated K and force_max).
                return T::LOWEST;
            }
            let next = hi.saturating_sub(step).max(lowest);
            if fires(T::from_rank(next)) {
                lo = next;
                break;
            }
            hi = next;
            step = step.saturating_mul(2);
        }
    }
    // lo < hi, so lo + 1 cannot overflow; the midpoint is taken in i128 (the ranks span up to
    // 2⁶⁴, more than `hi − lo` holds; `i64::midpoint` is newer than the workspace's Rust 1.85),
    // rounded towards zero, and with hi ≥ lo + 2 it lies strictly between.
    while lo + 1 < hi {
        let mid = ((i128::from(lo) + i128::from(hi)) / 2) as i64;
        if fires(T::from_rank(mid)) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    T::from_rank(lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The threshold decides exactly as the force: around it (±64 ranks, where the roundings
    /// decide), at random values, at the extremes and for NaN, in f32, f64 and Q31.32, over
    /// random stiffnesses, free deflections and limits. Fails for a threshold one rank off.
    fn threshold_is_exact<T: Real>(seed: u64) {
        let mut x = seed;
        let mut rnd = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let k = T::from_f64(0.01 + 50.0 * rnd());
            let d_free = T::from_f64(-3000.0 + 6000.0 * rnd());
            let fmax = T::from_f64(1.0 + 500.0 * rnd());
            let th = force_limit_lp(k, d_free, fmax);
            let force_fires = |lp: T| !(k * (d_free - lp) <= fmax);
            let r = th.rank();
            assert!(force_fires(th) && !force_fires(T::from_rank(r + 1)));
            let check = |lp: T| assert_eq!(!(lp > th), force_fires(lp), "{lp:?} vs {th:?}");
            for dr in -64..=64 {
                check(T::from_rank(r + dr));
            }
            check(T::from_f64(-4000.0 + 8000.0 * rnd()));
            check(T::LOWEST);
            check(T::HIGHEST);
            #[allow(clippy::eq_op)] // 0/0: a NaN on purpose, in every number format
            check(T::ZERO / T::ZERO);
        }
    }

    /// Far from the usual numbers: thresholds beyond the finite range, a NaN free deflection
    /// (fires everywhere), Q31.32 near its ends; the search brackets across most of the ranks
    /// (without overflow: `cargo test` checks it) and still decides as the force.
    fn threshold_at_the_extremes<T: Real>(cases: &[(f64, f64, f64)]) {
        for &(k, d_free, fmax) in cases {
            let (k, d_free, fmax) = (T::from_f64(k), T::from_f64(d_free), T::from_f64(fmax));
            let th = force_limit_lp(k, d_free, fmax);
            let force_fires = |lp: T| !(k * (d_free - lp) <= fmax);
            let (lo, hi) = (T::LOWEST.rank(), T::HIGHEST.rank());
            let r = th.rank();
            let near = [r.saturating_sub(1), r, r.saturating_add(1)];
            for x in [lo, lo + 1, -(1 << 40), -1, 0, 1, 1 << 40, hi - 1, hi]
                .into_iter()
                .chain(near)
            {
                let lp = T::from_rank(x.clamp(lo, hi));
                assert_eq!(!(lp > th), force_fires(lp), "{lp:?} vs {th:?}");
            }
        }
    }

    #[test]
    fn force_limit_threshold_at_the_extremes() {
        let cases = [
            (1e-300, 0.0, 1e300),
            (1e300, 1e300, 1e-300),
            (1.0, f64::NAN, 100.0),
            (1.0, -1e308, 1e308),
        ];
        threshold_at_the_extremes::<f64>(&cases);
        threshold_at_the_extremes::<f32>(&[(1e-30, 0.0, 1e30), (1.0, f32::NAN as f64, 1.0)]);
        threshold_at_the_extremes::<crate::fixed::Q32>(&[
            (1e-3, 0.0, 2e6),
            (1.0, -2e9, 1e8),
            (2e9, 2e9, 1e-9),
        ]);
        // The one case the threshold cannot express: a limit the force never reaches (K·2³¹
        // below it, in Q31.32): the threshold is the lowest value, wrong there only.
        use crate::fixed::Q32;
        let (k, fmax) = (Q32::from_f64(1e-9), Q32::from_f64(2e9));
        let th = force_limit_lp(k, Q32::ZERO, fmax);
        assert_eq!(th, Q32::LOWEST);
        assert!(k * (Q32::ZERO - Q32::LOWEST) <= fmax);
        // Above it the test does not fire, as the force; at it, it does (the difference).
        assert!(Q32::from_rank(Q32::LOWEST.rank() + 1) > th);
        assert!(Q32::LOWEST <= th);
    }

    #[test]
    fn force_limit_threshold_is_exact() {
        threshold_is_exact::<f32>(1);
        threshold_is_exact::<f64>(2);
        threshold_is_exact::<crate::fixed::Q32>(3);
    }

    fn params() -> GuardParams<f64> {
        GuardParams {
            spike: 50.0,
            hold: 10,
            force_max: 100.0,
            lost: NonZeroU32::new(5).unwrap(),
            diverge: 20,
            residual_ratio: 0.3,
            mean_weight: 0.1,
        }
    }
    const BITS: FaultBits = FaultBits {
        invalid: 1,
        saturated: 2,
        spike: 4,
    };

    #[test]
    fn bad_samples_are_held_and_the_estimator_waits() {
        let p = params();
        let mut g = Guard::<f64>::default();
        let u = 100.0;
        // Two good samples: the position and the velocity known.
        assert!(g.input(&p, -20.0, u, 1000.0, &BITS).ok);
        assert!(g.input(&p, -20.0, u, 1000.0, &BITS).ok);
        // A NaN, a saturated value and a spike: each held at Z = 120, flagged.
        for (d, f) in [(f64::NAN, 1), (1000.0, 2), (-400.0, 4)] {
            let r = g.input(&p, d, u, 1000.0, &BITS);
            assert_eq!((r.flags, r.ok), (f, false));
            assert_eq!(u - r.d, 120.0);
        }
        // Good again: used at once, but the estimator waits `hold` samples.
        let mut waited = 0;
        while !g.input(&p, -20.5, u, 1000.0, &BITS).ok {
            waited += 1;
        }
        assert_eq!(waited, p.hold);
        // The held Z follows the DAC: with U moved by 30, the replacement D moved by 30.
        let r = g.input(&p, f64::INFINITY, u + 30.0, 1000.0, &BITS);
        assert_eq!(r.d, -20.5 + 30.0);
    }

    #[test]
    fn the_spike_check_relocks_after_the_tip_moved_during_bad_input() {
        let p = params();
        let mut g = Guard::<f64>::default();
        let u = 100.0;
        assert!(g.input(&p, 0.0, u, 1000.0, &BITS).ok);
        // Five missing samples while the tip moved by 200 (4 × spike): the next good sample
        // is within reach (6 × spike) and accepted.
        for _ in 0..5 {
            assert!(!g.input(&p, f64::NAN, u, 1000.0, &BITS).ok);
        }
        let r = g.input(&p, -200.0, u, 1000.0, &BITS);
        assert_eq!((r.flags, r.d), (0, -200.0));
        // The tip at rest again (the mean velocity over the gap is forgotten in one sample).
        assert_eq!(g.input(&p, -200.0, u, 1000.0, &BITS).flags, 0);
        assert_eq!(g.input(&p, -200.0, u, 1000.0, &BITS).flags, 0);
        // A lasting jump of 500 (10 × spike) is accepted after at most 10 samples.
        let mut rejected = 0;
        while g.input(&p, 300.0, u, 1000.0, &BITS).flags != 0 {
            rejected += 1;
            assert!(rejected <= 10);
        }
        assert_eq!(g.input(&p, 300.0, u, 1000.0, &BITS).flags, 0);
        assert_eq!(g.input(&p, 300.0, u, 1000.0, &BITS).flags, 0);
        // Whereas one isolated spike is rejected and the next sample accepted.
        assert_eq!(g.input(&p, -300.0, u, 1000.0, &BITS).flags, 4);
        assert_eq!(g.input(&p, 300.0, u, 1000.0, &BITS).flags, 0);
    }

    #[test]
    fn a_fast_but_smooth_tip_is_not_a_spike() {
        // A free cantilever ringing at 20 kHz with 300 nm amplitude, sampled at 500 kHz: Z moves
        // up to 75 nm per sample (far beyond `spike`), but its second difference is ≤ 19 nm.
        let p = params();
        let mut g = Guard::<f64>::default();
        let w = 2.0 * core::f64::consts::PI * 20e3 / 500e3;
        for n in 0..10_000 {
            let d = 300.0 * (w * n as f64).sin();
            assert_eq!(g.input(&p, d, 0.0, 1000.0, &BITS).flags, 0, "sample {n}");
        }
    }

    #[test]
    fn divergence_resets_after_a_sustained_sign_only() {
        let p = params();
        let mut g = Watch::<f64>::default();
        let at_bound = UpdateInfo {
            at_bound: true,
            ..Default::default()
        };
        for _ in 0..19 {
            assert!(!g.diverging(&p, at_bound, 0.01, 1.0));
        }
        assert!(
            !g.diverging(&p, UpdateInfo::default(), 0.01, 1.0),
            "interrupted: no reset"
        );
        let mut n = 0;
        while !g.diverging(&p, at_bound, 0.01, 1.0) {
            n += 1;
        }
        assert_eq!(n, p.diverge - 1);
        // A residual as large as the measurement for long.
        g.restart();
        let mut n = 0;
        while !g.diverging(&p, UpdateInfo::default(), 1.0, 1.0) {
            n += 1;
            assert!(n < 100);
        }
    }

    #[test]
    fn block_watch_compares_mean_squares_with_the_ratio_squared() {
        let p = params(); // ratio 0.3: far when the RMS residual exceeds 0.3 × RMS w
        let mut g = Watch::<f64>::default();
        // RMS ratio 0.29: never far.
        for _ in 0..1000 {
            assert!(!g.diverging_ms(&p, UpdateInfo::default(), 0.29 * 0.29, 1.0));
        }
        // RMS ratio 0.31: far once the running means have moved (weight 0.1), then `diverge`
        // blocks in a row.
        let mut n = 0;
        while !g.diverging_ms(&p, UpdateInfo::default(), 0.31 * 0.31, 1.0) {
            n += 1;
            assert!(n < 200, "never reset");
        }
        assert!(n >= p.diverge as usize - 1);
    }
}
