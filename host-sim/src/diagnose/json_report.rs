//! The diagnosis report (`visco diagnose RECORDING --json REPORT.json`) as typed structs: the
//! contract's required fields (`../shared/spec/recording.md` §2: `recording`,
//! `nominal_model`, `rms_before_m`, `rms_after_m`, `left_out`) and the rest of what the
//! analysis did. A value that could not be computed is `null` ([`Num`]).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::report::{Num, Ordered};

/// The diagnosis report's `schema_version`.
pub const SCHEMA_VERSION: u32 = 1;

/// The whole report.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiagnoseReport {
    /// Version of this report's layout (1): raised when a field is removed or renamed or changes
    /// meaning or unit; adding a field keeps it.
    pub schema_version: u32,
    /// The recording's path, as given.
    pub recording: String,
    pub nominal_model: String,
    /// Held-out RMS of recorded − simulated D with the nominal model (m).
    pub rms_before_m: Num,
    /// Held-out RMS of recorded − simulated D with the extended model (m).
    pub rms_after_m: Num,
    /// Held-out RMS of recorded − simulated D with the extended model over the same where the
    /// tip is far out of contact (the farther half of the free held-out samples): about one, or
    /// less (contact stiffens the lever against its thermal noise), where the model fits the
    /// contact as well as the free lever; null where too few samples are far out of contact to
    /// tell.
    pub contact_misfit: Num,
    /// Held-out RMS of recorded − simulated D with the extended model over the noise: the
    /// sample-to-sample scatter (robust σ of the first difference over √2) and, for a dynamic
    /// model, the free lever's thermal noise √(k_B·T/K) at 300 K (which the scatter of a
    /// resonant lever's samples does not see), in quadrature. About one, or less, for a model
    /// that leaves only noise.
    pub misfit_over_noise: Num,
    /// The outcome in words: the effects left out, and "explains … to within its noise" only
    /// where `misfit_over_noise` ≤ 1.5; above, whether the misfit sits where the tip touches
    /// (`contact_misfit` > 1.5) or everywhere.
    pub verdict: String,
    /// The effects found, most important first; empty when the nominal model explains the
    /// recording to within its noise.
    pub left_out: Vec<LeftOut>,
    pub visco_version: String,
    pub mode: String,
    pub nominal: Nominal,
    pub held_out: HeldOutJson,
    pub selection: Selection,
    pub locate: LocateJson,
    /// The longest hold in contact, read for who moved: the sample or the scanner (null
    /// without a hold).
    pub hold: Option<HoldJson>,
    pub units: Units,
    /// The per-sample series written beside the report (absent when only analysed, as the
    /// Python `diagnose` does).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub series_csv: Option<String>,
    /// The figures written beside the report (absent when only analysed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub figures: Option<Vec<String>>,
}

/// A hold in contact and what it shows (diagnose/locate.rs `hold_reading`).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct HoldJson {
    /// First and last sample (1-based, inclusive).
    pub rows: [u64; 2],
    /// "constant force", "constant height" or "neither".
    pub kind: String,
    /// How far the base moved towards the sample over the hold (m; negative: away).
    pub base_towards_sample_m: Num,
    /// Change of the contact force over the hold (N).
    pub force_change_n: Num,
    pub reading: String,
}

/// One effect left out of the nominal model.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct LeftOut {
    /// The effect's identifier (`adhesion`, `stress-relaxation`, …).
    pub effect: String,
    pub explanation: String,
    /// The time spans where the mismatch sits.
    #[serde(rename = "where")]
    pub where_: Vec<SpanJson>,
    /// The effect's fitted parameters, names with their unit suffix.
    pub parameters: Ordered<Num>,
    pub rms_before_m: Num,
    pub rms_after_m: Num,
    pub phases: Vec<PhaseRms>,
    pub evidence: Evidence,
}

