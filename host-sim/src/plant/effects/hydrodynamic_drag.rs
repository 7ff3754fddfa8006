//! `hydrodynamic-drag`: a velocity-proportional force on the cantilever that acts out of
//! contact too (liquid).
//!
//! `F = −c_h·((1 − w)·Ż + w·U̇)`: the liquid drags on the lever, whose body moves with a
//! velocity between the tip's (w = 0) and the base's (w = 1). Out of contact both are the
//! same and a force curve's approach and retract baselines part by `2·c_h·v/K`; a dynamic
//! recording sees the free cantilever damped harder (a lower Q). The tip part is a linear
//! term the plant integrates exactly; the base part is held over the period (the DAC's U̇).

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nN·µs/nm).
#[derive(Clone, Debug)]
pub struct HydrodynamicDrag {
    drag: f64,
    base: f64,
    last_u: Option<f64>,
}

impl HydrodynamicDrag {
    /// Drag coefficient (nN·µs/nm, ≥ 0) and the base velocity's share w in [0, 1].
    pub fn new(drag: f64, base_fraction: f64) -> Self {
        HydrodynamicDrag {
            drag,
            base: base_fraction.clamp(0.0, 1.0),
            last_u: None,
        }
    }
}

impl Effect for HydrodynamicDrag {
    fn name(&self) -> &str {
        "hydrodynamic-drag"
    }
    fn linear_terms(&self) -> (f64, f64) {
        (0.0, (1.0 - self.base) * self.drag)
    }
    fn tip_force_nn(&self, ctx: &EffectContext) -> f64 {
        match self.last_u {
            Some(u0) if self.base > 0.0 && ctx.dt_us > 0.0 => {
                -self.base * self.drag * (ctx.u_nm - u0) / ctx.dt_us
            }
            _ => 0.0,
        }
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        self.last_u = Some(ctx.u_nm);
    }
}
