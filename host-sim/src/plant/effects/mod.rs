//! Extra physics ("effects"): the ten model extensions of `recording.md`'s vocabulary, each
//! defined once and used by everything that simulates — the plant ([`super::Plant::add_effect`]),
//! the concealed-effect suite (`experiment::concealed`) and `diagnose`'s model
//! (`diagnose::model`), which runs the same [`Effect`] values through the same hooks.
//!
//! | identifier | law (one file each) | parameters |
//! | --- | --- | --- |
//! | `nonlinear-stiffness` | [`NonlinearStiffness`]: the bed's elastic force × (δ/δ_ref)^q | q |
//! | `adhesion` | [`Adhesion`]: −F_a from the first touch (or from when the contact unloads) until the tip is ℓ out of the sample | F_a, ℓ, which |
//! | `surface-attraction` | [`SurfaceAttraction`]: −F_s·e^{−s/λ} at separation s > 0 (−F_s in contact) | F_s, λ |
//! | `stress-relaxation` | [`StressRelaxation`]: Maxwell arms on the bed (standard linear solid; two arms approximate power-law rheology) | ρ, τ per arm |
//! | `hydrodynamic-drag` | [`HydrodynamicDrag`]: −c_h·((1 − w)·Ż + w·U̇), in and out of contact | c_h, w |
//! | `baseline-tilt` | [`BaselineTilt`]: the detector reads D + b·(U − U_ref) | b |
//! | `thermal-drift` | [`ThermalDrift`]: the detector reads D + r·(t − t_ref) | r |
//! | `second-eigenmode` | [`SecondEigenmode`]: a mode at f₂ rung by the tip force and the base's motion, added to the reading | f₂, Q₂, g_F, g_U |
//! | `piezo-creep` | [`PiezoCreep`]: the base reaches U − γ·(U − U_f), U_f = U/(τs + 1) | γ, τ |
//! | `plastic-deformation` | [`PlasticDeformation`]: the bed sinks by φ × the deepest indentation | φ |
//!
//! ## Hooks
//! The plant (and `diagnose`'s model, in the same order) calls the hooks at fixed points of
//! every step (see [`super::Plant::step`]):
//!
//! 1. [`Effect::piezo_z_nm`]: the piezo position the cantilever base sees this period, from the
//!    commanded U (creep; plastic sinking, which is the same as the base rising by the sink:
//!    only `Z − h` and `U − Z` enter the physics). The DAC-step impulse `C·ΔU/M` uses the
//!    result.
//! 2. [`Effect::tip_force_nn`]: an extra force on the tip, held constant over the period
//!    (evaluated from the state at the period's start, as the DAC holds U). First order in the
//!    step: fine for the forces here, all slow or small next to the contact's own stiffness
//!    at the step sizes used; a force strongly dependent on Ż is given as a linear term.
//! 3. [`Effect::linear_terms`]: extra stiffness and damping on Z (hydrodynamic drag on the tip
//!    velocity), joined to `K + S_k` and `C + S_c` and integrated exactly. Read when the effect
//!    is added; call [`super::Plant::effects_changed`] if they change.
//! 4. [`Effect::measured_deflection_nm`]: what the detector reads, from the true deflection
//!    (baseline tilt, drift, the second mode's optical-lever signal).
//! 5. [`Effect::end_of_step`]: advance the effect's own state with the step's end state.
//!
//! Evaluation hooks take `&self` and only `end_of_step` changes state, so a caller may
//! evaluate an effect several times within a step (the quasi-static model iterates).
//!
//! Cost on the nominal path: one predictable branch per hook point when no effect is present.
//!
//! Units are the plant's internal ones: nm, µs, nN, nN/nm, nN·µs/nm. [`EffectSpec`] holds
//! the parameters in SI and builds the effect.

