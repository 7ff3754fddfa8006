//! `cargo xtask <task>`: the workspace's task runner (`cargo xtask --help`).
//!
//! Arguments are parsed by `clap`, so a mistyped task or flag is an error with the usage,
//! never silently ignored.

use clap::{Args, Parser, Subcommand, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;
use xtask::firmware;

#[derive(Parser)]
#[command(
    name = "cargo xtask",
    bin_name = "cargo xtask",
    about = "visco's task runner"
)]
struct Cli {
    #[command(subcommand)]
    task: Task,
}

/// Which firmware image: core, number format and estimator.
#[derive(Args, Clone, Copy)]
struct ImageArgs {
    /// The thumbv7m-none-eabi build on mps2-an385 (Cortex-M3, soft float); default: the
    /// Cortex-M7 on mps2-an500.
    #[arg(long)]
    m3: bool,
    /// The core in Q31.32 (feature fixed-point); default f32.
    #[arg(long)]
    fixed: bool,
}

impl ImageArgs {
    fn machine(self) -> firmware::Machine {
        if self.m3 {
            firmware::M3
        } else {
            firmware::M7
        }
    }
    fn number(self) -> firmware::Number {
        if self.fixed {
            firmware::Number::Q32
        } else {
            firmware::Number::F32
        }
    }
}

/// Bench and profile windows of a closed-loop recording.
#[derive(ValueEnum, Clone, Copy)]
enum Window {
    Idle,
    DiveDwell,
    DiveReadout,
    SveScan,
}

impl Window {
    fn name(self) -> &'static str {
        match self {
            Window::Idle => "idle",
            Window::DiveDwell => "dive-dwell",
            Window::DiveReadout => "dive-readout",
            Window::SveScan => "sve-scan",
        }
    }
}

fn estimator(gradient: bool) -> firmware::Estimator {
    if gradient {
        firmware::Estimator::Gradient
    } else {
        firmware::Estimator::LeastSquares
    }
}

#[derive(Subcommand)]
enum Task {
    /// Build both boards (qemu, stm32h743) in release, print sizes.
    Firmware,
    /// Boot the QEMU image, run N loop samples per mode, check the log.
    QemuSmoke {
        #[arg(long, default_value_t = 30_000)]
        steps: u32,
    },
    /// Prove no panic path is linked (panic-never handler + canary).
    PanicCheck,
    /// SysTick ticks vs counted instructions under -icount.
    Calibrate {
        /// SysTick shifts to measure, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "0,3,6")]
        shifts: Vec<u32>,
        /// The Cortex-M3 build on mps2-an385.
        #[arg(long)]
        m3: bool,
    },
    /// Instructions per loop interrupt: core stopped, DIVE dwell, DIVE read-out, SVE scan,
    /// over closed-loop recordings.
    Bench {
        #[arg(long, default_value_t = firmware::BENCH_STEPS)]
        steps: u32,
        #[arg(long, default_value_t = 0)]
        shift: u32,
        #[command(flatten)]
        image: ImageArgs,
        /// The gradient estimator in both modes; default least squares.
        #[arg(long)]
        gradient: bool,
        /// Only this window; default all.
        #[arg(long, value_enum)]
        window: Option<Window>,
    },
    /// Replay a closed-loop DIVE tap and SVE line through QEMU, compare with the host bit for
    /// bit (digests per block, or --full: every field of every sample).
    Replay {
        #[arg(long)]
        full: bool,
        #[command(flatten)]
        image: ImageArgs,
    },
    /// All firmware measurements; JSON as documented in firmware/README.md.
    FirmwareReport {
        #[arg(long)]
        json: Option<PathBuf>,
        #[arg(long)]
        no_replay: bool,
    },
    /// Regenerate the reports' JSON Schemas: host-sim/schemas/ (the `visco` reports) and
    /// xtask/schemas/firmware-report.schema.json.
    Schemas,
    /// Everything: install tools, fmt, no_std build, host tests, firmware tests, the Python
    /// package (what CI runs).
    Test,
    /// What `cargo xtask test` runs for the firmware.
    FirmwareTest,
    /// What `cargo xtask test` runs for the Python package (python/).
    PythonTest,
    /// What `cargo xtask test` runs for the independent reference simulator (refsim/).
    RefsimTest,
    /// Build the STM32H743 image and run it with probe-rs (RTT log).
    FlashStm32h743 {
        #[arg(long, default_value = "STM32H743ZITx")]
        chip: String,
    },
    /// Diagnostic: each direction of the QEMU UART link alone.
    LinkThroughput,
    /// Closed loop: host plant <-> firmware under QEMU, one round trip per sample, an SVE line
    /// segment, compared with the host-only run.
    Lockstep,
    /// Executed instructions of the loop interrupt per function and per instruction (QEMU exec
    /// log) in a bench window.
    Profile {
        #[arg(long, value_enum, default_value = "sve-scan")]
        window: Window,
        #[arg(long, default_value_t = 200)]
        steps: u32,
        #[command(flatten)]
        image: ImageArgs,
        /// The gradient estimator in both modes; default least squares.
        #[arg(long)]
        gradient: bool,
    },
    /// CRC-32 of every output of closed-loop runs of the host core (equal before and after a
    /// core change: bit-identical results), compared with xtask/core-digests.txt.
    CoreDigest {
        /// Rewrite xtask/core-digests.txt (an intended change of the core's results: same
        /// commit, with the reason).
        #[arg(long)]
        bless: bool,
    },
    /// Decode a defmt stream (e.g. QEMU semihosting output).
    Defmt { elf: PathBuf, stream: PathBuf },
    /// Every host parser under libFuzzer (cargo-fuzz, nightly; installs cargo-fuzz), seeded with
    /// the real recordings; N s per target.
    Fuzz {
        #[arg(long, default_value_t = 60)]
        seconds: u64,
        #[arg(long)]
        target: Option<String>,
    },
}

