//! `visco import`: vendor force-curve files → recording CSVs.
//!
//! All-or-nothing: every curve is read and written under a temporary name first; only when all
//! succeeded are they renamed into place. A failure leaves no output file behind.

use std::path::{Path, PathBuf};

use clap::Args;

use super::{positive_f64, CliResult};
use visco::recording::import::{Import, ImportOptions};
use visco::recording::{ErrorKind, PendingFile, Recording, RecordingError};

/// The placeholder that `--out` uses for the curve number of a map.
const CURVE_PLACEHOLDER: &str = "{curve}";

#[derive(Debug, Args)]
#[command(after_help = "\
Formats: JPK .jpk-force, .jpk-force-map, .jpk-qi-data; AFM Workshop .csv; NT-MDT .txt export.

Every output is a `mode: force-curve` recording (see shared/spec/recording.md): u_m the base
position, z up (JPK: the z sensor's reading; the piezo drive signal goes to `height_piezo_m`),
d_m the deflection (negative when the sample pushes the tip up), t_s from the vendor's rates,
plus `segment` (see the `# segments:` line) and, where the file has one, the vendor's force
`force_vendor_n` (vendor sign: positive = repulsive, = -k*d_m).

Maps (.jpk-force-map, .jpk-qi-data) hold one curve per grid point. Either pick one with
--curve INDEX, or write them all by putting {curve} in --out, which is replaced by the curve's
index number (as in the archive's index/N/):
    visco import map.jpk-force-map --tip-radius 5e-6 --out curves/map-{curve}.csv

A value the file lacks must be given: the tip radius always (no vendor stores it), the spring
constant and sensitivity where the file has none (AFM Workshop Force(nN) files need no
sensitivity), the sampling rate for AFM Workshop and NT-MDT files (they hold no time base).
A flag overrides the file's value, with a warning when they differ.

Errors are one line on stderr, `error: FILE[:MEMBER][:LINE]: reason (fix: ...)`, with exit
status 1; nothing is written unless every curve succeeds.")]
pub struct ImportArgs {
    /// The vendor file to import.
    pub file: PathBuf,

    /// Output recording CSV; for all curves of a map, a pattern containing {curve}.
    #[arg(long, value_name = "REC.csv")]
    pub out: PathBuf,

    /// Cantilever spring constant, N/m (overrides the file's).
    #[arg(long, value_name = "N_PER_M", value_parser = positive_f64)]
    pub spring_constant: Option<f64>,

    /// Deflection sensitivity: metres per unit of the file's raw deflection signal (m/V for
    /// JPK and AFM Workshop T-B(V), m/nA for NT-MDT DFL). Overrides the file's.
    #[arg(long, value_name = "M_PER_V", value_parser = positive_f64)]
    pub sensitivity: Option<f64>,

    /// Spherical tip radius, m (required: vendor files do not store it).
    #[arg(long, value_name = "M", value_parser = positive_f64)]
    pub tip_radius: Option<f64>,

    /// Sampling rate, Hz, for files without a time base (AFM Workshop, NT-MDT).
    #[arg(long, value_name = "HZ", value_parser = positive_f64)]
    pub sample_rate: Option<f64>,

    /// Import only this curve of a map (its index/N number).
    #[arg(long, value_name = "INDEX")]
    pub curve: Option<usize>,
}

/// Runs the import.
pub fn run(args: ImportArgs) -> CliResult {
    let opts = ImportOptions {
        spring_constant_n_per_m: args.spring_constant,
        sensitivity_m_per_unit: args.sensitivity,
        tip_radius_m: args.tip_radius,
        sample_rate_hz: args.sample_rate,
    };
    let mut import = Import::open(&args.file, &opts)?;
    let available = import.curves();
    let out_text = args.out.to_string_lossy().into_owned();
    let pattern = out_text.contains(CURVE_PLACEHOLDER);
    let chosen: Vec<usize> = match args.curve {
        Some(c) => vec![c],
        None if available.len() == 1 || pattern => available.clone(),
        None => {
            return Err(Box::new(
                RecordingError::new(
                    &args.file,
                    ErrorKind::Usage,
                    format!("the map holds {} curves", available.len()),
                )
                .with_fix(format!(
                    "pass --curve INDEX for one, or put {CURVE_PLACEHOLDER} in --out for all, \
                     e.g. --out curves/map-{CURVE_PLACEHOLDER}.csv"
                )),
            ))
        }
    };
    let out_for = |c: usize| -> PathBuf {
        if pattern {
            PathBuf::from(out_text.replace(CURVE_PLACEHOLDER, &c.to_string()))
        } else {
            args.out.clone()
        }
    };
    let mut pending: Vec<(usize, PendingFile, String)> = Vec::with_capacity(chosen.len());
    for &c in &chosen {
        let out = out_for(c);
        if same_file(&out, &args.file) {
            return Err(Box::new(RecordingError::new(
                &out,
                ErrorKind::Usage,
                "the output would overwrite the input",
            )));
        }
        let rec = import.read_curve(c)?;
        let summary = summarize(c, &rec, import.is_map());
        // Written under a temporary name; dropped (removed) if a later curve fails.
        pending.push((c, rec.write_pending(&out)?, summary));
    }
    for w in import.warnings() {
        eprintln!("warning: {w}");
    }
    let n = pending.len();
    let mut lines = Vec::with_capacity(n);
    for (_, file, summary) in pending {
        let shown = file.path().display().to_string();
        file.commit()?;
        lines.push(format!("  {summary} -> {shown}"));
    }
    println!(
        "imported {} ({}): {n} curve{}",
        args.file.display(),
        import.format().name(),
        if n == 1 { "" } else { "s" }
    );
    for l in lines {
        println!("{l}");
    }
    Ok(())
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// One line per curve: points, segments, k, sensitivity, rates, duration.
fn summarize(curve: usize, rec: &Recording, is_map: bool) -> String {
    let m = &rec.meta;
    let duration = match (rec.t_s.first(), rec.t_s.last()) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    let mut s = String::new();
    if is_map {
        s.push_str(&format!("curve {curve}: "));
    }
    s.push_str(&format!(
        "{} points over {:.3} s, k = {} N/m ({})",
        rec.len(),
        duration,
        m.cantilever_k_n_per_m,
        m.get("spring_constant_source").unwrap_or("file")
    ));
    if let Some(v) = m
        .get("sensitivity_m_per_v")
        .or(m.get("sensitivity_m_per_na"))
    {
        s.push_str(&format!(", sensitivity {v}"));
    }
    match m.get("segment_rates_hz") {
        Some(r) => s.push_str(&format!(", rates {r} Hz")),
        None => s.push_str(&format!(", rate {} Hz", m.sample_rate_hz)),
    }
    if let Some(seg) = m.get("segments") {
        s.push_str(&format!(", segments {seg}"));
    }
    if let (Some(x), Some(y)) = (m.get("position_x_m"), m.get("position_y_m")) {
        s.push_str(&format!(", at x = {x} m, y = {y} m"));
    }
    s
}
