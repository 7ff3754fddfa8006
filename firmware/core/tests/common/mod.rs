//! An exact reference plant for the core's tests: the cantilever on an aggregate Kelvin–Voigt
//! contact, the model the estimator is built on (10), integrated exactly in f64.
#![allow(dead_code)]

use visco_core::discretize::{discretize2, mass_spring_damper, Discrete2};
use visco_core::units;

/// M·Z̈ = K·D + C·Ḋ + F, D = U − Z, F = k·(h − Z) − c·Ż while in contact (Z < h, or always when
/// `always_in_contact`), else 0. Internal units (nm, nN, µs). U is held over each period.
pub struct AggregatePlant {
    pub m: f64,
    pub c_cant: f64,
    pub k_cant: f64,
    pub k: f64,
    pub c: f64,
    pub h: f64,
    pub z: f64,
    pub vz: f64,
    pub u: f64,
    pub period: f64,
    pub always_in_contact: bool,
    free: Discrete2,
    contact: Discrete2,
    /// Sub-steps for the period in which the contact changes.
    fine_free: Discrete2,
    fine_contact: Discrete2,
    fine: usize,
}

impl AggregatePlant {
    /// The paper's cantilever on an aggregate contact with SI values `k` (N/m), `c` (N·s/m),
    /// surface `h_m`, at loop period `period_s`.
    pub fn paper(k: f64, c: f64, h_m: f64, period_s: f64) -> Self {
        let cant = visco_core::Cantilever::PAPER;
        let m = cant.m_kg / units::MASS;
        let cc = cant.c_ns_per_m / units::DAMPING;
        let kc = cant.k_n_per_m / units::STIFFNESS;
        let k = k / units::STIFFNESS;
        let c = c / units::DAMPING;
        let period = period_s / units::TIME;
        let fine = 64;
        let d = |cd: f64, kd: f64, h: f64| {
            let (a, b) = mass_spring_damper(m, cd, kd);
            discretize2(a, b, h)
        };
        Self {
            m,
            c_cant: cc,
            k_cant: kc,
            k,
            c,
            h: h_m / units::LENGTH,
            z: h_m / units::LENGTH + 1000.0,
            vz: 0.0,
            u: h_m / units::LENGTH + 1000.0,
            period,
            always_in_contact: false,
            free: d(cc, kc, period),
            contact: d(cc + c, kc + k, period),
            fine_free: d(cc, kc, period / fine as f64),
            fine_contact: d(cc + c, kc + k, period / fine as f64),
            fine,
        }
    }

    /// Place the tip at rest at base position `u` (nm), in equilibrium.
    pub fn settle_at(&mut self, u: f64) {
        self.u = u;
        // Static equilibrium: K(U − Z) + k(h − Z)·[contact] = 0.
        let z_free = u;
        if self.always_in_contact || z_free < self.h {
            self.z = (self.k_cant * u + self.k * self.h) / (self.k_cant + self.k);
        } else {
            self.z = z_free;
        }
        self.vz = 0.0;
    }

    fn in_contact(&self, z: f64) -> bool {
        self.always_in_contact || z < self.h
    }

    /// Apply `u_next` (nm) over the next period; returns D (nm) at its end.
    pub fn step(&mut self, u_next: f64) -> f64 {
        // The DAC jump acts through C·Ḋ as an impulse on the tip velocity.
        self.vz += self.c_cant * (u_next - self.u) / self.m;
        self.u = u_next;
        let force_in = |s: &Self| s.k_cant * s.u + s.k * s.h;
        let c0 = self.in_contact(self.z);
        let (d, input) = if c0 {
            (&self.contact, force_in(self))
        } else {
            (&self.free, self.k_cant * self.u)
        };
        let x = d.step_zoh([self.z, self.vz], input);
        if self.in_contact(x[0]) == c0 {
            self.z = x[0];
            self.vz = x[1];
        } else {
            // The contact changes inside the period: integrate it in fine sub-steps.
            for _ in 0..self.fine {
                let c = self.in_contact(self.z);
                let (d, input) = if c {
                    (&self.fine_contact, force_in(self))
                } else {
                    (&self.fine_free, self.k_cant * self.u)
                };
                let x = d.step_zoh([self.z, self.vz], input);
                self.z = x[0];
                self.vz = x[1];
            }
        }
        self.u - self.z
    }
}
