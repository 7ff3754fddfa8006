//! `piezo-creep`: the actual base position lags the command slowly after a move.
//!
//! A piezo reaches most of a commanded move at once and creeps over the rest: the base is at
//! `U − γ·(U − U_f)` with `U_f` the command through `1/(τs + 1)`. After a step ΔU it stands
//! at `(1 − γ)·ΔU` and creeps the last `γ·ΔU` with time constant τ; during a hold after an
//! approach it keeps pressing in, so the force rises at constant command — the opposite sign
//! of stress relaxation.

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nm, µs).
#[derive(Clone, Debug)]
pub struct PiezoCreep {
    fraction: f64,
    tau: f64,
    filtered: Option<f64>,
}

impl PiezoCreep {
    /// Creep fraction γ in [0, 1), time constant τ (µs).
    pub fn new(fraction: f64, tau_us: f64) -> Self {
        PiezoCreep {
            fraction: fraction.clamp(-0.99, 0.99),
            tau: tau_us.max(1e-9),
            filtered: None,
        }
    }
}

impl Effect for PiezoCreep {
    fn name(&self) -> &str {
        "piezo-creep"
    }
    fn piezo_z_nm(&self, _ctx: &EffectContext, u_nm: f64) -> f64 {
        match self.filtered {
            Some(f) => u_nm - self.fraction * (u_nm - f),
            None => u_nm,
        }
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        let u = ctx.u_nm;
        self.filtered = Some(match self.filtered {
            None => u,
            Some(f) => u + (f - u) * (-ctx.dt_us / self.tau).exp(),
        });
    }
}
