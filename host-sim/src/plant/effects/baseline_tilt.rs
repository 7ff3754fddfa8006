//! `baseline-tilt`: the out-of-contact deflection changes linearly with the piezo position.
//!
//! The detector reads `D + b·(U − U_ref)`: light reflected off the sample interferes with the
//! lever's beam, or the lever's mount tilts as the piezo extends. It is a reading, not a
//! force: the tip does not move for it.

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nm).
#[derive(Clone, Debug)]
pub struct BaselineTilt {
    tilt: f64,
    u_ref: f64,
}

impl BaselineTilt {
    /// Tilt b (dimensionless, nm of D per nm of U) about `u_ref_nm`.
    pub fn new(tilt: f64, u_ref_nm: f64) -> Self {
        BaselineTilt {
            tilt,
            u_ref: u_ref_nm,
        }
    }
}

impl Effect for BaselineTilt {
    fn name(&self) -> &str {
        "baseline-tilt"
    }
    fn measured_deflection_nm(&self, ctx: &EffectContext, d_nm: f64) -> f64 {
        d_nm + self.tilt * (ctx.u_nm - self.u_ref)
    }
}
