//! Open-loop replay of the identification path: recorded U and D in, estimates out.
//!
//! [`crate::Controller::step`] closes the loop: it generates U (approach, indentation,
//! excitation, depth control) *and* estimates. Replaying a recording — on the host after the
//! fact (`visco identify`), or on the board in a hardware-in-the-loop test — needs only the
//! second half: the same prefilters, regressors, contact detector, estimators and high-pass, in
//! the same order per sample, fed with the U that was applied and the D that was measured.
//! [`Observer`] is that half, with the sequencing left to the caller, who decides from the
//! recording when an estimation window opens and closes.
//!
//! ## One sample ([`Observer::step`])
//! ```text
//! (U_k, D_k) ─▶ D ← D − D₀ (the free deflection offset, when known) ─▶ Z_k = U_k − D_k
//!     ─▶ prefilters (Z smooth, U a staircase) ─▶ contact detector (G_lp·D, −γ, −γ⁺)
//!     ─▶ DIVE: θ = [c, k] (13) or [c, k, k·(h_bed − z₀)] (offset form), φ from h or z₀
//!        SVE:  w and φ high-passed, θ = [c, k]; ĥ = Z + F/k̂, F = −K·G_lp·D   (decoupled)
//! ```
//! The pair (U_k, D_k) is that of the controller: U_k is the value the DAC held over the period
//! ending at t_k, D_k the deflection read at t_k. A recording made by stepping
//! `out = ctrl.step(d); d = plant.step(out.u_m, ..)` and writing `(out.u_m, d)` per row has
//! exactly this alignment.
//!
//! ## Same numbers as the loop
//! With the configuration of a [`crate::Config`] ([`ObserverConfig::from_config`]), a zero
//! offset, and the windows opened at the samples where the controller opened them, the
//! observer's estimates are those of the controller to the last bit (the unit test below
//! checks this for a DIVE tap and an SVE scan in f32, with the loop's estimator on blocks of one
//! sample: the observer is the per-sample law, not the loop's block schedule). Off-line, the host uses f64 and its own
//! windows and thresholds, derived from the recording.
//!
//! No allocation, no I/O, no panics: like the rest of the core, it also runs on the target.

use crate::config::{
    Cantilever, Config, ConfigError, ContactConfig, DiveRegressor, EstimatorConfig,
};
use crate::contact::{ContactDetector, ContactParams, ContactState};
use crate::estimator::{Estimator, EstimatorParams, UpdateInfo};
use crate::prefilter::HighPass;
use crate::real::Real;
use crate::regressor::{Regressor, RegressorParams};
use crate::{status, units};

/// What the observer needs: the cantilever, the prefilter, the contact detector and the two
/// estimators. A subset of [`Config`], without anything that generates U.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObserverConfig {
    /// Rate of the recording (Hz): one [`Observer::step`] per sample.
    pub sample_rate_hz: f64,
    /// Cantilever first mode (K, C, M).
    pub cantilever: Cantilever,
    /// λ of the prefilter 1/Λ, Λ = (λs + 1)² (s).
    pub lambda_s: f64,
    /// Contact detector.
    pub contact: ContactConfig,
    /// DIVE regressor form.
    pub dive_regressor: DiveRegressor,
    /// DIVE estimator.
    pub dive_estimator: EstimatorConfig,
    /// SVE estimator (the decoupled regression's two parameters).
    pub sve_estimator: EstimatorConfig,
    /// Corner of the SVE high-pass (Hz).
    pub sve_highpass_hz: f64,
    /// Span of heights the offset parameter θ₃ = k·(h − z₀) may cover (m): bounds θ₃.
    pub height_span_m: f64,
}

impl ObserverConfig {
    /// The observer of a controller configuration: the same filters, detector and estimators.
    pub fn from_config(cfg: &Config) -> Self {
        ObserverConfig {
            sample_rate_hz: cfg.sample_rate_hz,
            cantilever: cfg.cantilever,
            lambda_s: cfg.prefilter.lambda_s,
            contact: cfg.contact,
            dive_regressor: cfg.dive.regressor,
            dive_estimator: cfg.dive.estimator,
            sve_estimator: cfg.sve.estimator,
            sve_highpass_hz: cfg.sve.highpass_hz,
            height_span_m: cfg.limits.u_max_m - cfg.limits.u_min_m,
        }
    }

