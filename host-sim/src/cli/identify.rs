//! `visco identify`: a recording in, estimates and the fit out (see `visco::identify`).

use std::path::PathBuf;

use clap::{Args, ValueEnum};

use super::{positive_f64, CliResult};
use visco::identify::{identify, Options, Outcome, DEFAULT_PITCH_M};
use visco_core::DiveRegressor;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RegressorArg {
    /// θ = [c, k, k·(h_bed − z₀)]: the bed's offset under a sphere identified, no correction (32).
    Offset,
    /// The paper's (13), θ = [c, k] with δ from the contact height, then corrected by (32).
    Paper,
}

#[derive(Debug, Args)]
#[command(after_help = "\
Replays a recording (shared/spec/recording.md) through the identification core, open loop:
the recorded U and D in, the estimates out.

  dive         per tap: contact height, aggregate c and k read at the end of the dwell,
               per-element values (k/n, c/n; n from --element-pitch), the tap's misfit
  sve          maps of c, k, h and per-element c, k, forward and backward lines averaged,
               as CSV grids in --out DIR
  force-curve  contact point, the element bed's per-area k_a and c_a (quasi-static sphere
               on a Kelvin-Voigt bed; whether the lever's dynamics may be neglected, judged
               against the noise), aggregate and per element

Every mode simulates its nominal model with the identified values from the recorded U and
writes the RMS misfit against the recorded D, and the series as <stem>_fit.csv.

Errors are one line on stderr, `error: FILE[:LINE]: reason (fix: ...)`, exit status 1;
nothing is written unless everything succeeds.")]
pub struct IdentifyArgs {
    /// The recording CSV.
    pub recording: PathBuf,

    /// The JSON report to write.
    #[arg(long, value_name = "OUT.json")]
    pub json: PathBuf,

    /// Directory for the maps, series and figure (default: the JSON's directory).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// DIVE regressor form.
    #[arg(long, value_enum, default_value = "offset")]
    pub regressor: RegressorArg,

    /// Lateral pitch of the element bed, m, for per-element values (the paper's 100 nm).
    #[arg(long, value_name = "M", value_parser = positive_f64, default_value_t = DEFAULT_PITCH_M)]
    pub element_pitch: f64,

    /// Position of element (0, 0) of the bed's lattice, m, as X,Y: count the elements under
    /// the tip on that lattice instead of the continuum n = pi*a^2/pitch^2.
    #[arg(long, value_name = "X,Y", value_parser = parse_xy)]
    pub lattice_origin: Option<[f64; 2]>,

    /// DIVE read-out window at the end of each dwell, s.
    #[arg(long, value_name = "S", value_parser = positive_f64, default_value_t = 10e-3)]
    pub readout: f64,

    /// SVE pixels per line.
    #[arg(long, value_name = "N", default_value_t = 50)]
    pub pixels: usize,

    /// SVE lines (default: the scan lines found in the recording).
    #[arg(long, value_name = "N")]
    pub lines: Option<usize>,

    /// Force curves: contact threshold, in standard deviations of the free deflection.
    #[arg(long, value_name = "N", value_parser = positive_f64, default_value_t = 5.0)]
    pub contact_sigma: f64,
}

fn parse_xy(s: &str) -> Result<[f64; 2], String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("`{s}` is not X,Y"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("`{v}` is not a finite number"))
    };
    Ok([p(a)?, p(b)?])
}

/// Runs the identification.
pub fn run(args: IdentifyArgs) -> CliResult {
    let opts = Options {
        json: args.json,
        out_dir: args.out,
        regressor: match args.regressor {
            RegressorArg::Offset => DiveRegressor::Offset,
            RegressorArg::Paper => DiveRegressor::Paper,
        },
        element_pitch_m: args.element_pitch,
        lattice_origin_m: args.lattice_origin,
        readout_s: args.readout,
        pixels: args.pixels,
        lines: args.lines,
        contact_sigma: args.contact_sigma,
    };
    let report = identify(&args.recording, &opts)?;
    println!(
        "identified {} ({}): rms misfit {:.4e} m",
        args.recording.display(),
        report.mode,
        report.rms_misfit_m
    );
    match &report.outcome {
        Outcome::ForceCurve(f) => println!(
            "  contact at Z = {:.4e} m (row {}), k_a = {:.4e} N/m^3, c_a = {:.4e} N*s/m^3; \
             at {:.1} nm: k = {:.4e} N/m, c = {:.4e} N*s/m",
            f.contact_height_m,
            f.contact_row + 1,
            f.k_a_n_per_m3,
            f.c_a_ns_per_m3,
            f.max_depth_m * 1e9,
            f.k_n_per_m,
            f.c_ns_per_m
        ),
        Outcome::Dive(d) => {
            for t in &d.taps {
                println!("  {}", t.summary());
            }
        }
        Outcome::Sve(s) => println!("  {}", s.summary()),
    }
    for f in &report.files {
        println!("  -> {}", f.display());
    }
    Ok(())
}
