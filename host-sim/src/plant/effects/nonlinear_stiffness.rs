//! `nonlinear-stiffness`: the contact force does not grow with depth as the element bed
//! predicts.
//!
//! The bed under a sphere gives `F = k_a·V(δ)`, `V ≈ πRδ²` while shallow: F ∝ δ². Strain
//! stiffening, a Hertzian continuum (F ∝ δ^1.5) or another tip shape (a cone on the bed:
//! F ∝ δ³) change the exponent. The law multiplies the bed's elastic force by
//! `(δ/δ_ref)^q`: the shallow force–depth exponent becomes `2 + q` (Hertz: q = −½), and the
//! force at the reference depth is unchanged, so q does not trade against the bed's k_a
//! there. Applied as an extra force `F_el·((δ/δ_ref)^q − 1)` while the bed pushes.

use super::{Effect, EffectContext};

/// See the module docs. Internal units (nm).
#[derive(Clone, Debug)]
pub struct NonlinearStiffness {
    q: f64,
    inv_ref: f64,
}

/// The factor is capped: at a vanishing depth with q < 0 the force itself vanishes first.
const FACTOR_MAX: f64 = 1e3;

impl NonlinearStiffness {
    /// Exponent change `q`, reference depth (nm).
    pub fn new(q: f64, reference_depth_nm: f64) -> Self {
        NonlinearStiffness {
            q,
            inv_ref: 1.0 / reference_depth_nm.max(1e-9),
        }
    }

    /// The factor on the elastic force at apex depth `depth_nm`.
    pub fn factor(&self, depth_nm: f64) -> f64 {
        if depth_nm > 0.0 {
            (depth_nm * self.inv_ref).powf(self.q).min(FACTOR_MAX)
        } else {
            1.0
        }
    }
}

impl Effect for NonlinearStiffness {
    fn name(&self) -> &str {
        "nonlinear-stiffness"
    }
    fn tip_force_nn(&self, ctx: &EffectContext) -> f64 {
        if ctx.depth_nm > 0.0 && ctx.elastic_force_nn > 0.0 {
            ctx.elastic_force_nn * (self.factor(ctx.depth_nm) - 1.0)
        } else {
            0.0
        }
    }
}
