//! `visco concealed`: the concealed-effect suite (see `visco::experiment::concealed`).

use std::path::PathBuf;

use clap::Args;

use super::CliResult;
use visco::diagnose::search::SearchOptions;
use visco::experiment::concealed::{
    run_recordings, run_suite, ConcealedReport, SuiteReport, SuiteRow,
};

#[derive(Debug, Args)]
#[command(after_help = "\
Generates recordings with the project's plant (six cantilevers, tips, beds and protocols:
dynamic taps at 0.2-1 MHz and quasi-static force curves at 1-5 kHz), each with one effect
at a magnitude where D with and without it differ by only 3-10x the noise RMS, plus clean
ones, and diagnoses each. Prints the confusion matrix, the top-1 accuracy, the false-alarm
rate on clean recordings and the RMS cut; --json writes every row.

With --recordings DIR it also diagnoses every recording of DIR made by another simulator
(`python -m refsim generate --out DIR`, see refsim/README.md): each DIR/<stem>.csv with its
truth beside it (<stem>.truth.json: class, amplitude; <stem>.truth.csv: the noise-free D),
which is read only to score. Both suites are reported separately, each with its confusion
matrix and, per class, the top-1 right, the right ones with an extra wrong finding (a
recording named [right, wrong]), the exactly right and the clean false alarms.")]
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

    /// Also diagnose the recordings of DIR (with truth sidecars, e.g. from refsim).
    #[arg(long, value_name = "DIR")]
    pub recordings: Option<PathBuf>,

    /// Skip the project's own plant suite (with --recordings).
    #[arg(long, requires = "recordings")]
    pub no_plant: bool,

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
    let progress = |done: usize, total: usize, row: &SuiteRow| {
        eprintln!(
            "[{done}/{total}] {} seed {} ({}, {:.1}× noise): named {} in {:.1} s{}",
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
            row.wall_s,
            row.error
                .as_ref()
                .map_or(String::new(), |e| format!(" (refused: {e})"))
        );
    };
    let mut out = ConcealedReport {
        schema_version: visco::experiment::concealed::SCHEMA_VERSION,
        suite: None,
        plant: None,
        independent: None,
    };
    if !args.no_plant {
        let t = std::time::Instant::now();
        let report = run_suite(args.seeds, threads, &opts, &progress);
        println!("## The plant suite (visco's own simulator)\n");
        print_report(&report, t.elapsed().as_secs_f64());
        out.suite = Some(report.to_json());
    }
    if let Some(dir) = &args.recordings {
        let t = std::time::Instant::now();
        let report = run_recordings(dir, threads, &opts, &progress)?;
        println!(
            "\n## The independent suite ({}: recordings visco did not make)\n",
            dir.display()
        );
        print_report(&report, t.elapsed().as_secs_f64());
        let mut indep = report.to_json();
        indep.recordings_dir = Some(dir.display().to_string());
        // With both suites, the plant's moves under `plant` (see ConcealedReport).
        out.plant = out.suite.take();
        out.independent = Some(indep);
    }
    if let Some(path) = args.json {
        std::fs::write(&path, visco::report::to_pretty(&out))
            .map_err(|e| format!("{}: cannot write: {e}", path.display()))?;
        println!("  -> {}", path.display());
    }
    Ok(())
}

fn print_report(report: &SuiteReport, wall_s: f64) {
    println!("{}", report.confusion_markdown());
    println!("{}", report.per_class_markdown());
    println!(
        "top-1 accuracy {:.1} % over {} recordings with an effect ({:.1} % of the right ones \
         with an extra wrong finding); false alarms {:.1} % of {} clean ones; nominal held-out \
         RMS on clean ones {:.2}× the noise RMS (median); {:.0} s",
        100.0 * report.top1_accuracy(),
        report.rows.iter().filter(|r| r.effect.is_some()).count(),
        100.0 * report.extra_wrong_rate(),
        100.0 * report.false_alarm_rate(),
        report.rows.iter().filter(|r| r.effect.is_none()).count(),
        report.clean_rms_over_noise(),
        wall_s
    );
    let (two, right) = report.hidden_misfit_cut_at_least_2();
    println!(
        "hidden misfit (model against the noise-free truth) cut ≥ 2× on {two} of the {right} \
         named right first ({:.1} %)",
        100.0 * two as f64 / right.max(1) as f64
    );
    println!("| effect | named first | median cut of the hidden misfit | cut ≥ 2× | median cut over its span |");
    println!("|---|---|---|---|---|");
    for (k, n, right, cut, two, span) in report.per_effect() {
        println!(
            "| {k} | {right}/{n} | {cut:.1}× | {:.0} % | {span:.2}× |",
            two * 100.0
        );
    }
    let z = report.first_stage_z();
    println!(
        "Truth-based, where each miss was left: the share of the effect the nominal fit took \
         into its own parameters, and the misses an ideal extension could not have named \
         (held-out z below the first stage's {z:.2}):"
    );
    println!("| effect | median absorbed by the nominal | missed | of them below z {z:.2} |");
    println!("|---|---|---|---|");
    for (k, absorbed, missed, hidden) in report.absorbed_per_effect() {
        println!("| {k} | {:.0} % | {missed} | {hidden} |", absorbed * 100.0);
    }
}