    /// Checks every field the observer uses; the first bad one is named.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let fs = self.sample_rate_hz;
        let bad = |field: &'static str, value: f64, reason: &'static str| {
            Err(ConfigError {
                field,
                value,
                reason,
            })
        };
        let pos = |field: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                bad(field, v, "must be a finite number > 0")
            }
        };
        pos("sample_rate_hz", fs)?;
        pos("cantilever.k_n_per_m", self.cantilever.k_n_per_m)?;
        pos("cantilever.c_ns_per_m", self.cantilever.c_ns_per_m)?;
        pos("cantilever.m_kg", self.cantilever.m_kg)?;
        pos("prefilter.lambda_s", self.lambda_s)?;
        if self.lambda_s * fs < 0.5 {
            return bad(
                "prefilter.lambda_s",
                self.lambda_s,
                "must be at least half a sample period",
            );
        }
        pos("contact.lowpass_hz", self.contact.lowpass_hz)?;
        if self.contact.lowpass_hz >= 0.5 * fs {
            return bad(
                "contact.lowpass_hz",
                self.contact.lowpass_hz,
                "must be below the Nyquist frequency",
            );
        }
        pos("contact.gamma_m", self.contact.gamma_m)?;
        pos("contact.gamma_plus_m", self.contact.gamma_plus_m)?;
        if !(self.contact.gamma_plus_m > self.contact.gamma_m) {
            return bad(
                "contact.gamma_plus_m",
                self.contact.gamma_plus_m,
                "must be greater than gamma_m (γ⁺ > γ)",
            );
        }
        pos("sve_highpass_hz", self.sve_highpass_hz)?;
        if self.sve_highpass_hz >= 0.5 * fs {
            return bad(
                "sve_highpass_hz",
                self.sve_highpass_hz,
                "must be below the Nyquist frequency",
            );
        }
        pos("height_span_m", self.height_span_m)?;
        for (e, names) in [
            (&self.dive_estimator, ESTIMATOR_FIELDS[0]),
            (&self.sve_estimator, ESTIMATOR_FIELDS[1]),
        ] {
            pos(names[0], e.alpha)?;
            pos(names[1], e.beta_per_s)?;
            if e.beta_per_s >= 0.1 * fs {
                return bad(names[1], e.beta_per_s, "must be below a tenth of the rate");
            }
            pos(names[2], e.r0)?;
            for p in e.p0 {
                pos(names[3], p)?;
            }
            pos(names[4], e.k_min_n_per_m)?;
            if !(e.k_max_n_per_m > e.k_min_n_per_m) || !e.k_max_n_per_m.is_finite() {
                return bad(names[5], e.k_max_n_per_m, "must be finite and above k_min");
            }
            pos(names[6], e.c_max_ns_per_m)?;
        }
        Ok(())
    }
}

const ESTIMATOR_FIELDS: [[&str; 7]; 2] = [
    [
        "dive_estimator.alpha",
        "dive_estimator.beta_per_s",
        "dive_estimator.r0",
        "dive_estimator.p0",
        "dive_estimator.k_min_n_per_m",
        "dive_estimator.k_max_n_per_m",
        "dive_estimator.c_max_ns_per_m",
    ],
    [
        "sve_estimator.alpha",
        "sve_estimator.beta_per_s",
        "sve_estimator.r0",
        "sve_estimator.p0",
        "sve_estimator.k_min_n_per_m",
        "sve_estimator.k_max_n_per_m",
        "sve_estimator.c_max_ns_per_m",
    ],
];

/// What the estimator is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Estimating {
    /// Filters and detector run; no estimation.
    Off,
    /// A DIVE window: θ of the configured [`DiveRegressor`].
    Dive,
    /// An SVE scan: the decoupled regression ([`crate::SveRegressor::Decoupled`]; the paper's
    /// form needs the depth controller's feedback to keep its offset meaningful while scanning).
    Sve,
}

