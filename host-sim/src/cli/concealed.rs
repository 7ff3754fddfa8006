//! `visco concealed`: the concealed-effect suite (see `visco::experiment::concealed`).

use std::path::PathBuf;

use clap::Args;

use super::CliResult;
use visco::diagnose::search::SearchOptions;
use visco::experiment::concealed::run_suite;

#[derive(Debug, Args)]
#[command(after_help = "\
Generates recordings with the project's plant (six cantilevers, tips, beds and protocols:
dynamic taps at 0.2-1 MHz and quasi-static force curves at 1-5 kHz), each with one effect
at a magnitude where D with and without it differ by only 3-10x the noise RMS, plus clean
ones, and diagnoses each. Prints the confusion matrix, the top-1 accuracy, the false-alarm
rate on clean recordings and the RMS cut; --json writes every row.")]
pub struct ConcealedArgs {
    /// Recordings per effect (and clean ones).
    #[arg(long, value_name = "N", default_value_t = 20)]
    pub seeds: u64,

    /// Worker threads (default: the machine's cores).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,

    /// The report.
    #[arg(long, value_name = "FILE.json")]
    pub json: Option<PathBuf>,

    /// Family-wise false-alarm rate of each selection step.
    #[arg(long, value_name = "P", default_value_t = 0.01)]
    pub alpha: f64,
}

/// Runs the suite.
pub fn run(args: ConcealedArgs) -> CliResult {
    if args.seeds == 0 {
        return Err("--seeds must be at least 1".into());
    }
    if !(args.alpha > 0.0 && args.alpha < 1.0) {
        return Err("--alpha must be in (0, 1)".into());
    }
    if let Some(parent) = args.json.as_ref().and_then(|p| p.parent()) {
        if !parent.as_os_str().is_empty() && !parent.is_dir() {
            return Err(format!(
                "{}: the report's directory does not exist",
                parent.display()
            )
            .into());
        }
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let opts = SearchOptions {
        alpha: args.alpha,
        ..SearchOptions::default()
    };
    let t = std::time::Instant::now();
    let report = run_suite(args.seeds, threads, &opts, &|done, total, row| {
        eprintln!(
            "[{done}/{total}] {} seed {} ({}, {:.1}× noise): named {} in {:.1} s",
            row.effect.map_or("clean", |k| k.as_str()),
            row.seed,
            row.setup,
            row.ratio,
            if row.named.is_empty() {
                "nothing".to_string()
            } else {
                row.named
                    .iter()
                    .map(|k| k.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            },
            row.wall_s
        );
    });
    println!("{}", report.confusion_markdown());
    println!(
        "top-1 accuracy {:.1} % over {} recordings with an effect; false alarms {:.1} % of {} \
         clean ones; {:.0} s",
        100.0 * report.top1_accuracy(),
        report.rows.iter().filter(|r| r.effect.is_some()).count(),
        100.0 * report.false_alarm_rate(),
        report.rows.iter().filter(|r| r.effect.is_none()).count(),
        t.elapsed().as_secs_f64()
    );
    println!("| effect | named first | median cut of the hidden misfit | cut ≥ 2× | median cut over its span |");
    println!("|---|---|---|---|---|");
    for (k, n, right, cut, two, span) in report.per_effect() {
        println!(
            "| {k} | {right}/{n} | {cut:.1}× | {:.0} % | {span:.2}× |",
            two * 100.0
        );
    }
    if let Some(path) = args.json {
        std::fs::write(&path, report.to_json().to_pretty())
            .map_err(|e| format!("{}: cannot write: {e}", path.display()))?;
        println!("  -> {}", path.display());
    }
    Ok(())
}
