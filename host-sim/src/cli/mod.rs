//! Command-line front end: one module per subcommand.
//!
//! To add a subcommand `foo`: write `src/cli/foo.rs` with a `#[derive(clap::Args)] pub struct
//! FooArgs` and a `pub fn run(args: FooArgs) -> CliResult`, then add `mod foo;` and one
//! variant `Foo(foo::FooArgs)` to [`Command`] (and its arm in [`run`]). Errors are printed as a
//! single line `error: ...` on stderr with a non-zero exit status; library errors such as
//! `RecordingError` already read `FILE:LINE: reason (fix: ...)`.

mod concealed;
mod demo;
mod diagnose;
mod faults;
mod identify;
mod import;
mod replay;
mod schema;
mod sweep;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// What a subcommand returns: any error, displayed on one line.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;

/// visco: identify viscoelastic properties of living cells with an AFM.
#[derive(Debug, Parser)]
#[command(name = "visco", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// The paper's simulation study (DIVE and SVE on the embedded cell) with maps and a report.
    Demo(demo::DemoArgs),
    /// Imaging speed against accuracy (SVE line period, DIVE tap time) and the excitation study.
    Sweep(sweep::SweepArgs),
    /// Fault injection on the simulated instrument: boundedness, tip force, flags, recovery.
    Faults(faults::FaultsArgs),
    /// Convert a vendor force-curve file (JPK, AFM Workshop, NT-MDT, Asylum .ibw, Optics11 Chiaro, afmformats .tab) into recording CSVs.
    Import(import::ImportArgs),
    /// Identify a recording's viscoelastic parameters (dive, sve, force-curve) and its fit.
    Identify(identify::IdentifyArgs),
    /// The concealed-effect suite: every effect at 3–10× the noise, diagnosed; the confusion
    /// matrix.
    Concealed(concealed::ConcealedArgs),
    /// Find the physics the nominal model left out of a recording, model it, show the fit
    /// improve.
    Diagnose(diagnose::DiagnoseArgs),
    /// Replay a recording's deflection through the firmware under QEMU, bit for bit against
    /// the host build of the core.
    Replay(replay::ReplayArgs),
    /// The JSON Schema of a report the tools write (identify, diagnose, concealed, demo,
    /// sweep, faults).
    Schema(schema::SchemaArgs),
}

/// Parses the command line, runs the subcommand, reports errors. Exit status: 0 success,
/// 1 the command failed, 2 bad usage (from clap).
pub fn run() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo(args) => demo::run(args),
        Command::Faults(args) => faults::run(args),
        Command::Import(args) => import::run(args),
        Command::Identify(args) => identify::run(args),
        Command::Diagnose(args) => diagnose::run(args),
        Command::Concealed(args) => concealed::run(args),
        Command::Sweep(args) => sweep::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Schema(args) => schema::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Value parser for flags that must be finite and positive (rates, radii, constants).
pub fn positive_f64(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not a finite positive number")),
        Err(_) => Err(format!("`{s}` is not a number")),
    }
}