/// The outputs of one sample, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation<T> {
    /// Tip position Z = U − (D − D₀) at this sample (m).
    pub z_m: T,
    /// Z/Λ, the filtered tip position; it describes the previous sample (m).
    pub z_filtered_m: T,
    /// The contact detector's low-passed deflection G_lp·(D − D₀) (m).
    pub d_lowpassed_m: T,
    /// The contact detector's state; heights in m.
    pub contact: ContactState<T>,
    /// What the estimator did this sample.
    pub estimating: Estimating,
    /// Aggregate damping ĉ (N·s/m).
    pub c_ns_per_m: T,
    /// Aggregate spring constant k̂ (N/m).
    pub k_n_per_m: T,
    /// DIVE offset form: θ̂₃ = k̂·(h_bed − z₀) (N); 0 otherwise.
    pub offset_n: T,
    /// The identified height of the element bed under the tip (m): DIVE offset form
    /// z₀ + θ̂₃/k̂, DIVE paper form the contact height, SVE Z/Λ + F/k̂.
    pub bed_height_m: T,
    /// DIVE: h − Z/Λ (apex depth below the contact height); SVE: F/k̂ (the depth the SVE
    /// controller holds) (m).
    pub depth_m: T,
    /// Status bits of the update ([`status::ESTIMATING`], [`status::PROJECTED`],
    /// [`status::COV_AT_BOUND`], [`status::EST_RESET`], [`status::INPUT_INVALID`]).
    pub flags: u32,
}

#[derive(Clone, Copy, Debug)]
struct Params<T> {
    to_internal: T,
    to_m: T,
    damping_to_si: T,
    reg: RegressorParams<T>,
    contact: ContactParams<T>,
    dive_regressor: DiveRegressor,
    dive2: EstimatorParams<T, 2>,
    dive3: EstimatorParams<T, 3>,
    sve2: EstimatorParams<T, 2>,
    highpass: T,
    lowpass_coeff: f64,
}

/// The replay pipeline: filters, contact detector, estimators; no sequencer, no output.
#[derive(Clone, Debug)]
pub struct Observer<T> {
    p: Params<T>,
    reg: Regressor<T>,
    contact: ContactDetector<T>,
    est2: Estimator<T, 2>,
    est3: Estimator<T, 3>,
    hp: [HighPass<T>; 3],
    mode: Estimating,
    /// DIVE: contact height h; SVE: centre z₀ of the position regressor (internal).
    h: T,
    z0: T,
    /// Free deflection subtracted from every D (internal).
    d_offset: T,
    /// Free deflection of the SVE force, relative to the offset (internal).
    d_free: T,
    d_last: T,
}