mod adhesion;
mod baseline_tilt;
mod hydrodynamic_drag;
mod nonlinear_stiffness;
mod piezo_creep;
mod plastic_deformation;
mod second_eigenmode;
mod stress_relaxation;
mod surface_attraction;
mod thermal_drift;

pub use adhesion::Adhesion;
pub use baseline_tilt::BaselineTilt;
pub use hydrodynamic_drag::HydrodynamicDrag;
pub use nonlinear_stiffness::NonlinearStiffness;
pub use piezo_creep::PiezoCreep;
pub use plastic_deformation::PlasticDeformation;
pub use second_eigenmode::SecondEigenmode;
pub use stress_relaxation::StressRelaxation;
pub use surface_attraction::SurfaceAttraction;
pub use thermal_drift::ThermalDrift;

use visco_core::units::{DAMPING, FORCE, LENGTH, STIFFNESS, TIME};

/// What an effect sees of the plant (or of `diagnose`'s model) at a hook.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EffectContext {
    /// Time (µs): the period's start for hooks 1–2, its end for hooks 4–5.
    pub time_us: f64,
    /// The period (µs).
    pub dt_us: f64,
    /// Tip apex height Z (nm), in the frame of the bed the tip presses (see
    /// [`PlasticDeformation`]).
    pub z_nm: f64,
    /// Tip velocity Ż (nm/µs).
    pub z_dot_nm_per_us: f64,
    /// Commanded piezo position U of this period, after the DAC and travel clamp and before
    /// [`Effect::piezo_z_nm`] (nm).
    pub u_nm: f64,
    /// Lateral position (nm).
    pub x_nm: f64,
    pub y_nm: f64,
    /// Sample force on the tip, springs and dampers (nN, positive up).
    pub contact_force_nn: f64,
    /// The bed's elastic force alone, `Σ_W k_i·δ_i` (nN): what a Maxwell arm is loaded by.
    pub elastic_force_nn: f64,
    /// Apex depth below the height where the tip first touches the bed (nm): positive in
    /// contact, minus the separation above it, −∞ off the sample.
    pub depth_nm: f64,
    /// Number of engaged elements (the model reports 1 in contact, 0 out).
    pub active_elements: usize,
}

/// One extra physics term; every hook defaults to "no effect".
pub trait Effect: Send {
    /// A short name for reports (the identifier of `recording.md` for the ten laws).
    fn name(&self) -> &str;
    /// The piezo position the cantilever base sees this period (nm), from the commanded one.
    fn piezo_z_nm(&self, _ctx: &EffectContext, u_nm: f64) -> f64 {
        u_nm
    }
    /// An extra force on the tip held over the period (nN, positive up).
    fn tip_force_nn(&self, _ctx: &EffectContext) -> f64 {
        0.0
    }
    /// Constant extra stiffness (nN/nm) and damping (nN·µs/nm) acting on Z.
    fn linear_terms(&self) -> (f64, f64) {
        (0.0, 0.0)
    }
    /// The deflection the detector reports, from the true one (nm).
    fn measured_deflection_nm(&self, _ctx: &EffectContext, d_nm: f64) -> f64 {
        d_nm
    }
    /// Advance the effect's own state at the end of the period.
    fn end_of_step(&mut self, _ctx: &EffectContext) {}
}

/// The effect vocabulary of `recording.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectKind {
    NonlinearStiffness,
    Adhesion,
    SurfaceAttraction,
    StressRelaxation,
    HydrodynamicDrag,
    BaselineTilt,
    ThermalDrift,
    SecondEigenmode,
    PiezoCreep,
    PlasticDeformation,
}

impl EffectKind {
    /// All ten, in `recording.md`'s order.
    pub const ALL: [EffectKind; 10] = [
        EffectKind::NonlinearStiffness,
        EffectKind::Adhesion,
        EffectKind::SurfaceAttraction,
        EffectKind::StressRelaxation,
        EffectKind::HydrodynamicDrag,
        EffectKind::BaselineTilt,
        EffectKind::ThermalDrift,
        EffectKind::SecondEigenmode,
        EffectKind::PiezoCreep,
        EffectKind::PlasticDeformation,
    ];

