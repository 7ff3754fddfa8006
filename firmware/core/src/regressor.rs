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

use crate::prefilter::{Filtered, HeldGroup, Hold, Prefilter, PrefilterCoeffs, SmoothGroup, GROUP};
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

/// Both filters [`GROUP`] samples at a time (DIVE's stride of 4: [`Regressor::z_group`]).
/// Apart from [`RegressorParams`], so that the fields after those in the structures that
/// hold it keep their offsets (an FPU load reaches 1 020 bytes from its base).
#[derive(Clone, Copy, Debug)]
pub struct GroupParams<T> {
    zg: SmoothGroup<T>,
    ug: HeldGroup<T>,
}

impl<T: Real> GroupParams<T> {
    /// For time constant `lambda` and the loop period `period` (the same time unit).
    pub fn new(lambda: f64, period: f64) -> Self {
        Self {
            zg: SmoothGroup::new(lambda, period),
            ug: HeldGroup::new(lambda, period),
        }
    }
}

impl<T: Real> RegressorParams<T> {
    /// Z/Λ, s·Z/Λ and s²·Z/Λ from the Z filter's state `y`, `ẏ` and the sample it describes
    /// (`x2`): [`Regressor::z`]'s operations, for a pass that has them apart.
    #[inline(always)]
    pub fn z_filtered(&self, x2: T, y: T, dy: T) -> Filtered<T> {
        Filtered {
            x: y,
            dx: dy,
            ddx: self.z.ddx(x2, y, dy),
        }
    }

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

    /// The Z filter alone: [`Self::update`]'s Z part (for a pass that runs the two filters
    /// apart, each with its coefficients in registers).
    #[inline(always)]
    pub fn update_z(&mut self, p: &RegressorParams<T>, z: T) {
        self.zf.advance_smooth(&p.z, z);
    }

    /// The U filter alone: [`Self::update`]'s U part.
    #[inline(always)]
    pub fn update_u(&mut self, p: &RegressorParams<T>, u: T) {
        self.uf.update_held(&p.u, self.u_prev);
        self.u_prev = u;
    }

    /// [`GROUP`] samples' Z at once: the Z filter's state four [`Self::update_z`] leave, to
    /// the rounding of fewer operations (see [`SmoothGroup`]).
    #[inline(always)]
    pub fn z_group(&mut self, p: &GroupParams<T>, z: [T; GROUP]) {
        self.zf.advance_smooth_group(&p.zg, z);
    }