/// A time span where something sits.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SpanJson {
    pub t_start_s: f64,
    pub t_end_s: f64,
    /// `approach`, `contact`, `dwell`, `retract`, `free` or `scan`.
    pub phase: String,
    pub rows: [u64; 2],
    /// Share of the contribution's energy in the span.
    pub share: Num,
    /// Lateral position, when the recording has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y_m: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct PhaseRms {
    pub phase: String,
    pub rms_before_m: Num,
    pub rms_after_m: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Evidence {
    pub statistic: String,
    pub value: Num,
    pub z: Num,
    pub p_value: Num,
    pub level: Num,
    pub held_out_samples: u64,
    pub peak_contribution_m: Num,
    pub noise_rms_m: Num,
    pub physics: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Nominal {
    pub model: String,
    pub dynamics: String,
    pub input_between_samples: String,
    /// The bed the nominal model used (continuum, or a lattice with its pitch and offset) and why.
    pub bed: String,
    /// Fitted initial state (null for quasi-static recordings).
    pub initial_state: Option<InitialState>,
    /// The header's f0 and Q as calibrated (null for quasi-static recordings).
    pub calibration: Option<Calibration>,
    pub offset_m: Num,
    /// A force curve's optical-interference wave in U, found on the free approach as
    /// `identify` finds it and part of the nominal's baseline (null when there is none).
    pub baseline_wave: Option<crate::identify::report::BaselineWave>,
    pub contacts: Vec<ContactJson>,
    pub noise: NoiseJson,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct InitialState {
    pub model: String,
    pub z0_m: Num,
    pub v0_m_per_s: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Calibration {
    pub model: String,
    pub f0_correction: Num,
    pub q_correction: Num,
    pub f0_hz: Num,
    pub q: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ContactJson {
    pub unit: u64,
    pub rows: [u64; 2],
    pub in_contact: bool,
    pub contact_height_m: Num,
    pub k_a_n_per_m3: Num,
    pub c_a_ns_per_m3: Num,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y_m: Option<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct NoiseJson {
    pub model: String,
    pub order: u64,
    pub innovation_sigma_m: Num,
    pub residual_sigma_m: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct HeldOutJson {
    pub scheme: String,
    pub samples_per_block: u64,
    pub held_out_samples: u64,
    pub fit_samples: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Selection {
    pub method: String,
    pub family_alpha: f64,
    pub correction: String,
    pub detection_floor: String,
    pub simulations: u64,
    pub stages: Vec<Stage>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Stage {
    pub stage: u64,
    pub level: Num,
    pub candidates: Vec<Candidate>,
    /// The candidates left untested by the screen (first stage only): the stage fits in full
    /// the few whose linearised fit is best, and the others only where a brief polish
    /// already fits better than the best of those that passes its test (where none passes,
    /// the best of them).
    #[serde(default)]
    pub screened_out: Vec<ScreenedOut>,
}

/// A candidate the stage's linearised screen left out.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ScreenedOut {
    pub effect: String,
    /// Its linearised fit's gain in SSR on the fit samples, as a fraction of the stage
    /// model's SSR there (null where the linearised fit failed).
    pub linear_ssr_gain: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Candidate {
    pub effect: String,
    pub z: Num,
    pub p_value: Num,
    pub held_out_loglik_gain: Num,
    /// The held-out log-likelihood gain on the stage's common noise model, on which the
    /// stage ranks its candidates (with the test's own noise model in
    /// `held_out_loglik_gain`); the held-out loss gain (nm²) where misfit dominates.
    pub ranking_gain: Num,
    pub peak_contribution_m: Num,
    pub noise_rms_m: Num,
    pub passed_test: bool,
    pub passed_floor: bool,
    pub amplitude_at_limit: bool,
    pub rms_where_before_m: Num,
    pub rms_where_after_m: Num,
    pub chosen: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct LocateJson {
    pub correction: String,
    pub tones_hz: Vec<Num>,
    pub phases: Vec<PhaseSamples>,
    pub tests: Vec<TestJson>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct PhaseSamples {
    pub phase: String,
    pub held_out_samples: u64,
    pub rms_before_m: Num,
    pub rms_after_m: Num,
}

/// One test of the locate step.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct TestJson {
    pub group: String,
    pub test: String,
    pub statistic: String,
    pub value: Num,
    pub p_value: Num,
    /// Holm-adjusted p-value.
    pub p_adjusted: Num,
    pub significant: bool,
    /// The misfit the test attributes on the whitened residual, over the noise model's
    /// innovation σ (a signal-to-noise ratio): an offset's |mean|, a line's RMS, the excess
    /// variance's √(χ²/n − 1), for the correlation tests the explained part's RMS over the
    /// rest's.
    pub size_over_noise: Num,
    /// Significant, and `size_over_noise` at least 0.5: a misfit that matters.
    pub material: bool,
    pub detail: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub t_start_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub t_end_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_hz: Option<f64>,
}

/// The unit suffixes of the report's keys.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Units {
    #[serde(rename = "_m")]
    pub m: String,
    #[serde(rename = "_s")]
    pub s: String,
    #[serde(rename = "_hz")]
    pub hz: String,
    #[serde(rename = "_n")]
    pub n: String,
    #[serde(rename = "_ns_per_m")]
    pub ns_per_m: String,
    #[serde(rename = "_n_per_m3")]
    pub n_per_m3: String,
    #[serde(rename = "_ns_per_m3")]
    pub ns_per_m3: String,
    pub rows: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            m: "metres".into(),
            s: "seconds".into(),
            hz: "hertz".into(),
            n: "newtons".into(),
            ns_per_m: "N·s/m".into(),
            n_per_m3: "N/m³ (per-area spring of the bed)".into(),
            ns_per_m3: "N·s/m³ (per-area damper of the bed)".into(),
            rows: "1-based data rows, first and last".into(),
        }
    }
}