    /// The report's identifier.
    pub fn as_str(self) -> &'static str {
        match self {
            EffectKind::NonlinearStiffness => "nonlinear-stiffness",
            EffectKind::Adhesion => "adhesion",
            EffectKind::SurfaceAttraction => "surface-attraction",
            EffectKind::StressRelaxation => "stress-relaxation",
            EffectKind::HydrodynamicDrag => "hydrodynamic-drag",
            EffectKind::BaselineTilt => "baseline-tilt",
            EffectKind::ThermalDrift => "thermal-drift",
            EffectKind::SecondEigenmode => "second-eigenmode",
            EffectKind::PiezoCreep => "piezo-creep",
            EffectKind::PlasticDeformation => "plastic-deformation",
        }
    }

    /// Whether the effect acts only on what the detector reports (hooks 4 and 5), never on the
    /// cantilever's motion: the states of a model with it are those without it.
    pub fn reading_only(self) -> bool {
        matches!(
            self,
            EffectKind::BaselineTilt | EffectKind::ThermalDrift | EffectKind::SecondEigenmode
        )
    }

    /// From the identifier.
    pub fn parse(s: &str) -> Option<EffectKind> {
        EffectKind::ALL.into_iter().find(|k| k.as_str() == s.trim())
    }

    /// The physics left out, in a sentence (`recording.md`'s table).
    pub fn physics(self) -> &'static str {
        match self {
            EffectKind::NonlinearStiffness => {
                "the contact force does not grow with depth as the element bed predicts"
            }
            EffectKind::Adhesion => {
                "an attractive force while the tip touches the sample, seen most at pull-off"
            }
            EffectKind::SurfaceAttraction => {
                "an attractive force before contact that grows as the tip nears the surface"
            }
            EffectKind::StressRelaxation => {
                "the force relaxes at constant depth, which a Kelvin–Voigt element cannot do"
            }
            EffectKind::HydrodynamicDrag => {
                "a velocity-proportional force on the cantilever, in and out of contact"
            }
            EffectKind::BaselineTilt => {
                "the out-of-contact deflection changes linearly with the piezo position"
            }
            EffectKind::ThermalDrift => "the deflection offset drifts with time",
            EffectKind::SecondEigenmode => "the cantilever's second flexural mode is excited",
            EffectKind::PiezoCreep => "the actual base position lags the command after a move",
            EffectKind::PlasticDeformation => {
                "the surface does not come back: loading and unloading differ beyond viscosity"
            }
        }
    }
}

impl std::fmt::Display for EffectKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One effect with its parameters, SI. [`EffectSpec::build`] makes the plant's [`Effect`].
#[derive(Clone, Debug, PartialEq)]
pub enum EffectSpec {
    /// The bed's elastic force scaled by `(δ/δ_ref)^exponent_change`.
    NonlinearStiffness {
        exponent_change: f64,
        reference_depth_m: f64,
    },
    /// `force_n` of attraction from the first touch (or, `unloading_only`, from when the
    /// contact unloads) until the tip is `reach_m` out.
    Adhesion {
        force_n: f64,
        reach_m: f64,
        unloading_only: bool,
    },
    /// `force_n·e^{−s/decay_length_m}` of attraction at separation s.
    SurfaceAttraction { force_n: f64, decay_length_m: f64 },
    /// Maxwell arms `(stiffness ratio to the bed, relaxation time s)`.
    StressRelaxation { arms: Vec<(f64, f64)> },
    /// Drag `drag_ns_per_m` on `(1 − base_fraction)·Ż + base_fraction·U̇`.
    HydrodynamicDrag {
        drag_ns_per_m: f64,
        base_fraction: f64,
    },
    /// Detector reads `D + tilt·(U − u_ref_m)`.
    BaselineTilt { tilt: f64, u_ref_m: f64 },
    /// Detector reads `D + rate·(t − t_ref_s)`.
    ThermalDrift { rate_m_per_s: f64, t_ref_s: f64 },
    /// Second mode at `f_hz`, quality `q`, gains on the tip force (`gain`, relative to the
    /// first mode's static deflection per force `1/k_n_per_m`) and on the base's motion
    /// (`base_gain`).
    SecondEigenmode {
        f_hz: f64,
        q: f64,
        gain: f64,
        base_gain: f64,
        /// Gain on the base's velocity (`ω₂·s/(…)·U`).
        velocity_gain: f64,
        /// Gain on the tip force's static part (`F/K`: the mode's static compliance when K
        /// leaves it out).
        static_gain: f64,
        k_n_per_m: f64,
    },
    /// A fraction `fraction` of every move arrives with time constant `tau_s`.
    PiezoCreep { fraction: f64, tau_s: f64 },
    /// The bed sinks by `fraction` of the deepest indentation so far.
    PlasticDeformation { fraction: f64 },
}

