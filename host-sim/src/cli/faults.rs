//! `visco faults`: the fault-injection suite on the simulated instrument — for each fault class,
//! whether the loop stayed bounded, the largest tip force against the limit, the fault flags
//! raised and the time to recover (see `experiment::faults`).

use super::{positive_f64, CliResult};
use std::path::PathBuf;
use visco::experiment::faults::{run_fault, FaultClass, FaultOutcome};
use visco_core::status;

/// Inject each fault class into a closed-loop run and measure the recovery.
#[derive(Debug, clap::Args)]
pub struct FaultsArgs {
    /// Write the outcomes as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Loop rate of the core (Hz).
    #[arg(long, default_value_t = 500e3, value_parser = positive_f64)]
    rate: f64,
    /// Noise seeds to run (1..=N); the table shows the worst case over them.
    #[arg(long, default_value_t = 3)]
    seeds: u64,
}

/// The names of the fault bits in a status word.
pub fn flag_names(flags: u32) -> String {
    let names = [
        (status::INPUT_INVALID, "INPUT_INVALID"),
        (status::INPUT_SATURATED, "INPUT_SATURATED"),
        (status::INPUT_SPIKE, "INPUT_SPIKE"),
        (status::FORCE_LIMIT, "FORCE_LIMIT"),
        (status::CONTACT_LOST, "CONTACT_LOST"),
        (status::EST_DIVERGED, "EST_DIVERGED"),
        (status::NO_CONTACT, "NO_CONTACT"),
    ];
    let v: Vec<&str> = names
        .iter()
        .filter(|(b, _)| flags & b != 0)
        .map(|(_, n)| *n)
        .collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(" ")
    }
}

pub fn run(args: FaultsArgs) -> CliResult {
    if args.seeds == 0 {
        return Err("--seeds must be at least 1".into());
    }
    let mut all: Vec<FaultOutcome> = Vec::new();
    println!(
        "| fault class | bounded | max tip force / limit (nN) | flags | recovery to 5 % (ms, worst of {} seeds) |",
        args.seeds
    );
    println!("|---|---|---|---|---|");
    for class in FaultClass::ALL {
        let runs: Vec<FaultOutcome> = (1..=args.seeds)
            .map(|seed| run_fault(class, args.rate, seed))
            .collect();
        let bounded = runs.iter().all(|o| o.bounded);
        let force = runs.iter().map(|o| o.max_force_n).fold(0.0, f64::max);
        let flags = runs.iter().fold(0, |f, o| f | o.flags);
        let recovery = runs
            .iter()
            .map(|o| o.recovery_s)
            .try_fold(0.0f64, |w, r| r.map(|r| w.max(r)));
        println!(
            "| {} | {} | {:.1} / {:.0} | {} | {} |",
            serde_json::to_value(class)?.as_str().unwrap_or("?"),
            if bounded { "yes" } else { "NO" },
            force * 1e9,
            runs[0].force_limit_n * 1e9,
            flag_names(flags),
            if class == FaultClass::DiveForceLimit {
                // Its column: the retract on the limit, from the contact (ms, worst), and the
                // true static force there (nN, highest).
                let f = runs
                    .iter()
                    .filter_map(|o| o.retract_force_n)
                    .fold(0.0, f64::max);
                runs.iter()
                    .map(|o| o.retract_s)
                    .try_fold(0.0f64, |w, r| r.map(|r| w.max(r)))
                    .map_or("no retract".into(), |r| {
                        format!(
                            "retract {:.3} ms after contact at {:.1} nN",
                            r * 1e3,
                            f * 1e9
                        )
                    })
            } else {
                recovery.map_or("not recovered".into(), |r| format!("{:.1}", r * 1e3))
            },
        );
        all.extend(runs);
    }
    if let Some(path) = &args.json {
        let report = visco::experiment::faults::FaultsReport {
            schema_version: visco::experiment::faults::SCHEMA_VERSION,
            runs: all,
        };
        let json = visco::report::to_pretty(&report);
        visco::output::write_atomic(path, json.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
