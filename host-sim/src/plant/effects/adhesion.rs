//! `adhesion`: an attractive force while the tip touches the sample, seen most at pull-off.
//!
//! The contact holds the tip (a neck, tethers, bonds, a meniscus: the contact's own
//! attraction) with a force F_a until the apex is ℓ out of the sample on the retract, where it
//! lets go at once: the pull-off jump of a retract curve. ℓ = 0 ends the attraction with the
//! contact; ℓ > 0 is a neck or tether that stretches before it breaks. The pull acts either
//! from the first touch (a JKR/DMT-like contact adhesion: the approach jumps in too), or only
//! once the contact unloads — bonds and tethers formed in contact resist separation, not
//! indentation — that is from when the apex has risen above its deepest point by a fiftieth
//! of that depth (and at least a nanometre).

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nN, nm).
#[derive(Clone, Debug)]
pub struct Adhesion {
    force: f64,
    reach: f64,
    unloading_only: bool,
    attached: bool,
    /// Deepest apex depth since the touch (nm).
    deepest: f64,
    pulling: bool,
}

impl Adhesion {
    /// Attractive force (nN, ≥ 0 pulls towards the sample), reach (nm, ≥ 0), whether it acts
    /// only once the contact unloads.
    pub fn new(force_nn: f64, reach_nm: f64, unloading_only: bool) -> Self {
        Adhesion {
            force: force_nn,
            reach: reach_nm.max(0.0),
            unloading_only,
            attached: false,
            deepest: 0.0,
            pulling: false,
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
        if self.pulling {
            -self.force
        } else {
            0.0
        }
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        let d = ctx.depth_nm;
        if d > 0.0 {
            if !self.attached {
                self.deepest = 0.0;
            }
            self.attached = true;
            self.deepest = self.deepest.max(d);
        } else if d < -self.reach {
            self.attached = false;
            self.pulling = false;
        }
        if self.attached {
            self.pulling = !self.unloading_only
                || self.pulling
                || self.deepest - d > (0.02 * self.deepest).max(1.0);
        }
    }
}