impl EffectSpec {
    /// The vocabulary entry.
    pub fn kind(&self) -> EffectKind {
        match self {
            EffectSpec::NonlinearStiffness { .. } => EffectKind::NonlinearStiffness,
            EffectSpec::Adhesion { .. } => EffectKind::Adhesion,
            EffectSpec::SurfaceAttraction { .. } => EffectKind::SurfaceAttraction,
            EffectSpec::StressRelaxation { .. } => EffectKind::StressRelaxation,
            EffectSpec::HydrodynamicDrag { .. } => EffectKind::HydrodynamicDrag,
            EffectSpec::BaselineTilt { .. } => EffectKind::BaselineTilt,
            EffectSpec::ThermalDrift { .. } => EffectKind::ThermalDrift,
            EffectSpec::SecondEigenmode { .. } => EffectKind::SecondEigenmode,
            EffectSpec::PiezoCreep { .. } => EffectKind::PiezoCreep,
            EffectSpec::PlasticDeformation { .. } => EffectKind::PlasticDeformation,
        }
    }

    /// The effect, ready to add to a plant or a model (internal units inside).
    pub fn build(&self) -> Box<dyn Effect> {
        match self {
            EffectSpec::NonlinearStiffness {
                exponent_change,
                reference_depth_m,
            } => Box::new(NonlinearStiffness::new(
                *exponent_change,
                reference_depth_m / LENGTH,
            )),
            EffectSpec::Adhesion {
                force_n,
                reach_m,
                unloading_only,
            } => Box::new(Adhesion::new(
                force_n / FORCE,
                reach_m / LENGTH,
                *unloading_only,
            )),
            EffectSpec::SurfaceAttraction {
                force_n,
                decay_length_m,
            } => Box::new(SurfaceAttraction::new(
                force_n / FORCE,
                decay_length_m / LENGTH,
            )),
            EffectSpec::StressRelaxation { arms } => Box::new(StressRelaxation::new(
                arms.iter().map(|&(r, tau)| (r, tau / TIME)),
            )),
            EffectSpec::HydrodynamicDrag {
                drag_ns_per_m,
                base_fraction,
            } => Box::new(HydrodynamicDrag::new(
                drag_ns_per_m / DAMPING,
                *base_fraction,
            )),
            EffectSpec::BaselineTilt { tilt, u_ref_m } => {
                Box::new(BaselineTilt::new(*tilt, u_ref_m / LENGTH))
            }
            EffectSpec::ThermalDrift {
                rate_m_per_s,
                t_ref_s,
            } => Box::new(ThermalDrift::new(
                rate_m_per_s / LENGTH * TIME,
                t_ref_s / TIME,
            )),
            EffectSpec::SecondEigenmode {
                f_hz,
                q,
                gain,
                base_gain,
                velocity_gain,
                static_gain,
                k_n_per_m,
            } => Box::new(SecondEigenmode::new(
                f_hz * TIME,
                *q,
                *gain,
                *base_gain,
                *velocity_gain,
                *static_gain,
                k_n_per_m / STIFFNESS,
            )),
            EffectSpec::PiezoCreep { fraction, tau_s } => {
                Box::new(PiezoCreep::new(*fraction, tau_s / TIME))
            }
            EffectSpec::PlasticDeformation { fraction } => {
                Box::new(PlasticDeformation::new(*fraction))
            }
        }
    }

