//! `stress-relaxation`: the force relaxes at constant depth, which a Kelvin–Voigt element
//! cannot do.
//!
//! Each arm is a Maxwell element (spring in series with a dashpot) beside every element of the
//! bed, with a spring ρ times the element's and relaxation time τ: the standard linear solid.
//! Summed over the footprint, the arms' force obeys `τ·Ḟ_m + F_m = ρ·τ·Ḟ_el` with `F_el` the
//! bed's elastic force: a step in depth gives `(1 + ρ)·F_el` at once, relaxing to `F_el`
//! with time constant τ. Two arms with relaxation times a decade or more apart approximate
//! power-law rheology (`F ∝ t^{−α}`) over that span. The arms push only while the bed
//! touches the tip; out of contact they relax unloaded.

use super::{first_order, Effect, EffectContext};

/// At most this many arms.
pub const MAX_ARMS: usize = 3;

/// See the module docs. Internal units (nN, µs).
#[derive(Clone, Debug)]
pub struct StressRelaxation {
    /// (ρ, τ µs) per arm.
    arms: Vec<(f64, f64)>,
    /// The arms' forces (nN).
    force: Vec<f64>,
    /// The elastic force at the last step's end (`None` before the first).
    last_elastic: Option<f64>,
    /// Cached `(dt, [(a, w)])`.
    coeffs: (f64, Vec<(f64, f64)>),
}

impl StressRelaxation {
    /// Arms `(ρ ≥ 0, τ µs > 0)`; at most [`MAX_ARMS`] are kept.
    pub fn new(arms: impl IntoIterator<Item = (f64, f64)>) -> Self {
        let arms: Vec<(f64, f64)> = arms
            .into_iter()
            .take(MAX_ARMS)
            .map(|(r, tau)| (r, tau.max(1e-9)))
            .collect();
        let n = arms.len();
        StressRelaxation {
            arms,
            force: vec![0.0; n],
            last_elastic: None,
            coeffs: (f64::NAN, Vec::new()),
        }
    }

    /// The arms' total force now (nN).
    pub fn arm_force_nn(&self) -> f64 {
        self.force.iter().sum()
    }
}

impl Effect for StressRelaxation {
    fn name(&self) -> &str {
        "stress-relaxation"
    }
    fn tip_force_nn(&self, ctx: &EffectContext) -> f64 {
        if ctx.elastic_force_nn > 0.0 {
            self.arm_force_nn()
        } else {
            0.0
        }
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        let f = ctx.elastic_force_nn.max(0.0);
        let df = f - self.last_elastic.unwrap_or(f);
        self.last_elastic = Some(f);
        if self.coeffs.0 != ctx.dt_us {
            self.coeffs = (
                ctx.dt_us,
                self.arms
                    .iter()
                    .map(|&(_, tau)| first_order(ctx.dt_us, tau))
                    .collect(),
            );
        }
        for ((fm, &(rho, _)), &(a, w)) in self.force.iter_mut().zip(&self.arms).zip(&self.coeffs.1)
        {
            *fm = a * *fm + rho * w * df;
        }
    }
}
