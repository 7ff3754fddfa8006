//! `thermal-drift`: the deflection offset drifts with time.
//!
//! The detector reads `D + r·(t − t_ref)`: the lever's coating bends it as it warms, the
//! laser spot wanders. Over the seconds of a force curve a drift is linear to first order.
//! A reading, not a force.

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nm/µs, µs).
#[derive(Clone, Debug)]
pub struct ThermalDrift {
    rate: f64,
    t_ref: f64,
}

impl ThermalDrift {
    /// Rate (nm/µs) from `t_ref_us`.
    pub fn new(rate_nm_per_us: f64, t_ref_us: f64) -> Self {
        ThermalDrift {
            rate: rate_nm_per_us,
            t_ref: t_ref_us,
        }
    }
}

impl Effect for ThermalDrift {
    fn name(&self) -> &str {
        "thermal-drift"
    }
    fn measured_deflection_nm(&self, ctx: &EffectContext, d_nm: f64) -> f64 {
        d_nm + self.rate * (ctx.time_us - self.t_ref)
    }
}
