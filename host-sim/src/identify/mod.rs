//! `visco identify`: a recording in, the sample's viscoelastic parameters and the fit out.
//!
//! The host side of HIL-style replay: open loop, the recorded U and D go through the same core
//! building blocks the firmware runs ([`visco_core::observer::Observer`]: prefilters,
//! regressors, contact detector, least squares with forgetting, the SVE high-pass), and the
//! estimates are read out as the controller reads them. What the recording does not say (when
//! a tap dwells, where a scan line runs) is found in the data.
//!
//! | mode | what is identified | module |
//! | --- | --- | --- |
//! | `dive` | per tap: contact height, aggregate c and k (offset or paper regressor), per element (30)–(32) | [`dive`] |
//! | `sve` | maps of c, k, h (and per element), forward and backward lines averaged | [`sve`] |
//! | `force-curve` | contact point, per-area k_a and c_a of the element bed (quasi-static), aggregate and per element | [`force_curve`] |
//!
//! Every mode also simulates its nominal model with the identified values, driven by the
//! recorded U, and reports the RMS misfit against the recorded D (`rms_misfit_m`) with the
//! series (and a figure when the figure module is available).
//!
//! Outputs: `OUT.json`, and next to it (or in `--out DIR`) the fit's series `<stem>_fit.csv`
//! and figure `<stem>_fit.png` (DIVE and SVE also a full-rate detail, `<stem>_fit_detail.*`),
//! and for SVE the maps `<stem>_<quantity>.csv` / `.gsf` / `.png`, where `<stem>` is the JSON
//! file's stem. All are written atomically as a group: on any error nothing is left behind.
//!
//! Large `dive`/`sve` logs are streamed with [`crate::recording::RecordingReader`] in three
//! passes (survey, estimation, fit) in memory bounded by the number of taps, lines and pixels;
//! force curves are small and read whole.

/// The default contact threshold in noise σ (`--contact-sigma`).
pub const CONTACT_SIGMA: f64 = 5.0;

pub mod baseline;
pub mod dive;
pub mod error;
pub mod figures;
pub mod files;
pub mod force_curve;
pub mod replay;
pub mod report;
pub mod signal;
pub mod sve;

use std::path::{Path, PathBuf};

pub use error::{IdentifyError, Result};
pub use report::{IdentifyReport, ModeReport};

use crate::recording::{Metadata, Mode, Recording, RecordingReader};
use files::Staged;
use visco_core::DiveRegressor;

/// What the command line (or a caller) chooses.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The JSON report to write.
    pub json: PathBuf,
    /// Directory for the other outputs (maps, series, figure); default the JSON's directory.
    pub out_dir: Option<PathBuf>,
    /// DIVE regressor form (default the offset form, as the controller).
    pub regressor: DiveRegressor,
    /// Lateral pitch of the element bed for per-element values (m).
    pub element_pitch_m: f64,
    /// Position of element (0, 0) of the lattice, for exact element counts (m); `None` counts
    /// in the continuum limit n = π a²/pitch².
    pub lattice_origin_m: Option<[f64; 2]>,
    /// DIVE read-out window at the end of each dwell (s).
    pub readout_s: f64,
    /// SVE pixels per line.
    pub pixels: usize,
    /// SVE lines; `None` takes the scan lines found in the recording.
    pub lines: Option<usize>,
    /// Force curves: contact threshold in σ of the free deflection.
    pub contact_sigma: f64,
}

impl Options {
    /// Defaults, writing the report to `json`.
    pub fn new(json: impl Into<PathBuf>) -> Self {
        Options {
            json: json.into(),
            out_dir: None,
            regressor: DiveRegressor::Offset,
            element_pitch_m: DEFAULT_PITCH_M,
            lattice_origin_m: None,
            readout_s: 10e-3,
            pixels: 50,
            lines: None,
            contact_sigma: CONTACT_SIGMA,
        }
    }

    fn check(&self) -> Result<()> {
        let bad = |what: &str| Err(IdentifyError::new(&self.json, what.to_string()));
        if !(self.element_pitch_m.is_finite() && self.element_pitch_m > 0.0) {
            return bad("--element-pitch must be a finite positive length");
        }
        if !(self.readout_s.is_finite() && self.readout_s > 0.0) {
            return bad("--readout must be a finite positive time");
        }
        if self.pixels == 0 || self.pixels > 100_000 {
            return bad("--pixels must be 1 to 100000");
        }
        if matches!(self.lines, Some(0)) || self.lines.is_some_and(|l| l > 100_000) {
            return bad("--lines must be 1 to 100000");
        }
        if !(self.contact_sigma.is_finite() && self.contact_sigma > 0.0) {
            return bad("--contact-sigma must be a finite positive number");
        }
        if let Some(o) = self.lattice_origin_m {
            if !(o[0].is_finite() && o[1].is_finite()) {
                return bad("--lattice-origin must be finite");
            }
        }
        Ok(())
    }
}

/// Force curves are read into memory; larger files are refused (≈ 10 M rows).
const FORCE_CURVE_MAX_BYTES: u64 = 1 << 30;

/// The default element pitch: the paper's lattice (50 × 50 elements over 5 µm).
pub const DEFAULT_PITCH_M: f64 = 100e-9;

