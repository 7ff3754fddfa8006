//! `visco demo`: the paper's simulation study on the embedded cell, with the core in the loop.

use super::{positive_f64, CliResult};
use std::path::PathBuf;
use visco::experiment::demo::{self, DemoOptions};

/// Run DIVE (20 × 20 taps, 0.2 s each) and SVE (20 lines, 2 s each) on the embedded cell
/// phantom and write maps (PNG, Gwyddion .gsf, CSV), Figs. 8–9 and report.json.
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Output directory.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Loop rate of the core (Hz).
    #[arg(long, default_value_t = 500e3, value_parser = positive_f64)]
    rate: f64,
    /// Noise seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// A sample file instead of the embedded phantom (element CSV or .sample manifest; see
    /// `visco::sample::io`).
    #[arg(long)]
    sample: Option<PathBuf>,
    /// A reduced run: 5 × 5 taps of 0.1 s and 5 lines of 1 s.
    #[arg(long)]
    quick: bool,
    /// No progress output.
    #[arg(long)]
    quiet: bool,
}

pub fn run(args: DemoArgs) -> CliResult {
    let opts = DemoOptions {
        out: args.out.clone(),
        sample_rate_hz: args.rate,
        seed: args.seed,
        sample: args.sample,
        reduced: args.quick,
        progress: !args.quiet,
    };
    let report = demo::run(&opts)?;
    println!("{}", demo::summary_table(&report));
    println!(
        "outputs in {}/ (report.json, fig4–fig9 PNG, maps/*.gsf and *.csv)",
        args.out.display()
    );
    Ok(())
}
