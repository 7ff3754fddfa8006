//! The SVE depth controller (4.4): an integral controller (28) on the estimated depth.
//!
//! `δ = ĥ − Z` with `ĥ = θ̂₃/θ̂₂` (27), and `U_δ = kᵢ ∫ (δ_ref − δ) dτ`, discretised as a
//! rectangle-rule integrator at the loop period. The controller output is limited to the
//! piezo's range (less the excitation's amplitude, so that `U = U_exc + U_δ` never clips); the
//! integrator state *is* the output, so clamping it is the anti-windup: at a limit the
//! integrator stops, and it leaves the limit as soon as the error changes sign.
//!
//! Sign: a deeper tip needs a lower base, so `U_δ` decreases when `δ < δ_ref`.

use crate::real::Real;

/// Constants of the depth controller (internal units).
#[derive(Clone, Copy, Debug)]
pub struct DepthParams<T> {
    /// kᵢ·T, the integral gain times the loop period.
    pub ki_period: T,
    /// Lowest U_δ.
    pub u_min: T,
    /// Highest U_δ.
    pub u_max: T,
}

/// State of the depth controller.
#[derive(Clone, Copy, Debug, Default)]
pub struct DepthController<T> {
    u: T,
}

impl<T: Real> DepthController<T> {
    /// Start at the base position `u0` (bumpless transfer from the approach).
    pub fn new(u0: T) -> Self {
        Self { u: u0 }
    }

    /// The current output U_δ.
    pub fn output(&self) -> T {
        self.u
    }

    /// One sample: depth error `δ_ref − δ`; returns U_δ and whether it is at a limit.
    #[inline(always)]
    pub fn update(&mut self, p: &DepthParams<T>, depth_error: T) -> (T, bool) {
        // Deeper than wanted (error < 0) → raise the base (U up).
        let u = self.u - p.ki_period * depth_error;
        if u >= p.u_min && u <= p.u_max {
            // Inside the limits (false for NaN): what the clamp below would give.
            self.u = u;
            return (u, false);
        }
        let limited = u.clamp_to(p.u_min, p.u_max);
        let saturated = limited != u;
        self.u = limited;
        (limited, saturated)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integrates_towards_reference_and_does_not_wind_up() {
        let p = DepthParams {
            ki_period: 0.01f64,
            u_min: -100.0,
            u_max: 100.0,
        };
        let mut c = DepthController::new(0.0);
        // Plant: δ = 50 − 0.75·U (stiffer contact lowers the static gain).
        let mut u = 0.0;
        for _ in 0..5000 {
            let delta = 50.0 - 0.75 * u;
            u = c.update(&p, 30.0 - delta).0;
        }
        assert!((50.0 - 0.75 * u - 30.0).abs() < 1e-6);
        // A long impossible demand saturates without winding up: one sample of the opposite
        // error moves it off the limit at once.
        for _ in 0..100_000 {
            c.update(&p, -1e3);
        }
        assert_eq!(c.output(), 100.0);
        let (u, sat) = c.update(&p, 1.0);
        assert!(!sat && u < 100.0);
    }
}
