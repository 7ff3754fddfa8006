//! `visco diagnose`: the physics the nominal model left out, named and modelled (see
//! `visco::diagnose`).

use std::path::PathBuf;

use clap::Args;

use super::CliResult;
use visco::diagnose::{diagnose, Options};
use visco::plant::effects::EffectKind;

#[derive(Debug, Args)]
#[command(after_help = "\
Fits the nominal model (the cantilever and a spherical tip on a Kelvin-Voigt element bed)
to half of a recording (shared/spec/recording.md) driven by its U, and judges it on the
other half. Then it locates the misfit (per phase, against depth, in frequency, over time,
per tap), tries each effect of the vocabulary as an extension of the model, and names the
ones the held-out data support, most important first, with their parameters and the fit
before and after.

Effects: nonlinear-stiffness, adhesion, surface-attraction, stress-relaxation,
hydrodynamic-drag, baseline-tilt, thermal-drift, second-eigenmode, piezo-creep,
plastic-deformation.

Vendor files (JPK, AFM Workshop, NT-MDT, Asylum .ibw, Optics11 Chiaro, afmformats .tab) are converted first with `visco import`.

Writes REPORT.json, and next to it (or in --out DIR) <stem>_series.csv, <stem>_overview.png,
<stem>_effect<i>_<effect>.png per effect found and <stem>_spectrum.png, all or nothing.")]
pub struct DiagnoseArgs {
    /// The recording CSV.
    pub recording: PathBuf,

    /// The JSON report to write.
    #[arg(long, value_name = "REPORT.json")]
    pub json: PathBuf,

    /// Directory for the figures and the series (default: the report's directory).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// Family-wise false-alarm rate of each selection step: on a recording the nominal model
    /// explains, the chance of naming anything.
    #[arg(long, value_name = "P", default_value_t = 0.01, value_parser = parse_alpha)]
    pub alpha: f64,

    /// Name at most this many effects.
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub max_effects: usize,

    /// Only try these effects (comma-separated identifiers).
    #[arg(long, value_name = "LIST", value_delimiter = ',', value_parser = parse_effect)]
    pub effects: Option<Vec<EffectKind>>,

    /// Skip the figures.
    #[arg(long)]
    pub no_figures: bool,

    /// No progress on stderr.
    #[arg(long)]
    pub quiet: bool,
}

fn parse_alpha(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v < 1.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not in (0, 1)")),
        Err(_) => Err(format!("`{s}` is not a number")),
    }
}

fn parse_effect(s: &str) -> Result<EffectKind, String> {
    EffectKind::parse(s).ok_or_else(|| {
        format!(
            "`{s}` is not an effect; one of {}",
            EffectKind::ALL.map(|k| k.as_str()).join(", ")
        )
    })
}

/// Runs the diagnosis.
pub fn run(args: DiagnoseArgs) -> CliResult {
    let mut opts = Options::new(args.json);
    opts.out_dir = args.out;
    opts.alpha = args.alpha;
    opts.max_effects = args.max_effects;
    if let Some(e) = args.effects {
        opts.effects = e;
    }
    opts.figures = !args.no_figures;
    opts.progress = !args.quiet;
    let t = std::time::Instant::now();
    let d = diagnose(&args.recording, &opts)?;
    println!(
        "diagnosed {} in {:.1} s ({} simulations, {} model evaluations)",
        args.recording.display(),
        t.elapsed().as_secs_f64(),
        d.search.simulations,
        d.search.evaluations
    );
    println!("{}", d.summary());
    println!("  -> {}", opts.json.display());
    Ok(())
}
