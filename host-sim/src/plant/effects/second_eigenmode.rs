//! `second-eigenmode`: the cantilever's second flexural mode (about 6.27 × f₀ for a uniform
//! beam) is excited.
//!
//! A K from a static calibration lumps every mode's static compliance; what the first-mode
//! model then misses is the second mode's own dynamics, `H₂(s) = ω₂²/(s² + (ω₂/Q₂)·s + ω₂²)`.
//! The mode is driven two ways, each with its own gains in the detector's reading:
//!
//! * by the tip force: the detector adds `g_F·(H₂ − 1)·F_ts/K` (the dynamic part, for such a
//!   K; the static share `g_S` below is for a K that leaves it out) — a ring after every
//!   sharp change of the tip force;
//! * by the base's motion (the piezo shakes the lever's clamp): relative to the base the mode
//!   follows `s²/(s² + (ω₂/Q₂)s + ω₂²)·U` — every step of a DAC's staircase, every jerk of
//!   the piezo rings it — and the detector adds `g_U` times that. A medium that damps the
//!   mode's absolute velocity (liquid, air squeezed under the lever) drives it through the
//!   base's velocity as well, `ω₂·s/(s² + (ω₂/Q₂)s + ω₂²)·U`, with its own gain `g_V`: the
//!   mix of the two routes sets the phase of the mode's response to the base, which no
//!   header gives, so both gains are fitted.
//!
//! Whether the mode's static share `g_F·F_ts/K` is in K depends on how K was calibrated (a
//! static push, or a thermal tune of the first mode alone, whose modal stiffness leaves out
//! the higher modes' static compliance, ~3 % of a uniform beam's): a third gain `g_S` adds
//! `g_S·F_ts/K`, so that `g_S = g_F` is the whole `g_F·H₂·F_ts/K`.
//!
//! All are filters of what the recording and the model know (U) or compute (F_ts), so the
//! ring is predicted sample by sample, and decays over `Q₂/(π f₂)`. The gains are the mode's
//! optical-lever sensitivity relative to the first mode's (≈ 0.3 for an ideal beam) times its
//! participation in each drive.

use super::{Effect, EffectContext};
use crate::plant::linear::Propagator;
use std::cell::Cell;

/// See the module docs. Internal units (µs, nN, nm).
#[derive(Clone, Debug)]
pub struct SecondEigenmode {
    w: f64,
    w2: f64,
    damping: f64,
    q: f64,
    gain_force: f64,
    gain_base: f64,
    gain_velocity: f64,
    gain_static: f64,
    inv_k: f64,
    /// Force-driven mode (q nm, q̇ nm/µs, drive at the last step's end), base-driven mode
    /// (p nm, ṗ nm/µs).
    state: Option<[f64; 5]>,
    prop: (f64, Propagator),
    /// The states the last reading advanced to, keyed by the bits of its context's force,
    /// U and Δt (all that [`Self::advanced`] reads of it): the step's end takes them when its
    /// context is the reading's, as in a simulation, instead of advancing again.
    advanced_for: Cell<Option<([u64; 3], [f64; 5])>>,
}

impl SecondEigenmode {
    /// Frequency (MHz, 1/µs), quality factor, gains on the tip force's dynamic part, on the
    /// base's acceleration, on its velocity and on the tip force's static part, cantilever
    /// stiffness K (nN/nm).
    pub fn new(
        f_mhz: f64,
        q: f64,
        gain_force: f64,
        gain_base: f64,
        gain_velocity: f64,
        gain_static: f64,
        k_cant: f64,
    ) -> Self {
        let w = 2.0 * std::f64::consts::PI * f_mhz;
        let q = q.max(1e-3);
        SecondEigenmode {
            w,
            w2: w * w,
            damping: w / q,
            q,
            gain_force,
            gain_base,
            gain_velocity,
            gain_static,
            inv_k: 1.0 / k_cant,
            state: None,
            prop: (f64::NAN, Propagator::default()),
            advanced_for: Cell::new(None),
        }
    }

    fn propagator(&self, dt: f64) -> Propagator {
        if self.prop.0 == dt {
            self.prop.1
        } else {
            Propagator::new(1.0, self.damping, self.w2, dt)
        }
    }

    /// The modes' states at the end of the step of `ctx`: the force drive held at the mean of
    /// the step's end values (second order), the base held at the period's U (as the DAC).
    fn advanced(&self, ctx: &EffectContext) -> [f64; 5] {
        let x = ctx.contact_force_nn * self.inv_k;
        match self.state {
            None => [x, 0.0, x, ctx.u_nm, 0.0],
            Some([q, v, x0, pb, vb]) => {
                let pr = self.propagator(ctx.dt_us);
                let (q1, v1) = pr.apply(q, v, 0.5 * (x0 + x));
                let (p1, w1) = pr.apply(pb, vb, ctx.u_nm);
                [q1, v1, x, p1, w1]
            }
        }
    }

