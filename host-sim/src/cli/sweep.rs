//! `visco sweep`: beyond the paper — imaging speed against accuracy for SVE (line period) and
//! DIVE (tap time), and which excitation identifies fastest.

use super::{positive_f64, CliResult};
use std::path::PathBuf;
use visco::experiment::{excitation_study, sweep};
use visco::output::figure::{self, LinePanel, LinePlot, Quantity, Series};

/// Sweep the imaging speed of SVE and DIVE on the cell phantom (5 lines / 5 × 5 taps, the
/// loop re-tuned to each speed by the rules in `experiment::sweep`), and study the excitation.
#[derive(Debug, clap::Args)]
pub struct SweepArgs {
    /// Output directory (sweep.json and figures).
    #[arg(long, default_value = "out/sweep")]
    out: PathBuf,
    /// Loop rate of the core (Hz).
    #[arg(long, default_value_t = 500e3, value_parser = positive_f64)]
    rate: f64,
    /// What to run.
    #[arg(long, value_enum, default_value_t = What::All)]
    what: What,
    /// Noise seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum What {
    All,
    Sve,
    Dive,
    Excitation,
}

fn print_point(name: &str, p: &sweep::SweepPoint) {
    eprintln!(
        "{name} {:>7.3} s: {:>7.1} px/s  RMS h/c/k {:>6.2} / {:>6.2} / {:>6.2} %  max away from steep {:>6.2} / {:>6.2} / {:>6.2} %  failed {}  (paper scaling RMS {:.2} / {:.2} / {:.2} %; block {} samples)  {}",
        p.period_s, p.pixels_per_s, p.rms_error_pct[0], p.rms_error_pct[1], p.rms_error_pct[2], p.max_error_not_steep_pct[0], p.max_error_not_steep_pct[1], p.max_error_not_steep_pct[2], p.failed, p.paper_rms_error_pct[0], p.paper_rms_error_pct[1], p.paper_rms_error_pct[2], p.block_samples, if sweep::meets_goal(p) { "meets the goal" } else { "" }
    );
}

fn plot(
    path: &std::path::Path,
    title: &str,
    points: &[sweep::SweepPoint],
) -> Result<(), visco::output::OutputError> {
    let series = |i: usize, name: &str| {
        Series::line(
            name,
            points
                .iter()
                .map(|p| (p.pixels_per_s, p.rms_error_pct[i].min(100.0)))
                .collect(),
        )
    };
    figure::lines(
        path,
        &LinePlot {
            title: Some(title.into()),
            x: Quantity::new("pixel rate", "px/s"),
            x_log: true,
            panels: vec![LinePanel {
                y: Quantity::new("RMS error", "%"),
                series: vec![
                    series(0, "h"),
                    series(1, "c"),
                    series(2, "k"),
                    Series::dashed(
                        "2 % (goal)",
                        points.iter().map(|p| (p.pixels_per_s, 2.0)).collect(),
                    ),
                ],
                y_log: true,
                ..Default::default()
            }],
            ..Default::default()
        },
    )
}

