//! The DIVE contact detector (4.3.1).
//!
//! A first-order low-pass `G_lp` removes the cantilever's thermal and ADC noise from D. While
//! the tip approaches, the detector is *armed*; at the first sample where `G_lp·D < −γ` it
//! records the height `h = Z(t₁)` and becomes a *candidate*. The paper disables retriggering
//! "until `G_lp·D < −γ⁺` where γ⁺ > γ": while the candidate waits for the deeper threshold γ⁺,
//! further crossings of γ (noise around the threshold) do not move `h`; reaching γ⁺ *confirms*
//! the contact, latched until the sequencer re-arms the detector for the next tap. A candidate
//! whose low-passed deflection comes back above zero was noise, not contact: the detector
//! re-arms (this is the hysteresis band [−γ⁺, 0] of the paper's loop, made explicit).
//!
//! Sign: the sample pushes the tip up in contact, so D < 0 there (see `method.md`).

use crate::real::Real;

/// Constants of the contact detector (internal units).
#[derive(Clone, Copy, Debug)]
pub struct ContactParams<T> {
    /// Low-pass coefficient a of y ← y + a·(D − y).
    pub lowpass: T,
    /// γ > 0 (nm of deflection).
    pub gamma: T,
    /// γ⁺ > γ.
    pub gamma_plus: T,
}

/// Where the detector is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ContactState<T> {
    /// Waiting for the first crossing of −γ.
    Armed,
    /// Crossed −γ at height `h`; waiting for −γ⁺.
    Candidate {
        /// Z at the crossing.
        h: T,
    },
    /// Contact confirmed at height `h`.
    Confirmed {
        /// Z at the first crossing of −γ.
        h: T,
    },
}

/// State of the contact detector.
#[derive(Clone, Copy, Debug)]
pub struct ContactDetector<T> {
    lp: T,
    state: ContactState<T>,
}

impl<T: Real> ContactDetector<T> {
    /// Armed, with the low-pass at `d0`.
    pub fn new(d0: T) -> Self {
        Self {
            lp: d0,
            state: ContactState::Armed,
        }
    }

    /// Re-arm for the next tap, keeping the low-pass state.
    pub fn rearm(&mut self) {
        self.state = ContactState::Armed;
    }

    /// The low-passed deflection.
    pub fn lowpassed(&self) -> T {
        self.lp
    }

    /// The current state.
    pub fn state(&self) -> ContactState<T> {
        self.state
    }

    /// The confirmed contact height, if any.
    pub fn contact_height(&self) -> Option<T> {
        match self.state {
            ContactState::Confirmed { h } => Some(h),
            _ => None,
        }
    }

    /// Only the low-pass, for a confirmed contact (which `update` would leave as it is).
    #[inline(always)]
    pub fn lowpass(&mut self, p: &ContactParams<T>, d: T) {
        self.lowpass_with(p.lowpass, d);
    }

    /// [`Self::lowpass`] with another weight (the DIVE force limit's, per check step).
    #[inline(always)]
    pub fn lowpass_with(&mut self, weight: T, d: T) {
        self.lp += weight * (d - self.lp);
    }

    /// Take one sample of D and the tip position Z = U − D at the same instant.
    #[inline(always)]
    pub fn update(&mut self, p: &ContactParams<T>, d: T, z: T) -> ContactState<T> {
        self.lp += p.lowpass * (d - self.lp);
        let lp = self.lp;
        self.state = match self.state {
            ContactState::Armed if lp < -p.gamma => ContactState::Candidate { h: z },
            ContactState::Candidate { h } if lp < -p.gamma_plus => ContactState::Confirmed { h },
            ContactState::Candidate { .. } if lp > T::ZERO => ContactState::Armed,
            s => s,
        };
        self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> ContactParams<f64> {
        ContactParams {
            lowpass: 0.2,
            gamma: 1.0,
            gamma_plus: 2.0,
        }
    }

    #[test]
    fn records_first_crossing_and_ignores_retrigger() {
        let p = params();
        let mut c = ContactDetector::new(0.0);
        // The deflection goes down linearly; Z is just the sample index for identification.
        let mut first = None;
        for k in 0..100 {
            let d = -0.05 * k as f64;
            let s = c.update(&p, d, k as f64);
            if first.is_none() {
                if let ContactState::Candidate { h } = s {
                    first = Some(h);
                }
            }
        }
        let h = first.expect("never crossed");
        assert_eq!(c.contact_height(), Some(h));
        // Noise that goes back above −γ but not above 0 does not move h.
        for k in 0..50 {
            c.update(&p, if k % 2 == 0 { -0.5 } else { -3.0 }, 1000.0 + k as f64);
        }
        assert_eq!(c.contact_height(), Some(h));
    }

    #[test]
    fn noise_spike_rearms() {
        let p = params();
        let mut c = ContactDetector::new(0.0);
        for _ in 0..20 {
            c.update(&p, -1.6, 5.0); // candidate, never confirmed (lp → −1.6 > −γ⁺)
        }
        assert!(matches!(c.state(), ContactState::Candidate { h } if h == 5.0));
        for _ in 0..50 {
            c.update(&p, 0.5, 6.0);
        }
        assert_eq!(c.state(), ContactState::Armed);
    }
}
