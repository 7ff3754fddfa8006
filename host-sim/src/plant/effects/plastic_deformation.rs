//! `plastic-deformation`: the surface does not come back.
//!
//! A fraction φ of the deepest indentation so far stays: the bed under the tip sinks by
//! `s = φ·δ_max`. Loading is softer (part of each new depth is plastic), unloading follows
//! the elastic law from the sunk surface and loses contact earlier, and a later tap at the
//! same place finds the surface lower. Sinking the bed by s is the same as raising the
//! cantilever's base by s (only `Z − h` and `U − Z` enter the physics), so the law acts
//! through the piezo hook and the plant needs no moving elements.

use super::{Effect, EffectContext};

/// Largest fraction (φ → 1 would sink without bound).
const FRACTION_MAX: f64 = 0.95;

/// See the module docs. Internal units (nm).
#[derive(Clone, Debug)]
pub struct PlasticDeformation {
    fraction: f64,
    sink: f64,
}

impl PlasticDeformation {
    /// Plastic fraction φ in [0, 0.95].
    pub fn new(fraction: f64) -> Self {
        PlasticDeformation {
            fraction: fraction.clamp(0.0, FRACTION_MAX),
            sink: 0.0,
        }
    }
    /// How far the bed has sunk (nm).
    pub fn sink_nm(&self) -> f64 {
        self.sink
    }
}

impl Effect for PlasticDeformation {
    fn name(&self) -> &str {
        "plastic-deformation"
    }
    fn piezo_z_nm(&self, _ctx: &EffectContext, u_nm: f64) -> f64 {
        u_nm + self.sink
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        // The context's depth is below the sunk surface; the total is depth + sink.
        if ctx.depth_nm.is_finite() {
            self.sink = self.sink.max(self.fraction * (ctx.depth_nm + self.sink));
        }
    }
}
