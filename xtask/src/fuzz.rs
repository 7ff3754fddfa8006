//! `cargo xtask fuzz [--seconds N] [--target T]`: every parser of the host tools under
//! libFuzzer (cargo-fuzz, nightly), seeded with the real recordings in `../shared/data/real/`
//! and the project's own test files. Installs cargo-fuzz when missing. Prints the executions run
//! per target; a crash stops with the reproducer's path (turn it into a regression test in
//! `host-sim/tests/`).

use crate::firmware::root;
use std::path::{Path, PathBuf};
use std::process::Command;

type Result<T> = std::result::Result<T, String>;

/// The targets (`fuzz/fuzz_targets/*.rs`) and the seed files each starts from (by extension).
pub const TARGETS: [(&str, &[&str]); 10] = [
    ("recording_csv", &["csv"]),
    ("telemetry_log", &["bin", "log"]),
    ("jpk", &["jpk-force", "jpk-force-map"]),
    ("afm_workshop", &["csv"]),
    ("ntmdt", &["txt"]),
    ("sample_csv", &["csv"]),
    ("asylum_ibw", &["ibw"]),
    ("chiaro", &["txt"]),
    ("afmformats_tab", &["tab"]),
    ("afm_workshop_zip", &["zip"]),
];

fn ensure_cargo_fuzz() -> Result<()> {
    let ok = Command::new("cargo")
        .args(["+nightly", "fuzz", "--version"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if ok {
        return Ok(());
    }
    eprintln!("installing cargo-fuzz (cargo install cargo-fuzz --locked)");
    let st = Command::new("cargo")
        .args(["install", "cargo-fuzz", "--locked"])
        .status()
        .map_err(|e| format!("cannot run cargo install: {e}"))?;
    if !st.success() {
        return Err("cargo install cargo-fuzz failed".into());
    }
    Ok(())
}

/// Seeds: the real recordings and the project's test data, by extension, copied into the
/// target's corpus directory (`fuzz/corpus/T`, not committed) when not there yet.
fn seed(target: &str, exts: &[&str], corpus: &Path) -> Result<usize> {
    std::fs::create_dir_all(corpus).map_err(|e| format!("{}: {e}", corpus.display()))?;
    let dirs = [
        root().join("../shared/data/real"),
        root().join("host-sim/tests/data"),
        root().join("host-sim/tests/data/afmformats"),
    ];
    let mut n = 0;
    for dir in dirs {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            let name = p.file_name().and_then(|s| s.to_str()).unwrap_or("");
            let size = e.metadata().map(|m| m.len()).unwrap_or(u64::MAX);
            // libFuzzer's default -max_len is 4 KiB over the largest seed; keep seeds ≤ 4 MB.
            if exts.iter().any(|x| name.ends_with(&format!(".{x}"))) && size <= 4 << 20 {
                let to = corpus.join(format!("seed-{name}"));
                if !to.exists() {
                    std::fs::copy(&p, &to).map_err(|e| format!("{}: {e}", p.display()))?;
                }
                n += 1;
            }
        }
    }
    // The recording CSV reader: the real force curves imported to the contract (its own
    // files).
    if target == "recording_csv" {
        let opts = visco::recording::import::ImportOptions {
            spring_constant_n_per_m: Some(0.1),
            sensitivity_m_per_unit: Some(5e-8),
            tip_radius_m: Some(5e-6),
            sample_rate_hz: Some(2000.0),
        };
        let real = root().join("../shared/data/real");
        for e in std::fs::read_dir(&real).into_iter().flatten().flatten() {
            let p = e.path();
            let Ok(curves) = visco::recording::import::import_all(&p, &opts) else {
                continue;
            };
            if let Some((_, rec)) = curves.into_iter().next() {
                let name = p.file_name().and_then(|s| s.to_str()).unwrap_or("rec");
                let to = corpus.join(format!("seed-{name}.rec.csv"));
                if !to.exists() && rec.write(&to).is_ok() {
                    n += 1;
                }
            }
        }
    }
    // Chiaro's example is committed zipped: a small export of the same layout instead.
    if target == "chiaro" {
        let to = corpus.join("seed-chiaro.txt");
        if !to.exists() {
            let mut s = String::from(
                "Date\t12/05/2025\tTime\t11:20:38\tStatus\tOK\r\nX-position (um)\t5314.320\r\n\
                 k (N/m)\t0.019\r\nTip radius (um)\t27.500\r\nDevice:\tChiaro\r\n\
                 Time (s)\tLoad (uN)\tIndentation (nm)\tCantilever (nm)\tPiezo (nm)\tAuxiliary\r\n",
            );
            for i in 0..40i32 {
                let p = 100.0 * f64::from(20 - (20 - i).abs());
                s += &format!(
                    "{:.6}\t{:.6}\t0\t{:.3}\t{p:.3}\t0\r\n",
                    1e-3 * f64::from(i),
                    1e-4 * p,
                    5e-3 * p
                );
            }
            std::fs::write(&to, s).map_err(|e| format!("{}: {e}", to.display()))?;
        }
        n += 1;
    }
    eprintln!("{target}: {n} seed files");
    Ok(n)
}

/// Run the targets (all, or `only`) for `seconds` each; returns (target, executions).
pub fn run(seconds: u64, only: Option<&str>) -> Result<Vec<(String, u64)>> {
    ensure_cargo_fuzz()?;
    let fuzz = root().join("fuzz");
    let mut done = Vec::new();
    for (target, exts) in TARGETS {
        if only.is_some_and(|o| o != target) {
            continue;
        }
        let corpus: PathBuf = fuzz.join("corpus").join(target);
        seed(target, exts, &corpus)?;
        let out = Command::new("cargo")
            .current_dir(&fuzz)
            .args(["+nightly", "fuzz", "run", target])
            .arg(&corpus)
            .args([
                "--",
                &format!("-max_total_time={seconds}"),
                "-rss_limit_mb=4096",
                "-print_final_stats=1",
            ])
            .output()
            .map_err(|e| format!("cannot run cargo fuzz: {e}"))?;
        let log = String::from_utf8_lossy(&out.stderr);
        // libFuzzer's final statistics: "stat::number_of_executed_units: N".
        let execs = log
            .lines()
            .find_map(|l| l.strip_prefix("stat::number_of_executed_units:"))
            .and_then(|v| v.trim().parse::<u64>().ok());
        if !out.status.success() {
            let tail: Vec<&str> = log.lines().rev().take(40).collect();
            let tail: Vec<&str> = tail.into_iter().rev().collect();
            return Err(format!(
                "fuzz target {target} failed (a crash: the reproducer is under fuzz/artifacts/{target}/):\n{}",
                tail.join("\n")
            ));
        }
        let execs = execs.ok_or_else(|| format!("{target}: no final statistics in the log"))?;
        println!("{target}: {execs} executions in {seconds} s, no crash");
        done.push((target.to_string(), execs));
    }
    Ok(done)
}