    /// The parameters by name (SI, the unit in the name's suffix), as the report gives them.
    pub fn parameters(&self) -> Vec<(String, f64)> {
        let p = |k: &str, v: f64| (k.to_string(), v);
        match self {
            EffectSpec::NonlinearStiffness {
                exponent_change,
                reference_depth_m,
            } => vec![
                p("exponent_change", *exponent_change),
                p("shallow_force_depth_exponent", 2.0 + exponent_change),
                p("reference_depth_m", *reference_depth_m),
            ],
            EffectSpec::Adhesion {
                force_n,
                reach_m,
                unloading_only,
            } => vec![
                p("pull_off_force_n", *force_n),
                p("reach_m", *reach_m),
                p("on_unloading_only", f64::from(u8::from(*unloading_only))),
            ],
            EffectSpec::SurfaceAttraction {
                force_n,
                decay_length_m,
            } => vec![
                p("force_at_contact_n", *force_n),
                p("decay_length_m", *decay_length_m),
            ],
            EffectSpec::StressRelaxation { arms } => {
                let mut v = Vec::new();
                for (i, (r, tau)) in arms.iter().enumerate() {
                    v.push((format!("arm{}_stiffness_ratio", i + 1), *r));
                    v.push((format!("arm{}_relaxation_time_s", i + 1), *tau));
                }
                v
            }
            EffectSpec::HydrodynamicDrag {
                drag_ns_per_m,
                base_fraction,
            } => vec![
                p("drag_ns_per_m", *drag_ns_per_m),
                p("base_velocity_fraction", *base_fraction),
            ],
            EffectSpec::BaselineTilt { tilt, u_ref_m } => {
                vec![p("tilt_m_per_m", *tilt), p("u_ref_m", *u_ref_m)]
            }
            EffectSpec::ThermalDrift {
                rate_m_per_s,
                t_ref_s,
            } => vec![p("rate_m_per_s", *rate_m_per_s), p("t_ref_s", *t_ref_s)],
            EffectSpec::SecondEigenmode {
                f_hz,
                q,
                gain,
                base_gain,
                velocity_gain,
                static_gain,
                ..
            } => vec![
                p("f2_hz", *f_hz),
                p("q2", *q),
                p("force_gain", *gain),
                p("base_gain", *base_gain),
                p("base_velocity_gain", *velocity_gain),
                p("force_static_gain", *static_gain),
            ],
            EffectSpec::PiezoCreep { fraction, tau_s } => {
                vec![p("creep_fraction", *fraction), p("tau_s", *tau_s)]
            }
            EffectSpec::PlasticDeformation { fraction } => {
                vec![p("plastic_fraction", *fraction)]
            }
        }
    }
}

/// `e^{−dt/τ}` and the weight `(τ/dt)·(1 − e^{−dt/τ})` of a first-order lag for an input that
/// is linear over the step: the exact update `y ← a·y + w·Δx` of `τẏ + y = τẋ`.
#[inline]
pub(crate) fn first_order(dt: f64, tau: f64) -> (f64, f64) {
    let x = dt / tau;
    let a = (-x).exp();
    // (1 − e^{−x})/x without cancellation for small x.
    let w = if x < 1e-4 {
        1.0 - 0.5 * x + x * x / 6.0
    } else {
        -(-x).exp_m1() / x
    };
    (a, w)
}
