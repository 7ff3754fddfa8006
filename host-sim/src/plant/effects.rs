//! Extension point for extra physics ("effects"): adhesion, surface attraction, stress
//! relaxation (a Maxwell arm), hydrodynamic drag, baseline tilt, thermal drift, a second
//! eigenmode, piezo creep, plastic deformation, nonlinear stiffness, ...
//!
//! None is implemented here. An effect is a value with its own state implementing [`Effect`];
//! the plant calls its hooks at fixed points of every step (see [`super::Plant::step`]):
//!
//! 1. [`Effect::piezo_z_nm`]: replaces the piezo position U the cantilever base sees this
//!    period (creep, hysteresis, drift of the z axis). The DAC-step impulse `C·ΔU/M` uses the
//!    result, so a smooth creep adds no spurious impulse.
//! 2. [`Effect::tip_force_nn`]: an extra force on the tip, held constant over the period
//!    (evaluated from the state at the period's start, like the DAC holds U). This is first
//!    order in the step: fine for slow forces (drift, a slowly relaxing Maxwell arm); a force
//!    that depends strongly on Z or Ż within one period should be given as a linear term.
//! 3. [`Effect::linear_terms`]: extra stiffness and damping on Z (e.g. hydrodynamic drag
//!    `c_drag·Ż`); they join `K + S_k` and `C + S_c` and so are integrated exactly. They are
//!    read when the effect is added; call [`super::Plant::effects_changed`] if they change.
//! 4. [`Effect::measured_deflection_nm`]: maps the true deflection to what the detector sees
//!    before the ADC (baseline tilt, detector drift, a second eigenmode's optical lever signal).
//! 5. [`Effect::end_of_step`]: advance the effect's own state with the step's end state.
//!
//! Cost on the nominal path: one predictable branch per hook point when no effect is present
//! (`Vec::is_empty`), so effects cost nothing unless used.
//!
//! Units are the plant's internal ones: nm, µs, nN, nN/nm, nN·µs/nm.

/// What an effect sees of the plant at a hook.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EffectContext {
    /// Time at the start of the period (µs).
    pub time_us: f64,
    /// The period (µs).
    pub dt_us: f64,
    /// Tip apex height Z (nm).
    pub z_nm: f64,
    /// Tip velocity Ż (nm/µs).
    pub z_dot_nm_per_us: f64,
    /// Piezo position U after the DAC and travel clamp, before `piezo_z_nm` (nm).
    pub u_nm: f64,
    /// Lateral position (nm).
    pub x_nm: f64,
    pub y_nm: f64,
    /// Sample force on the tip (nN).
    pub contact_force_nn: f64,
    /// Number of engaged elements.
    pub active_elements: usize,
}

/// One extra physics term; every hook defaults to "no effect".
pub trait Effect: Send {
    /// A short name for reports.
    fn name(&self) -> &str;
    /// The piezo position the cantilever base sees this period (nm).
    fn piezo_z_nm(&mut self, _ctx: &EffectContext, u_nm: f64) -> f64 {
        u_nm
    }
    /// An extra force on the tip held over the period (nN, positive up).
    fn tip_force_nn(&mut self, _ctx: &EffectContext) -> f64 {
        0.0
    }
    /// Constant extra stiffness (nN/nm) and damping (nN·µs/nm) acting on Z.
    fn linear_terms(&self) -> (f64, f64) {
        (0.0, 0.0)
    }
    /// The deflection the detector reports, from the true one (nm).
    fn measured_deflection_nm(&mut self, _ctx: &EffectContext, d_nm: f64) -> f64 {
        d_nm
    }
    /// Advance the effect's own state at the end of the period.
    fn end_of_step(&mut self, _ctx: &EffectContext) {}
}
