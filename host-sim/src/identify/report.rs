//! The identify report (`visco identify RECORDING --json OUT.json`) as typed structs: the
//! common head, then the mode's part (force curve, DIVE, SVE), then the files written.
//!
//! Field names carry their unit suffix (`units` says what each suffix means); a computed value
//! that could not be computed is `null` ([`Num`]). Rows are 1-based data rows, `[first, last]`.

use serde::{Deserialize, Serialize};

use schemars::JsonSchema;

use crate::recording::Metadata;
use crate::report::{Num, Ordered};

/// The identify report's `schema_version`.
pub const SCHEMA_VERSION: u32 = 1;

/// The whole report.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct IdentifyReport {
    /// Version of this report's layout (1): raised when a field is removed or renamed or changes
    /// meaning or unit; adding a field keeps it.
    pub schema_version: u32,
    /// The recording's path, as given.
    pub recording: String,
    /// The version of visco that wrote the report.
    pub visco_version: String,
    /// What the unit suffixes of the keys mean.
    pub units: Units,
    /// The recording's mode (`mode`) and what it gives.
    #[serde(flatten)]
    pub result: ModeReport,
    /// Every file written, the report last.
    pub files: Vec<String>,
}

/// The mode-specific part, tagged by the recording's `mode`.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "mode")]
pub enum ModeReport {
    /// A quasi-static force curve.
    #[serde(rename = "force-curve")]
    ForceCurve(Box<ForceCurveReport>),
    /// DIVE: taps at fixed X, Y.
    #[serde(rename = "dive")]
    Dive(Box<DiveReport>),
    /// SVE: a scan at depth.
    #[serde(rename = "sve")]
    Sve(Box<SveReport>),
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
    #[serde(rename = "_n_per_m")]
    pub n_per_m: String,
    #[serde(rename = "_ns_per_m")]
    pub ns_per_m: String,
    #[serde(rename = "_n_per_m3")]
    pub n_per_m3: String,
    #[serde(rename = "_ns_per_m3")]
    pub ns_per_m3: String,
    #[serde(rename = "_kg")]
    pub kg: String,
    pub rows: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            m: "metres".into(),
            s: "seconds".into(),
            hz: "hertz".into(),
            n: "newtons".into(),
            n_per_m: "N/m".into(),
            ns_per_m: "N·s/m".into(),
            n_per_m3: "N/m³: per-area spring of the element bed (k_element/pitch²)".into(),
            ns_per_m3: "N·s/m³: per-area damper of the element bed (c_element/pitch²)".into(),
            kg: "kilograms".into(),
            rows: "1-based data rows of the recording (line numbers minus the header)".into(),
        }
    }
}

/// The cantilever as the recording gives it.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct CantileverJson {
    pub k_n_per_m: f64,
    pub c_ns_per_m: Option<f64>,
    pub m_kg: Option<f64>,
    pub f0_hz: Option<f64>,
    pub q: Option<f64>,
    /// Where the dynamics used came from (DIVE and SVE).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub used_from: Option<String>,
}

impl CantileverJson {
    /// From the recording's metadata.
    pub fn new(meta: &Metadata) -> Self {
        CantileverJson {
            k_n_per_m: meta.cantilever_k_n_per_m,
            c_ns_per_m: meta.cantilever_c_ns_per_m,
            m_kg: meta.cantilever_m_kg,
            f0_hz: meta.cantilever_f0_hz,
            q: meta.cantilever_q,
            used_from: None,
        }
    }

    /// With the source of the dynamics used.
    pub fn used_from(mut self, source: impl Into<String>) -> Self {
        self.used_from = Some(source.into());
        self
    }
}

/// Rows as `[first, last]`, 1-based, from 0-based `start..end`.
pub fn rows(start: u64, end: u64) -> [u64; 2] {
    [start + 1, end]
}

// ---- force curve -------------------------------------------------------------------------