    /// [`GROUP`] samples' U at once, as four [`Self::update_u`]: U/Λ and s·U/Λ after them.
    #[inline(always)]
    pub fn u_group(&mut self, p: &GroupParams<T>, u: [T; GROUP]) -> (T, T) {
        let [u1, u2, u3, u4] = u;
        let out = self.uf.update_held_group(&p.ug, [self.u_prev, u1, u2, u3]);
        self.u_prev = u4;
        out
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
        let (ux, udx) = self.uf.state();
        w_of(p, &z, ux, udx)
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

/// w = (M s² + C s + K)·Z/Λ − (C s + K)·U/Λ from the filters' outputs `z` and `ux` = U/Λ,
/// `udx` = s·U/Λ: [`Regressor::w`]'s operations, for a pass that has the two apart.
#[inline(always)]
pub fn w_of<T: Real>(p: &RegressorParams<T>, z: &Filtered<T>, ux: T, udx: T) -> T {
    p.mass * z.ddx + p.damping * (z.dx - udx) + p.stiffness * (z.x - ux)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{units, Config};

    /// f32's unit roundoff.
    const U: f64 = f32::EPSILON as f64 / 2.0;

    /// Σ_{m≥0} |Φᵐ| entrywise (Φ the group's transition, in f64): how far an error put into
    /// the state once reaches at most, over all later groups.
    fn reach(phi: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
        let mut p = [[1.0, 0.0], [0.0, 1.0]];
        let mut g = [[0.0; 2]; 2];
        for _ in 0..2000 {
            for i in 0..2 {
                for j in 0..2 {
                    g[i][j] += p[i][j].abs();
                }
            }
            let q = p;
            for i in 0..2 {
                for j in 0..2 {
                    p[i][j] = q[i][0] * phi[0][j] + q[i][1] * phi[1][j];
                }
            }
        }
        g
    }

    /// DIVE's grouped prefilters (issue 14, round 12) in f32 against the per-sample ones in
    /// f64 on a tap's signals at 1 MHz (the paper's cantilever and λ, U near 1 µm with the
    /// two tones, Z = U − D with noise): w and φ at every fourth sample within a bound
    /// derived from f32's arithmetic (the standard model, |fl(a ∘ b) − a ∘ b| ≤ u·|a ∘ b|,
    /// per operation: the roundings each group puts into the state, carried by the sum of
    /// |Φ⁴ᵐ| over the later groups, then through w's operations). In f64 the grouped form
    /// equals the per-sample one to its rounding. Prints the largest errors of both f32
    /// forms (`cargo test -p visco-core grouped -- --nocapture`).
    #[test]
    fn grouped_prefilters_f32_within_their_rounding_bound() {
        let cfg = Config::paper(1e6);
        let lambda = cfg.prefilter.lambda_s / units::TIME;
        let period = 1e-6 / units::TIME;
        let new = || {
            (
                cfg.cantilever.m_kg / units::MASS,
                cfg.cantilever.c_ns_per_m / units::DAMPING,
                cfg.cantilever.k_n_per_m / units::STIFFNESS,
            )
        };
        let (m, c, k) = new();
        let p32 = RegressorParams::<f32>::new(m, c, k, lambda, period);
        let p64 = RegressorParams::<f64>::new(m, c, k, lambda, period);
        let (q32, q64) = (
            GroupParams::<f32>::new(lambda, period),
            GroupParams::<f64>::new(lambda, period),
        );
        let (zphi, zw) = q32.zg.coefficients();
        let (uphi, uw) = q32.ug.coefficients();
        let gz = reach(q64.zg.coefficients().0);
        let gu = reach(q64.ug.coefficients().0);
        let (mf, cf, kf) = (p32.mass as f64, p32.damping as f64, p32.stiffness as f64);
        let (tl, il) = (2.0 * lambda, 1.0 / (lambda * lambda));
        // The inputs in f32 (both forms see the same values; their rounding is not the
        // filters').
        let signal = |i: usize| {
            let t = i as f64 * 1e-6;
            let w1 = 2.0 * core::f64::consts::PI * 20.8e3;
            let noise = ((i as u64).wrapping_mul(2_654_435_761) % 1000) as f64 / 1000.0 - 0.5;
            let u = 1000.0 + 600.0 * libm::sin(w1 * t) + 300.0 * libm::sin(w1 / 4.0 * t);
            let d = 400.0 + 200.0 * libm::sin(w1 * t + 0.4) + 0.4 * noise;
            ((u - d) as f32, u as f32)
        };
        let (z0, u0) = signal(0);
        let mut r64 = Regressor::<f64>::at_rest(z0 as f64, u0 as f64);
        let mut g64 = r64;
        let mut r32 = Regressor::<f32>::at_rest(z0, u0);
        let mut g32 = r32;
        let r = 455.0f32;
        // Bounds: the largest rounding a group has put into each state so far, and the held
        // input's error from the last group.
        let (mut bz, mut bu, mut eh) = ([0.0f64; 2], [0.0f64; 2], 0.0f64);
        let (mut worst_g, mut worst_s, mut worst_ratio, mut w_max) =
            (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let mut group = [(0.0f32, 0.0f32); 4];
        for i in 1..40_001usize {
            let (z, u) = signal(i);
            r64.update(&p64, u as f64, z as f64);
            r32.update(&p32, u, z);
            group[(i - 1) % 4] = (z, u);
            if i % 4 != 0 {
                continue;
            }
            // The group's state before it, for the magnitudes of its terms.
            let (zy, zdy) = g32.zf.state();
            let [held, x2, x1] = g32.zf.inputs();
            let (uy, udy) = g32.uf.state();
            let uprev = g32.u_prev;
            let zs = group.map(|g| g.0);
            let us = group.map(|g| g.1);
            g32.z_group(&q32, zs);
            let (ux, udx) = g32.u_group(&q32, us);
            g64.z_group(&q64, zs.map(f64::from));
            g64.u_group(&q64, us.map(f64::from));
            // Each state's rounding this group: 9 (Z) or 6 (U) products summed in turn, and
            // their coefficients' own rounding; the held input's error from the last group.
            let zv = [zy, zdy, held, x2, x1, zs[0], zs[1], zs[2], zs[3]].map(f64::from);
            let uv = [uy, udy, uprev, us[0], us[1], us[2]].map(f64::from);
            for s in 0..2 {
                let cz = zphi[s].into_iter().chain(zw[s]).map(f64::from);
                let mag: f64 = cz.zip(zv.iter()).map(|(a, b)| (a * b).abs()).sum();
                bz[s] = bz[s].max(10.0 * U * mag + f64::from(zw[s][0]).abs() * eh);
                let cu = uphi[s].into_iter().chain(uw[s]).map(f64::from);
                let mag: f64 = cu.zip(uv.iter()).map(|(a, b)| (a * b).abs()).sum();
                bu[s] = bu[s].max(7.0 * U * mag);
            }
            let (a2, a3, a4) = (zs[1] as f64, zs[2] as f64, zs[3] as f64);
            eh = 6.0 * U * (a3.abs() + ((a4 - a3).abs() + (a3 - a2).abs()) / 12.0);
            // The states' errors: every group's rounding carried by Σ|Φ⁴ᵐ|.
            let ez = [0, 1].map(|s| gz[s][0] * bz[0] + gz[s][1] * bz[1]);
            let eu = [0, 1].map(|s| gu[s][0] * bu[0] + gu[s][1] * bu[1]);
            // w's operations on them.
            let zf = g32.z(&p32);
            let (y, dy, x2) = (zf.x as f64, zf.dx as f64, g32.zf.inputs()[1] as f64);
            let sdd = x2 - y - tl * dy;
            let e_ddx = il * (ez[0] + tl * ez[1])
                + U * il * (2.0 * (tl * dy).abs() + (x2 - y).abs() + sdd.abs())
                + 2.0 * U * (il * sdd).abs();
            let (ux, udx) = (ux as f64, udx as f64);
            let (tm, tc, tk) = (mf * il * sdd, cf * (dy - udx), kf * (y - ux));
            let e_w = mf.abs() * e_ddx
                + cf.abs() * (ez[1] + eu[1])
                + kf.abs() * (ez[0] + eu[0])
                + U * (2.0 * tm.abs()
                    + 3.0 * tc.abs()
                    + 3.0 * tk.abs()
                    + (tm + tc).abs()
                    + (tm + tc + tk).abs());
            let e_w = 1.1 * e_w;
            // `schedule::group_read`'s operations.
            let [wg, f0, f1] = [w_of(&p32, &zf, ux as f32, udx as f32), -zf.dx, r - zf.x];
            let w64 = r64.w(&p64);
            let phi64 = r64.phi_sve(f64::from(r));
            let ws = r32.w(&p32);
            let err = (f64::from(wg) - w64).abs();
            assert!(
                err <= e_w,
                "sample {i}: w {wg} against {w64}, error {err} > bound {e_w}"
            );
            assert!(
                (f64::from(f0) - phi64[0]).abs() <= 1.1 * ez[1],
                "sample {i}: φ₁"
            );
            assert!(
                (f64::from(f1) - phi64[1]).abs() <= 1.1 * (ez[0] + U * (f64::from(r) - y).abs()),
                "sample {i}: φ₂"
            );
            // f64: the grouped form is the per-sample one.
            let wg64 = g64.w(&p64);
            assert!(
                (wg64 - w64).abs() <= 1e-9 * (1.0 + w64.abs()),
                "f64 at {i}: {wg64} vs {w64}"
            );
            worst_g = worst_g.max(err);
            worst_s = worst_s.max((f64::from(ws) - w64).abs());
            worst_ratio = worst_ratio.max(err / e_w);
            w_max = w_max.max(w64.abs());
        }
        std::eprintln!(
            "grouped f32: largest w error {worst_g:.3e} (of its bound at most {worst_ratio:.3}), per-sample f32 {worst_s:.3e}, |w| up to {w_max:.1}"
        );
    }
}