impl<T: Real> Observer<T> {
    /// Validates `cfg` and builds an observer at rest with the tip free at U = D = 0.
    pub fn new(cfg: &ObserverConfig) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let fs = cfg.sample_rate_hz;
        let t = |v: f64| T::from_f64(v);
        let nm = 1.0 / units::LENGTH;
        let lowpass_coeff = crate::discretize::one_pole_weight(
            2.0 * core::f64::consts::PI * cfg.contact.lowpass_hz / fs,
        );
        let p = Params {
            to_internal: t(nm),
            to_m: t(units::LENGTH),
            damping_to_si: t(units::DAMPING),
            reg: RegressorParams::new(
                cfg.cantilever.m_kg / units::MASS,
                cfg.cantilever.c_ns_per_m / units::DAMPING,
                cfg.cantilever.k_n_per_m / units::STIFFNESS,
                cfg.lambda_s / units::TIME,
                1e6 / fs,
            ),
            contact: ContactParams {
                lowpass: t(lowpass_coeff),
                gamma: t(cfg.contact.gamma_m * nm),
                gamma_plus: t(cfg.contact.gamma_plus_m * nm),
            },
            dive_regressor: cfg.dive_regressor,
            dive2: cfg.dive_estimator.params(fs, cfg.height_span_m),
            dive3: cfg.dive_estimator.params(fs, cfg.height_span_m),
            sve2: cfg.sve_estimator.params(fs, cfg.height_span_m),
            highpass: HighPass::coefficient(cfg.sve_highpass_hz, fs),
            lowpass_coeff,
        };
        Ok(Self {
            reg: Regressor::at_rest(T::ZERO, T::ZERO),
            contact: ContactDetector::new(T::ZERO),
            est2: Estimator::new(&p.dive2, [T::ZERO; 2]),
            est3: Estimator::new(&p.dive3, [T::ZERO; 3]),
            hp: [HighPass::default(); 3],
            mode: Estimating::Off,
            h: T::ZERO,
            z0: T::ZERO,
            d_offset: T::ZERO,
            d_free: T::ZERO,
            d_last: T::ZERO,
            p,
        })
    }

    /// Filters at rest at base position `u_m` and deflection `d_m` (the tip still), the
    /// contact detector armed with its low-pass at `d_m`, estimation off.
    pub fn reset(&mut self, u_m: f64, d_m: f64) {
        let nm = 1.0 / units::LENGTH;
        let u = T::from_f64(u_m * nm);
        let d = T::from_f64(d_m * nm) - self.d_offset;
        self.reg = Regressor::at_rest(u - d, u);
        self.contact = ContactDetector::new(d);
        self.d_last = d;
        self.mode = Estimating::Off;
    }

    /// The free deflection D₀ (m), subtracted from every D from now on: a sensor offset, so
    /// that the contact thresholds and the force act on the deflection that bends the
    /// cantilever. The controller has none (0).
    pub fn set_deflection_offset(&mut self, d0_m: f64) {
        self.d_offset = T::from_f64(d0_m * (1.0 / units::LENGTH));
    }

    /// Contact thresholds γ and γ⁺ (m of deflection), e.g. raised above a recording's noise.
    pub fn set_contact_thresholds(&mut self, gamma_m: f64, gamma_plus_m: f64) {
        self.p.contact.gamma = T::from_f64(gamma_m) * self.p.to_internal;
        self.p.contact.gamma_plus = T::from_f64(gamma_plus_m) * self.p.to_internal;
    }

    /// The contact detector's low-pass coefficient a of y ← y + a·(D − y).
    pub fn lowpass_coefficient(&self) -> f64 {
        self.p.lowpass_coeff
    }

    /// A new contact detector, armed, with its low-pass at the last deflection seen (what the
    /// controller does when an approach starts).
    pub fn restart_contact(&mut self) {
        self.contact = ContactDetector::new(self.d_last);
    }

    /// Re-arms the contact detector, keeping its low-pass.
    pub fn rearm(&mut self) {
        self.contact.rearm();
    }

    /// Opens a DIVE window. The estimator restarts from `theta0` = [c (N·s/m), k (N/m),
    /// θ₃ (N)] with covariance P₀; the contact height is `contact_height_m`, or, when `None`,
    /// the height the detector confirmed (returns `false`, and opens nothing, if it has none).
    /// `centre_below_contact_m` places the centre of the offset form's position regressor,
    /// z₀ = h − this (any constant near the tip keeps f32's digits; the controller uses the
    /// indentation depth). The paper's form uses h in φ = [s·δ/Λ, δ/Λ], δ = h − Z.
    pub fn start_dive(
        &mut self,
        contact_height_m: Option<f64>,
        centre_below_contact_m: f64,
        theta0: [f64; 3],
    ) -> bool {
        let h = match contact_height_m {
            Some(h) => T::from_f64(h * (1.0 / units::LENGTH)),
            None => match self.contact.contact_height() {
                Some(h) => h,
                None => return false,
            },
        };
        self.h = h;
        self.z0 = h - T::from_f64(centre_below_contact_m * (1.0 / units::LENGTH));
        let th = [
            T::from_f64(theta0[0] / units::DAMPING),
            T::from_f64(theta0[1] / units::STIFFNESS),
            T::from_f64(theta0[2] / units::FORCE),
        ];
        match self.p.dive_regressor {
            DiveRegressor::Paper => self.est2.restart(&self.p.dive2, [th[0], th[1]]),
            DiveRegressor::Offset => self.est3.restart(&self.p.dive3, th),
        }
        self.mode = Estimating::Dive;
        true
    }

    /// Opens an SVE scan at the current sample (the controller does this at the sample that
    /// confirms contact). The position regressor is centred at `z0_m`, or, when `None`, at
    /// the height the detector confirmed (returns `false` if it has none). `d_free_m` is the
    /// free deflection of the force balance F = K·(D_free − G_lp·D) (relative to the offset;
    /// the controller takes D at the start of the approach); `theta0` the starting [c, k].
    pub fn start_sve(&mut self, z0_m: Option<f64>, d_free_m: f64, theta0: [f64; 2]) -> bool {
        let nm = 1.0 / units::LENGTH;
        let z0 = match z0_m {
            Some(z) => T::from_f64(z * (1.0 / units::LENGTH)),
            None => match self.contact.contact_height() {
                Some(h) => h,
                None => return false,
            },
        };
        self.z0 = z0;
        self.d_free = T::from_f64(d_free_m * nm);
        self.est2.restart(
            &self.p.sve2,
            [
                T::from_f64(theta0[0] / units::DAMPING),
                T::from_f64(theta0[1] / units::STIFFNESS),
            ],
        );
        let w = self.reg.w(&self.p.reg);
        let phi = self.reg.phi_sve(self.z0);
        self.hp = [
            HighPass::at_rest(w),
            HighPass::at_rest(phi[0]),
            HighPass::at_rest(phi[1]),
        ];
        self.mode = Estimating::Sve;
        true
    }

    /// Resumes estimating in the window last opened, from the estimates where they stopped.
    pub fn resume(&mut self, mode: Estimating) {
        self.mode = mode;
    }

    /// Closes the window: the estimates stay as they are.
    pub fn stop(&mut self) {
        self.mode = Estimating::Off;
    }

    /// What the estimator is doing.
    pub fn estimating(&self) -> Estimating {
        self.mode
    }

    /// The two-parameter estimator (DIVE paper form, SVE), internal units.
    pub fn estimator2(&self) -> &Estimator<T, 2> {
        &self.est2
    }

    /// The three-parameter estimator (DIVE offset form), internal units.
    pub fn estimator3(&self) -> &Estimator<T, 3> {
        &self.est3
    }

    /// One recorded sample: `u_m` the base position held over the period ending now, `d_m`
    /// the deflection read now (m). Recordings are f64; each value is converted to internal
    /// units in f64 and then rounded once to `T`, so a U on the DAC grid and a D that the loop
    /// received as `T` arrive exactly as the loop had them.
    #[inline]
    pub fn step(&mut self, u_m: f64, d_m: f64) -> Observation<T> {
        let p = &self.p;
        let mut flags = 0u32;
        let nm = 1.0 / units::LENGTH;
        let u = T::from_f64(u_m * nm);
        let d_in = T::from_f64(d_m * nm) - self.d_offset;
        let d = if d_in.is_finite() {
            d_in
        } else {
            flags |= status::INPUT_INVALID;
            self.d_last
        };
        self.d_last = d;
        let z = u - d;
        self.reg.update(&p.reg, u, z);
        let state = self.contact.update(&p.contact, d, z);
        let input_ok = flags == 0;
        let (mut th, mut bed, mut depth) = ([T::ZERO; 3], T::ZERO, T::ZERO);
        match self.mode {
            Estimating::Off => {}
            Estimating::Dive => {
                let w = self.reg.w(&p.reg);
                match p.dive_regressor {
                    DiveRegressor::Paper => {
                        if input_ok {
                            flags |= est_flags(self.est2.update(
                                &p.dive2,
                                w,
                                &self.reg.phi_dive(self.h),
                            ));
                        }
                        let t2 = self.est2.theta();
                        th = [t2[0], t2[1], T::ZERO];
                        bed = self.h;
                    }
                    DiveRegressor::Offset => {
                        if input_ok {
                            flags |= est_flags(self.est3.update(
                                &p.dive3,
                                w,
                                &self.reg.phi_sve(self.z0),
                            ));
                        }
                        th = self.est3.theta();
                        bed = self.z0 + th[2] / th[1];
                    }
                }
                depth = self.h - self.reg.z_x();
            }
            Estimating::Sve => {
                let w = self.reg.w(&p.reg);
                let phi = self.reg.phi_sve(self.z0);
                let hp = &mut self.hp;
                let wh = hp[0].update(p.highpass, w);
                let phi_h = [
                    hp[1].update(p.highpass, phi[0]),
                    hp[2].update(p.highpass, phi[1]),
                ];
                if input_ok {
                    flags |= est_flags(self.est2.update(&p.sve2, wh, &phi_h));
                }
                let t2 = self.est2.theta();
                th = [t2[0], t2[1], T::ZERO];
                // k̂ ≥ k_min > 0 by projection.
                let force = p.reg.stiffness * (self.d_free - self.contact.lowpassed());
                depth = force / t2[1];
                bed = self.reg.z_x() + depth;
            }
        }
        let to_m = p.to_m;
        Observation {
            z_m: z * to_m,
            z_filtered_m: self.reg.z_x() * to_m,
            d_lowpassed_m: self.contact.lowpassed() * to_m,
            contact: match state {
                ContactState::Armed => ContactState::Armed,
                ContactState::Candidate { h } => ContactState::Candidate { h: h * to_m },
                ContactState::Confirmed { h } => ContactState::Confirmed { h: h * to_m },
            },
            estimating: self.mode,
            c_ns_per_m: th[0] * p.damping_to_si,
            k_n_per_m: th[1],
            offset_n: th[2] * to_m,
            bed_height_m: bed * to_m,
            depth_m: depth * to_m,
            flags,
        }
    }
}