/// A force curve's report part.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ForceCurveReport {
    pub model: String,
    pub cantilever_dynamics: CantileverDynamics,
    pub approach: RowSpan,
    pub baseline: Baseline,
    pub contact: ForceCurveContact,
    pub k_a_n_per_m3: Num,
    pub fit_rows: String,
    pub approach_force_depth_exponent: Num,
    pub c_a_ns_per_m3: Num,
    pub relaxation_time_s: Num,
    pub max_depth_m: Num,
    pub max_force_n: Num,
    pub force_range_n: Num,
    pub element_pitch_m: f64,
    pub filter_lambda_s: f64,
    /// The vendor's force column compared with −K·(D − D₀), when the recording has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vendor_force: Option<VendorForce>,
    pub cantilever: CantileverJson,
    pub tip_radius_m: f64,
    /// The one "tap": the values at the deepest point.
    pub taps: Vec<ForceCurveTap>,
    pub rms_misfit_m: Num,
    pub fit: ForceCurveFitJson,
    pub notes: Vec<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct CantileverDynamics {
    pub neglected: bool,
    pub why: String,
    pub to_noise: Num,
    pub to_force_range: Num,
    pub inertial_force_max_n: Num,
    pub damping_force_max_n: Num,
    pub f0_hz: Num,
    pub q: Num,
    pub f0_q_source: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct RowSpan {
    pub rows: [u64; 2],
    pub t_start_s: f64,
    pub t_end_s: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Baseline {
    pub kind: String,
    pub offset_m: Num,
    pub tilt_m_per_m: Num,
    pub u_ref_m: Num,
    pub noise_m: Num,
    pub free_rows: [u64; 2],
    /// The optical-interference wave in U, `amplitude·sin(2π(U − u_ref)/period + phase)`, when
    /// the free approach shows one (null otherwise).
    pub wave: Option<BaselineWave>,
}

/// An interference wave of the free deflection (identify/baseline.rs says when one is kept).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct BaselineWave {
    /// The wave is `amplitude·sin(2π(U − u_ref)/period + phase)`.
    pub u_ref_m: Num,
    pub amplitude_m: Num,
    pub period_m: Num,
    pub phase_rad: Num,
    /// The sum-of-squares drop over the periodogram's false-alarm level (α = 10⁻³): > 1.
    pub significance: Num,
    /// Amplitudes fitted on each half of the free part at the same period (stationarity).
    pub halves_amplitude_m: [Num; 2],
}

impl BaselineWave {
    /// The report of a baseline's wave (`None` without one).
    pub fn of(b: &crate::identify::baseline::Baseline) -> Option<BaselineWave> {
        b.wave.as_ref().map(|w| BaselineWave {
            u_ref_m: b.u_ref_m.into(),
            amplitude_m: w.amplitude_m.into(),
            period_m: w.period_m.into(),
            phase_rad: w.phase_rad.into(),
            significance: w.significance.into(),
            halves_amplitude_m: [w.halves_m[0].into(), w.halves_m[1].into()],
        })
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ForceCurveContact {
    pub height_m: Num,
    pub row: u64,
    pub t_s: Num,
    pub u_m: Num,
    pub threshold_row: u64,
    pub method: String,
    pub inside_approach: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct VendorForce {
    pub column: String,
    pub max_abs_difference_n: Num,
    pub max_abs_vendor_n: Num,
    pub matches: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ForceCurveTap {
    pub contact_height_m: Num,
    pub c_ns_per_m: Num,
    pub k_n_per_m: Num,
    pub depth_m: Num,
    pub elements_under_tip: Num,
    pub c_element_ns_per_m: Num,
    pub k_element_n_per_m: Num,
    pub note: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ForceCurveFitJson {
    pub model: String,
    pub rms_misfit_m: Num,
    pub rms_misfit_contact_m: Num,
    pub rms_misfit_over_noise: Num,
    pub deflection_range_m: Num,
    pub segments: Vec<SegmentFit>,
    pub series_csv: String,
    pub figure_png: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SegmentFit {
    /// The recording's segment number.
    pub segment: i64,
    pub kind: String,
    pub rows: u64,
    pub rms_misfit_m: Num,
}

// ---- DIVE ------------------------------------------------------------------------------------

/// A DIVE recording's report part.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiveReport {
    pub model: String,
    pub cantilever: CantileverJson,
    pub tip_radius_m: f64,
    pub sample_rate_hz: f64,
    pub regressor: String,
    pub segmentation: String,
    pub per_element: DivePerElement,
    pub replay: DiveReplay,
    pub taps: Vec<DiveTapJson>,
    pub summary: DiveSummary,
    /// Present (not null) when rows sit at exactly the extreme deflection.
    pub deflection_clipped: Option<Clipped>,
    pub notes: Vec<String>,
    pub rms_misfit_m: Num,
    pub fit: DiveFit,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DivePerElement {
    pub element_pitch_m: f64,
    pub count: String,
    pub lattice_origin_m: Option<[f64; 2]>,
    pub how: String,
}

/// What the observer replay ran with.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Observer {
    pub prefilter_lambda_s: f64,
    pub estimator: EstimatorJson,
    pub contact_detector: ContactDetectorJson,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct EstimatorJson {
    pub law: String,
    pub memory_s: f64,
    pub alpha: f64,
    pub p0: [f64; 3],
    pub r0: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct ContactDetectorJson {
    pub lowpass_hz: f64,
    pub gamma_m: f64,
    pub gamma_plus_m: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiveReplay {
    #[serde(flatten)]
    pub observer: Observer,
    pub readout_s: f64,
    pub dwell: String,
}

/// One DIVE tap; the contact's values only when it touched (`contact`), and then the
/// estimates null-free unless not computable.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiveTapJson {
    pub index: u64,
    /// The `tap` column's value, if the recording has one.
    pub tap: Option<u32>,
    pub rows: [u64; 2],
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub x_m: Num,
    pub y_m: Num,
    pub contact: bool,
    /// null without contact.
    pub contact_height_m: Num,
    /// null without contact.
    pub c_ns_per_m: Num,
    /// null without contact.
    pub k_n_per_m: Num,
    /// The rest of the values at contact (absent without contact).
    #[serde(flatten)]
    pub at_contact: Option<DiveTapContact>,
    pub rms_misfit_m: Num,
    pub rms_misfit_dwell_m: Num,
    pub flags: Vec<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiveTapContact {
    pub contact_t_s: f64,
    pub offset_n: Num,
    pub bed_height_m: Num,
    pub surface_height_m: Num,
    pub depth_m: Num,
    pub depth_range_m: [Num; 2],
    pub elements_under_tip: Num,
    pub mean_sag_m: Num,
    pub c_element_ns_per_m: Num,
    pub k_element_n_per_m: Num,
    pub free_deflection_m: Num,
    /// The estimation window, when one was found.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dwell: Option<Dwell>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Dwell {
    pub rows: [u64; 2],
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub hold_z_m: Num,
    pub readout_t_start_s: f64,
    pub readout_samples: u64,
}

/// Mean, standard deviation and range over the taps with estimates (null when none).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Stat {
    pub mean: Num,
    pub std: Num,
    pub min: Num,
    pub max: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiveSummary {
    pub taps: u64,
    pub with_estimates: u64,
    pub k_n_per_m: Stat,
    pub c_ns_per_m: Stat,
    pub k_element_n_per_m: Stat,
    pub c_element_ns_per_m: Stat,
    pub contact_height_m: Stat,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Clipped {
    pub low_m: f64,
    pub rows_at_low: u64,
    pub high_m: f64,
    pub rows_at_high: u64,
    pub note: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct DiveFit {
    pub model: String,
    pub rms_misfit_m: Num,
    pub series_csv: String,
    pub series_stride_rows: u64,
    pub detail_csv: Option<String>,
    pub figure_png: String,
    pub detail_png: Option<String>,
}

// ---- SVE -------------------------------------------------------------------------------------

/// An SVE recording's report part.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SveReport {
    pub model: String,
    pub cantilever: CantileverJson,
    pub tip_radius_m: f64,
    pub sample_rate_hz: f64,
    pub regressor: String,
    pub contact: SveContact,
    pub scan: Scan,
    pub grid: Grid,
    pub per_element: SvePerElement,
    pub replay: SveReplay,
    /// One entry per map, keyed by the quantity (`k_n_per_m`, …), in the order written.
    pub maps: Ordered<MapJson>,
    pub notes: Vec<String>,
    /// Always empty: a scan has no taps (the key is kept for scripts that read taps).
    pub taps: Vec<serde_json::Value>,
    pub rms_misfit_m: Num,
    pub fit: SveFit,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SveContact {
    pub row: u64,
    pub t_s: f64,
    pub height_m: Num,
    pub free_deflection_m: Num,
    pub released_row: Option<u64>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Scan {
    pub passes: u64,
    pub forward: u64,
    pub backward: u64,
    pub x_range_m: [Num; 2],
    pub y_range_m: [Num; 2],
    pub lines_from: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct Grid {
    pub pixels: u64,
    pub lines: u64,
    pub x_m: Vec<Num>,
    pub y_m: Vec<Num>,
    pub empty_pixels: u64,
    pub lines_equally_spaced: bool,
    pub layout: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SvePerElement {
    pub element_pitch_m: f64,
    pub count: String,
    pub spring: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SveReplay {
    #[serde(flatten)]
    pub observer: Observer,
    pub sve_highpass_hz: f64,
    pub converge_s: f64,
}

/// One map's files and statistics (nan pixels left out).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct MapJson {
    pub file: String,
    pub gsf: String,
    pub png: String,
    pub unit: String,
    pub valid_pixels: u64,
    pub mean: Num,
    pub std: Num,
    pub min: Num,
    pub max: Num,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SveFit {
    pub model: String,
    pub rms_misfit_m: Num,
    pub rms_misfit_scan_m: Num,
    pub series_csv: String,
    pub series_stride_rows: u64,
    pub detail_csv: String,
    pub figure_png: String,
    pub detail_png: String,
}