    /// The reading's addition for a state.
    fn reading(&self, s: &[f64; 5], u: f64) -> f64 {
        // Base drive: s²/(s² + (ω₂/Q₂)s + ω₂²)·U = U − p − ṗ/(Q₂ω₂) with p = H₂·U.
        let base = u - s[3] - s[4] / (self.q * self.w);
        // Velocity drive: ω₂·s/(s² + (ω₂/Q₂)s + ω₂²)·U = ṗ/ω₂.
        let velocity = s[4] / self.w;
        self.gain_force * (s[0] - s[2])
            + self.gain_static * s[2]
            + self.gain_base * base
            + self.gain_velocity * velocity
    }
}

impl Effect for SecondEigenmode {
    fn name(&self) -> &str {
        "second-eigenmode"
    }
    fn measured_deflection_nm(&self, ctx: &EffectContext, d_nm: f64) -> f64 {
        let s = self.advanced(ctx);
        self.advanced_for.set(Some((context_key(ctx), s)));
        d_nm + self.reading(&s, ctx.u_nm)
    }
    fn end_of_step(&mut self, ctx: &EffectContext) {
        if self.prop.0 != ctx.dt_us {
            self.prop = (
                ctx.dt_us,
                Propagator::new(1.0, self.damping, self.w2, ctx.dt_us),
            );
        }
        // The state has not moved since the reading (only this sets it): the same
        // arithmetic on the same inputs, so the same bits.
        self.state = Some(match self.advanced_for.take() {
            Some((key, s)) if key == context_key(ctx) => s,
            _ => self.advanced(ctx),
        });
    }
}

/// What [`SecondEigenmode::advanced`] reads of a context, as bits.
#[inline]
fn context_key(ctx: &EffectContext) -> [u64; 3] {
    [
        ctx.contact_force_nn.to_bits(),
        ctx.u_nm.to_bits(),
        ctx.dt_us.to_bits(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(i: usize, dt: f64) -> EffectContext {
        let t = i as f64 * dt;
        EffectContext {
            time_us: t,
            dt_us: dt,
            z_nm: 0.0,
            z_dot_nm_per_us: 0.0,
            u_nm: 3.0 * (0.7 * t).sin() + if i % 7 == 0 { 1.5 } else { 0.0 },
            x_nm: 0.0,
            y_nm: 0.0,
            contact_force_nn: if i % 5 < 2 {
                0.0
            } else {
                0.2 * (1.3 * t).cos()
            },
            elastic_force_nn: 0.0,
            depth_nm: 0.0,
            active_elements: 0,
        }
    }

    /// The step's end takes the states its reading advanced to only for that reading's own
    /// context: with readings at the same context, at another one, twice, or none, the
    /// states and readings are bit for bit those of the mode advanced afresh each time.
    #[test]
    fn the_step_end_reuses_the_readings_states_only_for_its_context() {
        let fresh = |e: &mut SecondEigenmode, c: &EffectContext| {
            e.advanced_for.set(None);
            e.end_of_step(c);
        };
        let mut a = SecondEigenmode::new(0.4, 30.0, 0.3, 0.05, 0.02, 0.1, 0.2);
        let mut b = a.clone();
        for i in 0..400 {
            let dt = if i % 50 == 49 { 1.3 } else { 1.0 };
            let c = ctx(i, dt);
            let other = ctx(i + 1, dt);
            let ra = match i % 4 {
                0 => a.measured_deflection_nm(&c, 0.5),
                1 => {
                    a.measured_deflection_nm(&other, 0.5);
                    a.measured_deflection_nm(&c, 0.5)
                }
                2 => {
                    let r = a.measured_deflection_nm(&c, 0.5);
                    a.measured_deflection_nm(&other, 0.5);
                    r
                }
                _ => a.measured_deflection_nm(&c, 0.5),
            };
            if i % 4 == 3 {
                a.advanced_for.set(None);
            }
            a.end_of_step(&c);
            let rb = b.measured_deflection_nm(&c, 0.5);
            fresh(&mut b, &c);
            assert_eq!(ra.to_bits(), rb.to_bits(), "sample {i}");
            let (sa, sb) = (a.state.unwrap(), b.state.unwrap());
            for (x, y) in sa.iter().zip(&sb) {
                assert_eq!(x.to_bits(), y.to_bits(), "sample {i}");
            }
        }
    }
}
