//! `visco replay`: a recording's deflection fed sample by sample to the firmware under QEMU,
//! its outputs compared bit for bit with the host build of the same core.

use std::path::PathBuf;

use clap::{Args, ValueEnum};

use super::CliResult;
use visco::replay::{
    self, core_config, lockstep_qemu, read_recording, replay_qemu, simulate, FirmwareConfig,
    InputKind, Target,
};
use visco::sample::Sample;
use visco::telemetry::{firmware_losses, write_recording_csv, LinkStats};
use visco_protocol::{Mode, PerSample};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TargetArg {
    /// The firmware image on an emulated Cortex-M7 (`qemu-system-arm -machine mps2-an500`).
    Qemu,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    /// Dynamic indentation (taps).
    Dive,
    /// Scanning.
    Sve,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum InputArg {
    /// Codes when every D is on the ADC grid, else metres.
    Auto,
    /// ADC codes through the firmware's ADC driver (D rounded to the grid).
    Codes,
    /// D in metres, handed to the core as it is.
    Metres,
}

#[derive(Debug, Args)]
#[command(after_help = "\
The recording (shared/spec/recording.md) supplies D (d_m), the mode and the sample rate; the
cantilever (K, and C and M or f0 and Q) and the tip radius of its metadata configure the core
unless --set says otherwise. The core's configuration is Config::paper at the sample rate with
the fields of the recording's `visco_config` metadata (written by `visco replay --simulate`)
and of --set replaced; field names as in the core's errors, e.g. --set dive.tap_s=0.05
--set sve.lines=1 (list: --set help=0).

The firmware image is built by `cargo xtask firmware`; qemu-system-arm must be installed.
Outputs come back as compact blocks (DAC codes, status, a CRC-32 of every field of 48
samples; ~10 000 samples/s) or, with --full, every field of every sample (~2 000/s; needed
for --out). Exit status 1 unless every sample and record is bit-identical.

--simulate first writes REC: the host plant (the cell phantom) in closed loop with the host
core, D through the firmware's ADC path, until the sequence is done (or --max-samples). With
--lockstep the firmware drives the plant instead, one sample per UART round trip, compared
with the host-only run (slow: ~800 samples/s; use a short sequence).

Example:
    visco replay tap.csv --simulate --mode dive --set dive.nx=1 --set dive.ny=1 --set dive.tap_s=0.05
    visco replay tap.csv --target qemu")]
pub struct ReplayArgs {
    /// The recording CSV (read; written first with --simulate).
    pub recording: PathBuf,

    /// Where the firmware runs.
    #[arg(long, value_enum, default_value = "qemu")]
    pub target: TargetArg,

    /// The mode to replay (default: the recording's).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,

    /// A core configuration field, NAME=VALUE (repeatable); also adc_metres_per_code.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,

    /// What to feed: ADC codes or metres.
    #[arg(long, value_enum, default_value = "auto")]
    pub input: InputArg,

    /// Every field of every sample back (slower), instead of digests per block.
    #[arg(long)]
    pub full: bool,

    /// Replay only the first N samples.
    #[arg(long, value_name = "N")]
    pub samples: Option<usize>,

    /// Write the firmware's outputs as a recording (needs --full).
    #[arg(long, value_name = "OUT.csv")]
    pub out: Option<PathBuf>,

    /// The QEMU firmware image.
    #[arg(long, value_name = "ELF", default_value = replay::DEFAULT_ELF)]
    pub elf: PathBuf,

    /// Simulate the recording first (host plant and core in closed loop) and write it to
    /// RECORDING.
    #[arg(long)]
    pub simulate: bool,

    /// With --simulate: the firmware drives the plant (closed loop over the UART) instead of
    /// replaying afterwards.
    #[arg(long, requires = "simulate")]
    pub lockstep: bool,

    /// With --simulate: at most this many samples.
    #[arg(long, value_name = "N", default_value_t = 2_000_000)]
    pub max_samples: usize,

    /// With --simulate: the plant's noise seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

fn apply_sets(fw: &mut FirmwareConfig, sets: &[String]) -> CliResult {
    for s in sets {
        if s.starts_with("help") {
            return Err(format!(
                "configuration fields: {}, {}",
                replay::ADC_KEY,
                core_config::PARAMS.join(", ")
            )
            .into());
        }
        fw.set_assignment(s)?;
    }
    Ok(())
}

fn mode_of(arg: Option<ModeArg>, rec: Option<visco::recording::Mode>) -> Result<Mode, String> {
    match (arg, rec) {
        (Some(ModeArg::Dive), _) | (None, Some(visco::recording::Mode::Dive)) => Ok(Mode::Dive),
        (Some(ModeArg::Sve), _) | (None, Some(visco::recording::Mode::Sve)) => Ok(Mode::Sve),
        _ => Err("the recording is not a dive or sve recording: give --mode".into()),
    }
}

/// Runs the replay.
pub fn run(args: ReplayArgs) -> CliResult {
    let TargetArg::Qemu = args.target;
    let target = Target::new(&args.elf);
    if args.out.is_some() && !args.full {
        return Err("--out needs --full (the firmware's every output of every sample)".into());
    }
    if args.simulate {
        let mode =
            mode_of(args.mode, None).map_err(|_| "--simulate needs --mode dive or --mode sve")?;
        let mut fw = FirmwareConfig::default();
        apply_sets(&mut fw, &args.set)?;
        let sample = Sample::cell_phantom();
        if args.lockstep {
            let r = lockstep_qemu(&target, &fw, mode, &sample, args.seed, args.max_samples)?;
            r.host.recording.write(&args.recording)?;
            println!(
                "lockstep {mode:?}: {} samples in closed loop with the firmware under QEMU \
                 ({:.0} samples/s), {} records; trajectory bit-identical to the host-only run: \
                 {}, records: {}; wrote the host-only run to {}",
                r.samples,
                r.samples_per_s,
                r.records.len(),
                r.bit_identical,
                r.records_identical,
                args.recording.display()
            );
            return match r.difference {
                None => Ok(()),
                Some(d) => Err(format!("lockstep differs: {d}").into()),
            };
        }
        let sim = simulate(&fw, mode, &sample, args.seed, args.max_samples)?;
        sim.recording.write(&args.recording)?;
        println!(
            "simulated {mode:?}: {} samples ({:.3} s at {} Hz), {} records; wrote {}",
            sim.steps.len(),
            sim.steps.len() as f64 / sim.config.sample_rate_hz,
            sim.config.sample_rate_hz,
            sim.records.len(),
            args.recording.display()
        );
    }
    let (rec, mut fw) = read_recording(&args.recording)?;
    let mode = mode_of(args.mode, Some(rec.meta.mode))?;
    // The recording's instrument, unless the configuration already says otherwise.
    let meta = &rec.meta;
    let mut from_meta = vec![
        ("sample_rate_hz", Some(meta.sample_rate_hz)),
        ("cantilever.k_n_per_m", Some(meta.cantilever_k_n_per_m)),
        ("tip_radius_m", Some(meta.tip_radius_m)),
    ];
    match (
        meta.cantilever_c_ns_per_m,
        meta.cantilever_m_kg,
        meta.cantilever_f0_hz,
        meta.cantilever_q,
    ) {
        (Some(c), Some(m), _, _) => {
            from_meta.push(("cantilever.c_ns_per_m", Some(c)));
            from_meta.push(("cantilever.m_kg", Some(m)));
        }
        (_, _, Some(f0), Some(q)) => {
            let c = visco_core::Cantilever::from_resonance(meta.cantilever_k_n_per_m, f0, q);
            from_meta.push(("cantilever.c_ns_per_m", Some(c.c_ns_per_m)));
            from_meta.push(("cantilever.m_kg", Some(c.m_kg)));
        }
        _ => {}
    }
    for (name, v) in from_meta {
        if let (Some(v), Some(id)) = (v, core_config::param_id(name)) {
            if fw.staged.get(id).is_none() {
                fw.set(name, v)?;
            }
        }
    }
    apply_sets(&mut fw, &args.set)?;
    let n = args.samples.unwrap_or(rec.len()).min(rec.len());
    let kind = match args.input {
        InputArg::Auto => InputKind::Auto,
        InputArg::Codes => InputKind::Codes,
        InputArg::Metres => InputKind::Metres,
    };
    let per_sample = if args.full {
        PerSample::Full
    } else {
        PerSample::Blocks
    };
    let r = replay_qemu(&target, &fw, mode, &rec.d_m[..n], kind, per_sample)?;
    println!(
        "replay {mode:?} of {} on QEMU: {} samples as {}{}, {:.0} samples/s; {} records",
        args.recording.display(),
        r.samples,
        match r.input {
            InputKind::Codes => "ADC codes",
            _ => "metres",
        },
        if r.rounded > 0 {
            format!(" ({} rounded to the ADC grid)", r.rounded)
        } else {
            String::new()
        },
        r.samples_per_s,
        r.records.len()
    );
    // A recording made with this core reproduces its own U: row k+1 holds the U of step k.
    let reproduced = r
        .host
        .iter()
        .zip(rec.u_m.iter().skip(1))
        .take_while(|(s, u)| s.u_m as f64 == **u)
        .count();
    println!(
        "recorded U reproduced by the core for the first {reproduced} of {} samples",
        n.saturating_sub(1)
    );
    println!("link: {}", r.firmware.stats);
    if let Some(st) = &r.firmware.status {
        println!(
            "firmware counted: {}; {} chunks of tones computed by the loop (the estimator \
             task's were late: a cost, not a loss)",
            firmware_losses(st).unwrap_or_else(|| "nothing lost or late".to_string()),
            st.tones_late
        );
    }
    if let Some(out) = &args.out {
        let meta = vec![
            ("mode", format!("{mode:?}").to_lowercase()),
            (
                "source",
                format!("visco replay of {} on QEMU", args.recording.display()),
            ),
            (
                "cantilever_k_n_per_m",
                format!("{}", rec.meta.cantilever_k_n_per_m),
            ),
            ("tip_radius_m", format!("{}", rec.meta.tip_radius_m)),
        ];
        let stats: LinkStats = r.firmware.stats;
        let f = std::fs::File::create(out)?;
        write_recording_csv(
            std::io::BufWriter::new(f),
            &r.firmware.steps,
            rec.meta.sample_rate_hz,
            &meta,
            &stats,
        )?;
        println!("wrote the firmware's outputs to {}", out.display());
    }
    match (&r.difference, r.bit_identical && r.records_identical) {
        (None, true) => {
            println!(
                "bit-identical: every U code, DAC word, U, X, Y, status word and estimate of {} \
                 samples, and all {} records",
                r.samples,
                r.records.len()
            );
            Ok(())
        }
        (d, _) => Err(format!(
            "the firmware differs from the host build: {}",
            d.clone().unwrap_or_default()
        )
        .into()),
    }
}
