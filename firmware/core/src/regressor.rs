//! The regressors of DIVE (13) and SVE (16), built only from U, D and a contact height.
//!
//! Both modes share the measured side
//! `w = (M s² + C s + K)·Z/Λ − (C s + K)·U/Λ` — which is `(M·Z̈ − K·D − C·Ḋ)/Λ`, the force the
//! sample exerts, filtered — and differ in the regressor:
//!
//! * DIVE (13): `φ = [s·δ/Λ, δ/Λ] = [−s·Z/Λ, h − Z/Λ]`, θ = [c, k], with h from the contact
//!   detector (a constant h passes the unit-DC-gain filter unchanged).
//! * SVE (16): `φ = [−s·Z/Λ, z₀ − Z/Λ, 1]`, θ = [c, k, k·(h − z₀)]. The paper writes `−Z/Λ`
//!   (z₀ = 0); any known constant z₀ leaves the identity `w = θᵀφ` exact and only moves part
//!   of θ₃ into a known term: taking z₀ near the tip keeps the position regressor at tens of
//!   nm, so f32 keeps its digits.
//!
//! Z = U − D is smooth and filtered as such ([`Hold::Smooth`]); U is the DAC's staircase and
//! filtered with a zero-order hold (see [`crate::prefilter`] for why this matters). The smooth
//! filter's outputs describe the previous sample, so the U filter is fed the previous U: w and φ
//! are those of the previous sample instant, a delay of one loop period that the estimator,
//! whose memory is thousands of periods, does not notice.

use crate::prefilter::{Filtered, Hold, Prefilter, PrefilterCoeffs};
use crate::real::Real;

/// Constants of the regressor: the cantilever in internal units and the prefilters.
#[derive(Clone, Copy, Debug)]
pub struct RegressorParams<T> {
    /// M (internal units).
    pub mass: T,
    /// C (internal units).
    pub damping: T,
    /// K (internal units).
    pub stiffness: T,
    z: PrefilterCoeffs<T>,
    u: PrefilterCoeffs<T>,
}

impl<T: Real> RegressorParams<T> {
    /// From the cantilever (internal units), λ and the loop period (the same time unit).
    pub fn new(mass: f64, damping: f64, stiffness: f64, lambda: f64, period: f64) -> Self {
        Self {
            mass: T::from_f64(mass),
            damping: T::from_f64(damping),
            stiffness: T::from_f64(stiffness),
            z: PrefilterCoeffs::new(lambda, period, Hold::Smooth),
            u: PrefilterCoeffs::new(lambda, period, Hold::Zero),
        }
    }
}

/// The two prefilters (their states are their x/Λ and s·x/Λ; s²·Z/Λ is formed from the Z
/// filter's state when w needs it, not every sample).
#[derive(Clone, Copy, Debug, Default)]
pub struct Regressor<T> {
    zf: Prefilter<T>,
    uf: Prefilter<T>,
    u_prev: T,
}

impl<T: Real> Regressor<T> {
    /// At rest with the tip at `z0` and the base at `u0`.
    pub fn at_rest(z0: T, u0: T) -> Self {
        Self {
            zf: Prefilter::at_rest(z0),
            uf: Prefilter::at_rest(u0),
            u_prev: u0,
        }
    }

    /// Take one sample: `u` is the base position held over the period ending now (the DAC value
    /// output one step ago), `z = u − D` the tip position sampled now.
    #[inline(always)]
    pub fn update(&mut self, p: &RegressorParams<T>, u: T, z: T) {
        self.zf.advance_smooth(&p.z, z);
        self.uf.update_held(&p.u, self.u_prev);
        self.u_prev = u;
    }

    /// Z/Λ, s·Z/Λ and s²·Z/Λ (the last formed here; unused, inlining drops it).
    #[inline(always)]
    pub fn z(&self, p: &RegressorParams<T>) -> Filtered<T> {
        let (x, dx) = self.zf.state();
        Filtered {
            x,
            dx,
            ddx: self.zf.ddx_smooth(&p.z),
        }
    }

    /// Z/Λ alone.
    #[inline(always)]
    pub fn z_x(&self) -> T {
        self.zf.state().0
    }

    /// s·Z/Λ alone.
    #[inline(always)]
    pub fn z_dx(&self) -> T {
        self.zf.state().1
    }

    /// U/Λ and s·U/Λ (the U filter does not form s²·U/Λ: nothing needs it; `ddx` is 0).
    #[inline(always)]
    pub fn u(&self) -> Filtered<T> {
        let (x, dx) = self.uf.state();
        Filtered {
            x,
            dx,
            ddx: T::ZERO,
        }
    }

    /// w = (M s² + C s + K)·Z/Λ − (C s + K)·U/Λ.
    #[inline(always)]
    pub fn w(&self, p: &RegressorParams<T>) -> T {
        let z = self.z(p);
        let u = self.u();
        p.mass * z.ddx + p.damping * (z.dx - u.dx) + p.stiffness * (z.x - u.x)
    }

    /// DIVE (13): [s·δ/Λ, δ/Λ] with δ = h − Z.
    #[inline(always)]
    pub fn phi_dive(&self, h: T) -> [T; 2] {
        [-self.z_dx(), h - self.z_x()]
    }

    /// SVE (16) with a fixed reference z₀: [−s·Z/Λ, z₀ − Z/Λ, 1].
    #[inline(always)]
    pub fn phi_sve(&self, z0: T) -> [T; 3] {
        [-self.z_dx(), z0 - self.z_x(), T::ONE]
    }
}