pub fn run(args: SweepArgs) -> CliResult {
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let mut out = sweep::SweepReport {
        schema_version: sweep::SCHEMA_VERSION,
        ..Default::default()
    };
    if matches!(args.what, What::All | What::Sve) {
        let periods = [2.0, 1.0, 0.5, 0.2, 0.1, 0.08, 0.07, 0.06, 0.05, 0.04];
        out.sve = sweep::sve_sweep(&periods, args.rate, args.seed, |p| {
            print_point("SVE line period", p)
        })?;
        out.sve_fastest_meeting_goal = sweep::fastest_meeting_goal(&out.sve).cloned();
        plot(
            &args.out.join("sweep_sve.png"),
            "SVE: accuracy against pixel rate (20 lines × 50 px, instrument scaling)",
            &out.sve,
        )?;
    }
    if matches!(args.what, What::All | What::Dive) {
        let taps = [0.2, 0.1, 0.05, 0.03, 0.02, 0.015, 0.01];
        out.dive = sweep::dive_sweep(&taps, args.rate, args.seed, |p| {
            print_point("DIVE tap time", p)
        })?;
        out.dive_fastest_meeting_goal = sweep::fastest_meeting_goal(&out.dive).cloned();
        plot(
            &args.out.join("sweep_dive.png"),
            "DIVE: accuracy against pixel rate (5 × 5 taps, instrument scaling)",
            &out.dive,
        )?;
    }
    if matches!(args.what, What::All | What::Excitation) {
        let f0 = visco_core::Cantilever::PAPER.f0_hz();
        out.excitation =
            excitation_study::study(&excitation_study::candidates(f0), args.rate, args.seed);
        for c in &out.excitation {
            eprintln!(
                "excitation f1 {:>6.0} Hz, f2 {:>6.0} Hz, tip {:>3.0}/{:>3.0} nm: spread of ĉ {:.2e}, k̂ {:.2e}; predicted information c {:.2e}, k {:.2e}",
                c.f1_hz, c.f2_hz, c.tip_amplitudes_m[0] * 1e9, c.tip_amplitudes_m[1] * 1e9, c.relative_spread[0], c.relative_spread[1], c.predicted_information[0], c.predicted_information[1]
            );
        }
    }
    out.notes = vec![
        "errors in % of h_max, c_max, k_max against the footprint reference, instrument scaling, steep from the identified topography (see `visco demo`); paper_rms_error_pct: the paper's n = |W| scaling, needs the simulator's contact count".into(),
        "goal: every RMS error <= 2 % and every error away from steep topography <= 5 %, no pixel lost".into(),
        "the loop is re-tuned to each speed by the rules in host-sim/src/experiment/sweep.rs".into(),
        "excitation: spread = relative standard deviation of the estimate over a 60 ms read-out at a fixed 10 ms memory; the time to a given accuracy scales with its square".into(),
    ];
    let json = serde_json::to_string_pretty(&out)?;
    visco::output::write_atomic(&args.out.join("sweep.json"), json.as_bytes())?;
    match &out.sve_fastest_meeting_goal {
        Some(p) => println!("SVE: fastest meeting RMS ≤ 2 %, max away from steep ≤ 5 %: line period {} s, {:.0} px/s (the paper: 25 px/s; goal ≥ 2000 px/s)", p.period_s, p.pixels_per_s),
        None if !out.sve.is_empty() => println!("SVE: no line period meets RMS ≤ 2 %, max away from steep ≤ 5 %"),
        None => {}
    }
    match &out.dive_fastest_meeting_goal {
        Some(p) => println!("DIVE: fastest meeting RMS ≤ 2 %, max away from steep ≤ 5 %: tap time {} s, {:.0} px/s (the paper: 5 px/s; goal ≥ 2000 px/s)", p.period_s, p.pixels_per_s),
        None if !out.dive.is_empty() => println!("DIVE: no tap time meets RMS ≤ 2 %, max away from steep ≤ 5 %"),
        None => {}
    }
    if let Some(best) = out.excitation.iter().min_by(|a, b| {
        a.relative_spread[0]
            .max(a.relative_spread[1])
            .total_cmp(&b.relative_spread[0].max(b.relative_spread[1]))
    }) {
        println!(
            "excitation identifying fastest: f1 = {:.0} Hz, f2 = {:.0} Hz, tip amplitudes {:.0}/{:.0} nm (worst relative spread {:.2e})",
            best.f1_hz, best.f2_hz, best.tip_amplitudes_m[0] * 1e9, best.tip_amplitudes_m[1] * 1e9, best.relative_spread[0].max(best.relative_spread[1])
        );
    }
    println!("sweep.json and figures in {}", args.out.display());
    Ok(())
}
