//! `cargo xtask <task>`: see `usage()`.

use std::path::PathBuf;
use std::process::ExitCode;
use xtask::firmware;

fn usage() -> &'static str {
    "usage: cargo xtask <task>
  firmware                      build both boards (qemu, stm32h743) in release, print sizes
  qemu-smoke [--steps N]        boot the QEMU image, run N loop samples per mode, check the log
  panic-check                   prove no panic path is linked (panic-never handler + canary)
  calibrate [--shifts 0,3,6] [--m3]
                                SysTick ticks vs counted instructions under -icount
  bench [--steps N] [--shift S] [--m3] [--fixed] [--gradient]
        [--window idle|dive-dwell|dive-readout|sve-scan]
                                instructions per loop interrupt: core stopped, DIVE dwell, DIVE
                                read-out, SVE scan, over closed-loop recordings (--m3: the
                                thumbv7m-none-eabi build on mps2-an385, Cortex-M3, soft float;
                                --fixed: the core in Q31.32, feature fixed-point; --gradient:
                                the gradient estimator in both modes)
  replay [--full] [--m3] [--fixed]
                                replay a closed-loop DIVE tap and SVE line through QEMU, compare
                                with the host bit for bit (digests per block, or --full: every
                                field of every sample; --m3 --fixed: the Q31.32 build on the
                                Cortex-M3 against the host's Q31.32 core)
  firmware-report [--json FILE] [--no-replay]
                                all measurements; JSON as documented in firmware/README.md
  test                          everything: install tools, fmt, no_std build, host tests,
                                firmware tests, the Python package (what CI runs)
  firmware-test                 what `cargo xtask test` runs for the firmware
  python-test                   what `cargo xtask test` runs for the Python package (python/)
  flash-stm32h743 [--chip C]    build the STM32H743 image and run it with probe-rs (RTT log)
  link-throughput               diagnostic: each direction of the QEMU UART link alone
  lockstep                      closed loop: host plant ↔ firmware under QEMU, one round trip
                                per sample, an SVE line segment, compared with the host-only run
  profile [--window W] [--steps N] [--m3] [--fixed] [--gradient]
                                executed instructions of the loop interrupt per function and
                                per instruction (QEMU exec log) in a bench window: dive-dwell,
                                dive-readout, sve-scan
  core-digest                   CRC-32 of every output of closed-loop runs of the host core
                                (equal before and after a core change: bit-identical results)
  defmt ELF STREAM              decode a defmt stream (e.g. QEMU semihosting output)
  fuzz [--seconds N] [--target T]
                                every host parser under libFuzzer (cargo-fuzz, nightly; installs
                                cargo-fuzz), seeded with the real recordings; N s per target"
}

fn arg_value(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn num<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> Result<T, String> {
    match arg_value(args, name) {
        None => Ok(default),
        Some(v) => v
            .parse()
            .map_err(|_| format!("{name} needs a number, got {v:?}")),
    }
}

/// `--m3`: the Cortex-M3 build on mps2-an385; else the Cortex-M7 on mps2-an500.
fn machine(args: &[String]) -> firmware::Machine {
    if args.iter().any(|a| a == "--m3") {
        firmware::M3
    } else {
        firmware::M7
    }
}

/// `--fixed`: the core in Q31.32 (feature `fixed-point`); else f32.
fn number(args: &[String]) -> firmware::Number {
    if args.iter().any(|a| a == "--fixed") {
        firmware::Number::Q32
    } else {
        firmware::Number::F32
    }
}

/// `--gradient`: the gradient estimator in both modes; else least squares.
fn estimator(args: &[String]) -> firmware::Estimator {
    if args.iter().any(|a| a == "--gradient") {
        firmware::Estimator::Gradient
    } else {
        firmware::Estimator::LeastSquares
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(task) = args.first().cloned() else {
        eprintln!("{}", usage());
        return ExitCode::FAILURE;
    };
    let rest = &args[1..];
    let result = (|| -> Result<(), String> {
        match task.as_str() {
            "firmware" => firmware::build_all().map(|_| ()),
            "qemu-smoke" => firmware::qemu_smoke(num(rest, "--steps", 30_000)?),
            "panic-check" => firmware::panic_check(),
            "calibrate" => {
                firmware::ensure_tools()?;
                let shifts: Vec<u32> = arg_value(rest, "--shifts")
                    .unwrap_or_else(|| "0,3,6".into())
                    .split(',')
                    .map(|s| s.trim().parse().map_err(|_| format!("bad shift {s:?}")))
                    .collect::<Result<_, _>>()?;
                let m = if rest.iter().any(|a| a == "--m3") {
                    firmware::M3
                } else {
                    firmware::M7
                };
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
                    println!("shift={shift}: slope {m:.6} instructions/tick, expected 40/2^{shift} = {e:.6}");
                }
                Ok(())
            }
            "bench" => {
                firmware::ensure_tools()?;
                let steps = num(rest, "--steps", firmware::BENCH_STEPS)?;
                let shift = num(rest, "--shift", 0u32)?;
                let e = estimator(rest);
                let img = firmware::build_image(machine(rest), number(rest))?;
                println!("{}, estimator: {}", img.describe(), e.name());
                let b = firmware::bench_all(
                    &img,
                    steps,
                    shift,
                    arg_value(rest, "--window").as_deref(),
                    e,
                )?;
                firmware::print_bench(&b);
                Ok(())
            }
            "replay" => {
                firmware::ensure_tools()?;
                let img = firmware::build_image(machine(rest), number(rest))?;
                println!("{}", img.describe());
                let mut ok = true;
                for s in [firmware::dive_tap(), firmware::sve_line()] {
                    let r = firmware::replay_image(&img, &s, rest.iter().any(|a| a == "--full"))?;
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
            "firmware-report" => firmware::firmware_report(
                arg_value(rest, "--json").map(PathBuf::from).as_deref(),
                !rest.iter().any(|a| a == "--no-replay"),
            ),
            "firmware-test" => firmware::firmware_tests(),
            "python-test" => xtask::suite::python_tests(),
            // Placeholder until the workspace's own `test` task lands: the host tests of the
            // default members, then the firmware tests.
            "test" => xtask::suite::run_all(),
            "fuzz" => xtask::fuzz::run(
                num(rest, "--seconds", 60u64)?,
                arg_value(rest, "--target").as_deref(),
            )
            .map(|_| ()),
            "link-throughput" => firmware::link_throughput(),
            "lockstep" => firmware::lockstep().map(|_| ()),
            "core-digest" => firmware::core_digest(),
            "profile" => {
                firmware::ensure_tools()?;
                let img = firmware::build_image(machine(rest), number(rest))?;
                println!("{}, estimator: {}", img.describe(), estimator(rest).name());
                firmware::profile_image(
                    &img,
                    &arg_value(rest, "--window").unwrap_or_else(|| "sve-scan".into()),
                    num(rest, "--steps", 200u32)?,
                    estimator(rest),
                )
            }
            "flash-stm32h743" => firmware::flash_stm32h743(
                &arg_value(rest, "--chip").unwrap_or_else(|| "STM32H743ZITx".into()),
            ),
            "defmt" => {
                let (Some(elf), Some(stream)) = (rest.first(), rest.get(1)) else {
                    return Err(usage().into());
                };
                for l in firmware::decode_defmt(elf.as_ref(), stream.as_ref())? {
                    println!("{l}");
                }
                Ok(())
            }
            _ => Err(format!("unknown task {task:?}\n{}", usage())),
        }
    })();
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