/// What one mode found, typed (the JSON holds the same and more).
#[derive(Debug, Clone)]
pub enum Outcome {
    /// A force curve.
    ForceCurve(Box<force_curve::ForceCurveFit>),
    /// DIVE taps.
    Dive(dive::DiveResult),
    /// An SVE scan.
    Sve(sve::SveResult),
}

/// The result of [`identify`].
#[derive(Debug, Clone)]
pub struct Report {
    /// The recording's mode.
    pub mode: Mode,
    /// The report written (as JSON: [`crate::report::to_pretty`]).
    pub json: IdentifyReport,
    /// Every file written, the JSON last.
    pub files: Vec<PathBuf>,
    /// RMS of recorded − simulated D over the whole recording (m).
    pub rms_misfit_m: f64,
    /// The typed result.
    pub outcome: Outcome,
}

/// Where the outputs go and what they are called.
pub(crate) struct Outputs {
    pub dir: PathBuf,
    pub stem: String,
}

impl Outputs {
    pub fn path(&self, suffix: &str) -> PathBuf {
        self.dir.join(format!("{}_{suffix}", self.stem))
    }
}

/// Identifies the recording at `path` and writes the outputs (all or nothing).
pub fn identify(path: &Path, opts: &Options) -> Result<Report> {
    opts.check()?;
    let header = RecordingReader::open(path)?.header().clone();
    // `--out DIR` is created when missing, and removed again if nothing could be written.
    let (dir, stem) = files::plan_outputs(&opts.json, opts.out_dir.as_deref(), path)?;
    let created = files::create_missing_dir(&dir)?;
    let result = run(
        path,
        &header.meta,
        opts,
        Outputs {
            dir: dir.clone(),
            stem,
        },
    );
    if result.is_err() && created {
        let _ = std::fs::remove_dir(&dir);
    }
    result
}

fn run(path: &Path, meta: &Metadata, opts: &Options, out: Outputs) -> Result<Report> {
    let mut staged = Staged::new();
    let (result, rms, outcome) = match meta.mode {
        Mode::ForceCurve => {
            // Force curves are read whole (they are small: thousands to tens of thousands of
            // rows); a file this large is a log, not a force curve.
            let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
            if bytes > FORCE_CURVE_MAX_BYTES {
                return Err(IdentifyError::new(
                    path,
                    format!(
                        "a force curve of {} MB is read whole, which this one is too large for \
                         (limit {} MB)",
                        bytes >> 20,
                        FORCE_CURVE_MAX_BYTES >> 20
                    ),
                ));
            }
            let rec = Recording::read(path)?;
            let fit = force_curve::identify(&rec, path, opts)?;
            let series = out.path("fit.csv");
            staged.write(&series, &fit.series_csv(&rec))?;
            let png = out.path("fit.png");
            let mut env = figures::Envelope::with_max_points(rec.len() as u64, 50_000);
            for i in 0..rec.len() {
                env.push(rec.t_s[i], rec.d_m[i], fit.simulated_d_m[i]);
            }
            figures::stage_overview(
                &mut staged,
                &png,
                &format!(
                    "{}: force curve, quasi-static sphere on a Kelvin–Voigt bed",
                    path.file_name()
                        .map_or(String::new(), |n| n.to_string_lossy().into_owned())
                ),
                &env,
            )?;
            let mut j = fit.to_report(&rec, meta);
            j.fit.series_csv = series.display().to_string();
            j.fit.figure_png = png.display().to_string();
            let mut notes = fit.notes.clone();
            let d = &fit.dynamics;
            notes.insert(
                0,
                if d.neglected {
                    format!(
                        "cantilever dynamics neglected: the curve is quasi-static, the lever's \
                         dynamic force bends it by {:.2}× the deflection noise (see \
                         cantilever_dynamics)",
                        d.to_noise
                    )
                } else {
                    format!(
                        "cantilever dynamics NOT negligible: the lever's dynamic force bends it \
                         by up to {:.2}× the deflection noise, which the quasi-static fit leaves \
                         out (see cantilever_dynamics; f0 and Q {})",
                        d.to_noise, d.source
                    )
                },
            );
            j.notes = notes;
            let rms = fit.rms_misfit_m;
            (
                ModeReport::ForceCurve(Box::new(j)),
                rms,
                Outcome::ForceCurve(Box::new(fit)),
            )
        }
        Mode::Dive => {
            let r = dive::identify(path, opts, &out, &mut staged)?;
            let j = r.json.clone();
            let rms = r.rms_misfit_m;
            (ModeReport::Dive(Box::new(j)), rms, Outcome::Dive(r))
        }
        Mode::Sve => {
            let r = sve::identify(path, opts, &out, &mut staged)?;
            let j = r.json.clone();
            let rms = r.rms_misfit_m;
            (ModeReport::Sve(Box::new(j)), rms, Outcome::Sve(r))
        }
    };
    let mut files: Vec<String> = staged
        .paths()
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    files.push(opts.json.display().to_string());
    let json = IdentifyReport {
        schema_version: report::SCHEMA_VERSION,
        recording: path.display().to_string(),
        visco_version: env!("CARGO_PKG_VERSION").to_string(),
        units: report::Units::default(),
        result,
        files,
    };
    staged.write(&opts.json, &crate::report::to_pretty(&json))?;
    let files = staged.commit()?;
    Ok(Report {
        mode: meta.mode,
        json,
        files,
        rms_misfit_m: rms,
        outcome,
    })
}
