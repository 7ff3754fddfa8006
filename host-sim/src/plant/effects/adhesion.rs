//! `adhesion`: an attractive force while the tip touches the sample, seen most at pull-off.
//!
//! From the first touch (apex depth > 0) the tip is pulled towards the sample with a constant
//! force F_a (a neck, tethers, a meniscus: the contact's own attraction), and it stays
//! attached on the retract until the apex is ℓ out of the sample, where it lets go at once:
//! the pull-off jump of a retract curve. ℓ = 0 is a contact adhesion that ends with the
//! contact (DMT-like); ℓ > 0 a neck or tether that stretches before it breaks.

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nN, nm).
#[derive(Clone, Debug)]
pub struct Adhesion {
    force: f64,
    reach: f64,
    attached: bool,
}

impl Adhesion {
    /// Attractive force (nN, ≥ 0 pulls towards the sample), reach (nm, ≥ 0).
    pub fn new(force_nn: f64, reach_nm: f64) -> Self {
        Adhesion {
            force: force_nn,
            reach: reach_nm.max(0.0),
            attached: false,
        }
    }
    /// Whether the tip is held by the sample now.
    pub fn attached(&self) -> bool {
        self.attached
    }
}

impl Effect for Adhesion {
    fn name(&self) -> &str {
        "adhesion"
    }
    fn tip_force_nn(&self, _ctx: &EffectContext) -> f64 {
        if self.attached {
            -self.force
        } else {
            0.0
        }
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        if ctx.depth_nm > 0.0 {
            self.attached = true;
        } else if ctx.depth_nm < -self.reach {
            self.attached = false;
        }
    }
}
