//! `surface-attraction`: an attractive force before contact that grows as the tip nears the
//! surface.
//!
//! `F = −F_s·e^{−s/λ}` at separation `s > 0` of the apex above the surface, `−F_s` once in
//! contact (continuous): an electrostatic double layer decays exponentially with the Debye
//! length λ; van der Waals forces between a sphere and a plane fall off faster but act over
//! a few nm too. Unlike [`super::Adhesion`] it is the same on the way in and out: no
//! hysteresis, and it acts before the first touch.

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nN, nm).
#[derive(Clone, Debug)]
pub struct SurfaceAttraction {
    force: f64,
    inv_decay: f64,
}

impl SurfaceAttraction {
    /// Force at contact (nN, ≥ 0 attracts), decay length λ (nm).
    pub fn new(force_nn: f64, decay_length_nm: f64) -> Self {
        SurfaceAttraction {
            force: force_nn,
            inv_decay: 1.0 / decay_length_nm.max(1e-6),
        }
    }
}

impl Effect for SurfaceAttraction {
    fn name(&self) -> &str {
        "surface-attraction"
    }
    fn tip_force_nn(&self, ctx: &EffectContext) -> f64 {
        let s = (-ctx.depth_nm).max(0.0);
        -self.force * (-s * self.inv_decay).exp()
    }
}