fn run(task: Task) -> Result<(), String> {
    match task {
        Task::Firmware => firmware::build_all().map(|_| ()),
        Task::QemuSmoke { steps } => firmware::qemu_smoke(steps),
        Task::PanicCheck => firmware::panic_check(),
        Task::Calibrate { shifts, m3 } => {
            firmware::ensure_tools()?;
            let m = if m3 { firmware::M3 } else { firmware::M7 };
            let elf = firmware::build_for(m.target, firmware::Board::Qemu, &[])?;
            println!("{} ({}), {}", m.machine, m.cpu, m.target);
            let c = firmware::calibrate_on(m, &elf, &shifts)?;
            for p in &c.points {
                println!(
                    "shift={} iterations={} instructions={} ticks={} instructions/tick={:.4}",
                    p.shift,
                    p.iterations,
                    p.instructions,
                    p.ticks,
                    f64::from(p.instructions) / f64::from(p.ticks)
                );
            }
            for (shift, m, e) in &c.slopes {
                println!(
                    "shift={shift}: slope {m:.6} instructions/tick, expected 40/2^{shift} = {e:.6}"
                );
            }
            Ok(())
        }
        Task::Bench {
            steps,
            shift,
            image,
            gradient,
            window,
        } => {
            firmware::ensure_tools()?;
            let e = estimator(gradient);
            let img = firmware::build_image(image.machine(), image.number())?;
            println!("{}, estimator: {}", img.describe(), e.name());
            let b = firmware::bench_all(&img, steps, shift, window.map(Window::name), e)?;
            firmware::print_bench(&b);
            Ok(())
        }
        Task::Replay { full, image } => {
            firmware::ensure_tools()?;
            let img = firmware::build_image(image.machine(), image.number())?;
            println!("{}", img.describe());
            let mut ok = true;
            for s in [firmware::dive_tap(), firmware::sve_line()] {
                let r = firmware::replay_image(&img, &s, full)?;
                println!(
                    "replay {}: {} samples, {:.0} samples/s, bit-identical {}, {} records \
                     identical {}, reproduces the closed-loop recording {}, link: {}",
                    r.name,
                    r.samples,
                    r.samples_per_s,
                    r.bit_identical,
                    r.records,
                    r.records_identical,
                    r.reproduces_recording,
                    r.stats
                );
                ok &= r.bit_identical && r.records_identical;
            }
            if ok {
                Ok(())
            } else {
                Err("replay is not bit-identical".into())
            }
        }
        Task::FirmwareReport { json, no_replay } => {
            firmware::firmware_report(json.as_deref(), !no_replay)
        }
        Task::Schemas => xtask::firmware_report::write_schemas(),
        Task::Test => xtask::suite::run_all(),
        Task::FirmwareTest => firmware::firmware_tests(),
        Task::PythonTest => xtask::suite::python_tests(),
        Task::RefsimTest => xtask::suite::refsim_tests(),
        Task::FlashStm32h743 { chip } => firmware::flash_stm32h743(&chip),
        Task::LinkThroughput => firmware::link_throughput(),
        Task::Lockstep => firmware::lockstep().map(|_| ()),
        Task::Profile {
            window,
            steps,
            image,
            gradient,
        } => {
            firmware::ensure_tools()?;
            let e = estimator(gradient);
            let img = firmware::build_image(image.machine(), image.number())?;
            println!("{}, estimator: {}", img.describe(), e.name());
            firmware::profile_image(&img, window.name(), steps, e)
        }
        Task::CoreDigest { bless } => xtask::digest::run(bless),
        Task::Defmt { elf, stream } => {
            for l in firmware::decode_defmt(&elf, &stream)? {
                println!("{l}");
            }
            Ok(())
        }
        Task::Fuzz { seconds, target } => xtask::fuzz::run(seconds, target.as_deref()).map(|_| ()),
    }
}

fn main() -> ExitCode {
    // An unknown task or flag exits here with the usage (clap's exit code 2).
    let cli = Cli::parse();
    match run(cli.task) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn an_unknown_flag_or_task_is_an_error() {
        for bad in [
            &["cargo xtask", "bench", "--bogus"][..],
            &["cargo xtask", "tset"],
            &["cargo xtask", "bench", "--window", "sve"],
            &["cargo xtask", "qemu-smoke", "--steps", "many"],
        ] {
            assert!(Cli::try_parse_from(bad).is_err(), "{bad:?} was accepted");
        }
    }

    #[test]
    fn flags_reach_the_task() {
        let cli =
            Cli::try_parse_from(["cargo xtask", "calibrate", "--shifts", "1,2", "--m3"]).unwrap();
        match cli.task {
            Task::Calibrate { shifts, m3 } => assert!(shifts == [1, 2] && m3),
            _ => panic!("parsed as another task"),
        }
        let cli = Cli::try_parse_from([
            "cargo xtask",
            "bench",
            "--window",
            "dive-readout",
            "--m3",
            "--fixed",
        ])
        .unwrap();
        match cli.task {
            Task::Bench {
                window,
                image,
                gradient,
                ..
            } => {
                assert_eq!(window.map(Window::name), Some("dive-readout"));
                assert!(image.m3 && image.fixed && !gradient);
            }
            _ => panic!("parsed as another task"),
        }
    }
}
