//! Faults: what the loop does with bad input, a runaway force, a lost sample surface and an
//! estimator that is being misled. Each has a defined behaviour and a status bit.
//!
//! ## Input (every sample)
//! * **Non-finite** (a bus glitch, or a *missing* sample, which the board reports as NaN):
//!   rejected, flag `INPUT_INVALID`.
//! * **Saturated** (at or beyond the ADC's full scale): rejected, flag `INPUT_SATURATED`.
//! * **Spiking**: the tip has mass, so Z = U − D cannot jump; a sample whose Z moved by more
//!   than `spike` since the last good one (the largest believable tip motion per sample, from
//!   the excitation and the approach speed, with a margin) is rejected, flag `INPUT_SPIKE`.
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

/// Constants of the fault handling (internal units).
#[derive(Clone, Copy, Debug)]
pub struct GuardParams<T> {
    /// Largest believable change of the tip position Z between samples (nm).
    pub spike: T,
    /// Samples the estimator stays frozen after bad input.
    pub hold: u32,
    /// Static force limit (nN).
    pub force_max: T,
    /// Samples without contact force before SVE declares the surface lost.
    pub lost: u32,
    /// Consecutive updates before a divergence sign triggers the reset.
    pub diverge: u32,
    /// Residual-to-measurement ratio beyond which the model explains nothing.
    pub residual_ratio: T,
    /// Weight of the running means of |e| and |w| per update.
    pub mean_weight: T,
}

/// State of the fault handling.
#[derive(Clone, Copy, Debug, Default)]
pub struct Guard<T> {
    z_good: T,
    primed: bool,
    hold: u32,
    lost_count: u32,
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
    /// over the period that ends now); `d_max` is the ADC's full scale.
    #[inline(always)]
    pub fn input(
        &mut self,
        p: &GuardParams<T>,
        d: T,
        u: T,
        d_max: T,
        flags: &FaultBits,
    ) -> Input<T> {
        let z = u - d;
        // In range (false for NaN), and not a jump of the tip.
        let in_range = d > -d_max && d < d_max;
        let jump = z - self.z_good;
        let plausible = !self.primed || (jump < p.spike && jump > -p.spike);
        if in_range && plausible {
            self.z_good = z;
            self.primed = true;
            let ok = self.hold == 0;
            if !ok {
                self.hold -= 1;
            }
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
        self.hold = p.hold;
        // Hold the tip where it was: D follows the DAC.
        Input {
            d: u - self.z_good,
            ok: false,
            flags: f,
        }
    }

    /// Forget the last good tip position (after a jump of U that moves the tip legitimately
    /// fast, such as the force-limit retract).
    pub fn reprime(&mut self) {
        self.primed = false;
    }

    /// The SVE surface check: `no_force` when the low-passed force is below the contact
    /// threshold this sample; true once it has been so for `lost` samples.
    #[inline(always)]
    pub fn surface_lost(&mut self, p: &GuardParams<T>, no_force: bool) -> bool {
        if no_force {
            self.lost_count = self.lost_count.saturating_add(1);
        } else {
            self.lost_count = 0;
        }
        self.lost_count >= p.lost
    }

    /// Reset the surface check (contact found again).
    pub fn surface_found(&mut self) {
        self.lost_count = 0;
    }

    /// Watch one estimator update; true when the reset policy triggers (the counters restart).
    #[inline(always)]
    pub fn diverging(&mut self, p: &GuardParams<T>, info: UpdateInfo, e: T, w: T) -> bool {
        let count = |c: &mut u32, on: bool| {
            *c = if on { c.saturating_add(1) } else { 0 };
            *c >= p.diverge
        };
        self.e_mean += p.mean_weight * (e.abs() - self.e_mean);
        self.w_mean += p.mean_weight * (w.abs() - self.w_mean);
        let far = self.e_mean > p.residual_ratio * self.w_mean;
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
    pub fn restart_watch(&mut self) {
        self.bound_count = 0;
        self.projected_count = 0;
        self.residual_count = 0;
        self.e_mean = T::ZERO;
        self.w_mean = T::ZERO;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> GuardParams<f64> {
        GuardParams {
            spike: 50.0,
            hold: 10,
            force_max: 100.0,
            lost: 5,
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
    fn divergence_resets_after_a_sustained_sign_only() {
        let p = params();
        let mut g = Guard::<f64>::default();
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
        g.restart_watch();
        let mut n = 0;
        while !g.diverging(&p, UpdateInfo::default(), 1.0, 1.0) {
            n += 1;
            assert!(n < 100);
        }
    }
}