fn est_flags(info: UpdateInfo) -> u32 {
    let mut f = status::ESTIMATING;
    if info.at_bound {
        f |= status::COV_AT_BOUND;
    }
    if info.projected {
        f |= status::PROJECTED;
    }
    if info.reset {
        f |= status::EST_RESET;
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretize::{discretize2, mass_spring_damper, Discrete2};
    use crate::{Command, Controller, Mode, Phase};
    use std::vec::Vec;

    /// The cantilever on an aggregate Kelvin–Voigt contact, exact per period, internal units.
    /// The contact switches at period boundaries only: the test compares two computations on
    /// the same data, not physics.
    struct Aggregate {
        free: Discrete2,
        contact: Discrete2,
        m: f64,
        cc: f64,
        kc: f64,
        k: f64,
        h: f64,
        z: f64,
        v: f64,
        u: f64,
    }

    impl Aggregate {
        fn new(h_m: f64, u0_m: f64, fs: f64) -> Self {
            let cant = Cantilever::PAPER;
            let m = cant.m_kg / units::MASS;
            let cc = cant.c_ns_per_m / units::DAMPING;
            let kc = cant.k_n_per_m / units::STIFFNESS;
            let (k, c) = (0.099, 1.7e-5 / units::DAMPING);
            let d = |cd: f64, kd: f64| {
                let (a, b) = mass_spring_damper(m, cd, kd);
                discretize2(a, b, 1e6 / fs)
            };
            let u = u0_m / units::LENGTH;
            Self {
                free: d(cc, kc),
                contact: d(cc + c, kc + k),
                m,
                cc,
                kc,
                k,
                h: h_m / units::LENGTH,
                z: u,
                v: 0.0,
                u,
            }
        }

        fn step(&mut self, u_m: f64) -> f64 {
            let u = u_m / units::LENGTH;
            self.v += self.cc * (u - self.u) / self.m;
            self.u = u;
            let x = if self.z < self.h {
                self.contact
                    .step_zoh([self.z, self.v], self.kc * u + self.k * self.h)
            } else {
                self.free.step_zoh([self.z, self.v], self.kc * u)
            };
            self.z = x[0];
            self.v = x[1];
            (self.u - self.z) * units::LENGTH
        }
    }

    /// One recorded row and what the controller made of it.
    struct Row {
        u: f64,
        d: f32,
        status: u32,
        theta: [f32; 3],
    }

    /// The controller in closed loop; rows in the recording's alignment (U held over the
    /// period ending at the sample, D read at it), each with the status and θ̂ of the step
    /// that consumed it.
    fn closed_loop(cfg: &Config, mode: Mode, steps: usize) -> Vec<Row> {
        let mut ctrl = Controller::<f32>::new(cfg).unwrap();
        let mut plant = Aggregate::new(120e-9, cfg.approach.u_start_m, cfg.sample_rate_hz);
        ctrl.command(Command::Start(mode));
        let mut rows = Vec::new();
        // U exactly as the loop holds it: its DAC value, code × LSB (6 µm over 16 bits).
        let lsb_m = (cfg.limits.u_max_m - cfg.limits.u_min_m) / 65536.0;
        assert_eq!(cfg.limits.u_max_m, -cfg.limits.u_min_m);
        let (mut u, mut d) = ((cfg.approach.u_start_m / lsb_m).round() * lsb_m, 0.0f32);
        for _ in 0..steps {
            let out = ctrl.step(d);
            let theta = match mode {
                Mode::Dive => ctrl.estimator3().theta(),
                Mode::Sve => {
                    let t = ctrl.estimator2().theta();
                    [t[0], t[1], 0.0]
                }
            };
            rows.push(Row {
                u,
                d,
                status: out.status,
                theta,
            });
            if ctrl.phase() == Phase::Done {
                break;
            }
            d = plant.step(out.u_m as f64) as f32;
            u = out.u_code as f64 * lsb_m;
        }
        rows
    }

    fn phase(st: u32) -> u32 {
        st >> status::PHASE_SHIFT
    }

    /// Replays `rows` with the windows opened where the controller opened them; returns how
    /// many estimator updates were compared (every one bit for bit).
    fn replay(cfg: &Config, mode: Mode, rows: &[Row]) -> usize {
        let mut obs = Observer::<f32>::new(&ObserverConfig::from_config(cfg)).unwrap();
        obs.reset(rows[0].u, 0.0);
        let mut prev = Phase::Move as u32;
        let mut compared = 0;
        for r in rows {
            let estimating = r.status & status::ESTIMATING != 0;
            if mode == Mode::Dive {
                if estimating && obs.estimating() == Estimating::Off {
                    let k0 = cfg.nominal_dive.k_n_per_m;
                    let depth = cfg.dive.indent_depth_m;
                    let theta0 = [
                        cfg.nominal_dive.c_ns_per_m,
                        k0,
                        // The controller's θ₃ = k·(indent − R/3), formed in nm.
                        k0 * (depth * 1e9 - cfg.tip_radius_m * 1e9 / 3.0) * units::FORCE,
                    ];
                    assert!(obs.start_dive(None, depth, theta0), "no contact height");
                } else if !estimating && obs.estimating() == Estimating::Dive {
                    obs.stop();
                }
            }
            let o = obs.step(r.u, r.d as f64);
            let now = phase(r.status);
            if now == Phase::Approach as u32 && prev == Phase::Move as u32 {
                // The controller built a new detector in that step, from its D.
                obs.restart_contact();
            }
            if mode == Mode::Sve && now == Phase::Settle as u32 && prev == Phase::Approach as u32 {
                let n = cfg.nominal_sve;
                let d_free = rows
                    .iter()
                    .take_while(|x| phase(x.status) != Phase::Approach as u32)
                    .last()
                    .map(|x| x.d as f64)
                    .unwrap();
                assert!(obs.start_sve(None, d_free, [n.c_ns_per_m, n.k_n_per_m]));
            }
            if estimating && o.flags & status::ESTIMATING != 0 {
                let th = match mode {
                    Mode::Dive => obs.estimator3().theta(),
                    Mode::Sve => {
                        let t = obs.estimator2().theta();
                        [t[0], t[1], 0.0]
                    }
                };
                assert_eq!(th, r.theta, "sample {compared} of the window");
                compared += 1;
            } else {
                assert!(
                    !estimating,
                    "the controller estimated, the observer did not"
                );
            }
            prev = now;
        }
        compared
    }

    #[test]
    fn dive_replay_is_bit_identical_to_the_loop() {
        let mut cfg = Config::paper(1e6);
        cfg.dive.nx = 1;
        cfg.dive.ny = 1;
        cfg.dive.tap_s = 0.05;
        // The observer is the per-sample law: the loop's blocks of one sample.
        cfg.dive.estimator.decimation = 1;
        let rows = closed_loop(&cfg, Mode::Dive, 60_000);
        let n = replay(&cfg, Mode::Dive, &rows);
        assert!(n > 20_000, "only {n} updates compared");
    }

    #[test]
    fn sve_replay_is_bit_identical_to_the_loop() {
        let mut cfg = Config::paper(1e6);
        cfg.sve.lines = 1;
        cfg.sve.pixels = 4;
        cfg.sve.line_period_s = 0.06;
        cfg.sve.estimator.decimation = 1;
        let rows = closed_loop(&cfg, Mode::Sve, 200_000);
        let n = replay(&cfg, Mode::Sve, &rows);
        assert!(n > 50_000, "only {n} updates compared");
    }
}
