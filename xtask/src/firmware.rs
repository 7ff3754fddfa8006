//! Firmware tasks: building both boards, the QEMU smoke test, the zero-panic link check, the
//! SysTick calibration and instruction counts under `-icount`, the replay self-test, and the
//! report.

use crate::telemetry::qemu::{QemuLink, QemuOptions};
use crate::telemetry::{ReplayInput, ReplayOutput};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use visco_firmware::core_glue::{build_core, CoreCommand, LoopCore, StagedConfig};
use visco_firmware::drivers::ad5541;
use visco_firmware::scale::Scale;
use visco_protocol::{
    param, Command as Cmd, Mode, PerSample, StepBlockFrame, StepFrame, Telemetry,
};

/// A task error: a message for the user.
pub type Result<T> = std::result::Result<T, String>;

/// The Cortex-M7 target both boards build for.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// The Cortex-M3 target (issue 8's fixed-point build).
pub const TARGET_M3: &str = "thumbv7m-none-eabi";

/// An emulated machine and the target its image is built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Machine {
    /// QEMU machine.
    pub machine: &'static str,
    /// QEMU CPU.
    pub cpu: &'static str,
    /// Rust target.
    pub target: &'static str,
}

/// Cortex-M7 with FPU (the product's core): QEMU mps2-an500.
pub const M7: Machine = Machine {
    machine: "mps2-an500",
    cpu: "cortex-m7",
    target: TARGET,
};
/// Cortex-M3 without FPU (issue 8): QEMU mps2-an385, same peripheral map as the AN500.
pub const M3: Machine = Machine {
    machine: "mps2-an385",
    cpu: "cortex-m3",
    target: TARGET_M3,
};

/// The two boards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Board {
    /// QEMU mps2-an500 (default features).
    Qemu,
    /// STM32H743 (`--no-default-features --features board-stm32h743`).
    Stm32h743,
}

impl Board {
    /// Name used in reports.
    pub fn name(self) -> &'static str {
        match self {
            Board::Qemu => "qemu",
            Board::Stm32h743 => "stm32h743",
        }
    }
    fn features(self) -> &'static [&'static str] {
        match self {
            Board::Qemu => &[],
            Board::Stm32h743 => &["--no-default-features", "--features", "board-stm32h743"],
        }
    }
    /// The flash address range of the board (everything else allocated is RAM).
    fn flash(self) -> std::ops::Range<u64> {
        match self {
            Board::Qemu => 0..0x0040_0000,
            Board::Stm32h743 => 0x0800_0000..0x0820_0000,
        }
    }
}

/// The workspace root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

fn cargo() -> String {
    std::env::var("CARGO").unwrap_or_else(|_| "cargo".into())
}

fn run(cmd: &mut Command) -> Result<()> {
    let shown = format!("{cmd:?}");
    eprintln!("$ {shown}");
    let status = cmd
        .status()
        .map_err(|e| format!("cannot run {shown}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{shown} failed: {status}"))
    }
}

fn output(cmd: &mut Command) -> Result<String> {
    let shown = format!("{cmd:?}");
    let out = cmd
        .output()
        .map_err(|e| format!("cannot run {shown}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{shown} failed: {}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

// ---------------------------------------------------------------- tools

/// Installs what the firmware tasks need when it is missing: the two Cortex-M targets
/// (rustup) and QEMU (apt-get, with sudo when not root). Fails loudly, never skips.
pub fn ensure_tools() -> Result<()> {
    let installed = output(Command::new("rustup").args(["target", "list", "--installed"]))
        .map_err(|e| format!("rustup is needed for the firmware targets: {e}"))?;
    let missing: Vec<&str> = [TARGET, TARGET_M3]
        .into_iter()
        .filter(|t| !installed.lines().any(|l| l.trim() == *t))
        .collect();
    if !missing.is_empty() {
        run(Command::new("rustup")
            .args(["target", "add"])
            .args(&missing))?;
    }
    if Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
    {
        return Ok(());
    }
    eprintln!("qemu-system-arm is missing: installing it with apt-get");
    let root = output(Command::new("id").arg("-u"))
        .map(|s| s.trim() == "0")
        .unwrap_or(false);
    let apt = |args: &[&str]| -> Result<()> {
        if root {
            run(Command::new("apt-get").args(args))
        } else {
            run(Command::new("sudo").arg("apt-get").args(args))
        }
    };
    apt(&["update"])?;
    apt(&["install", "-y", "qemu-system-arm"])?;
    match Command::new("qemu-system-arm").arg("--version").output() {
        Ok(o) if o.status.success() => Ok(()),
        _ => Err("qemu-system-arm is still missing after apt-get install".into()),
    }
}

// ---------------------------------------------------------------- builds

/// Builds the firmware for `board` in release, with extra features; returns the ELF path.
pub fn build(board: Board, extra_features: &[&str]) -> Result<PathBuf> {
    build_for(TARGET, board, extra_features)
}

/// [`build`] for another target (the QEMU board also builds for `thumbv7m-none-eabi`).
pub fn build_for(target: &str, board: Board, extra_features: &[&str]) -> Result<PathBuf> {
    let mut cmd = Command::new(cargo());
    cmd.current_dir(root())
        .args([
            "build",
            "--release",
            "-p",
            "visco-firmware",
            "--target",
            target,
        ])
        .args(board.features());
    for f in extra_features {
        cmd.args(["--features", f]);
    }
    run(&mut cmd)?;
    let elf = root()
        .join("target")
        .join(target)
        .join("release")
        .join("visco-firmware");
    // Each board/feature set overwrites the same output name: keep a copy per variant so
    // later steps (sizes, QEMU, defmt decoding) use the right image.
    let mut name = format!("visco-firmware-{}", board.name());
    for f in extra_features {
        name.push('-');
        name.push_str(f);
    }
    let copy = elf.with_file_name(name);
    std::fs::copy(&elf, &copy).map_err(|e| format!("copy {}: {e}", elf.display()))?;
    Ok(copy)
}

/// `cargo xtask firmware`: both boards in release.
pub fn build_all() -> Result<Vec<(Board, PathBuf)>> {
    ensure_tools()?;
    let mut out = Vec::new();
    for b in [Board::Qemu, Board::Stm32h743] {
        let elf = build(b, &[])?;
        let s = sizes(&elf, b)?;
        println!(
            "{}: {} (flash {} bytes, static RAM {} bytes)",
            b.name(),
            elf.display(),
            s.flash,
            s.ram
        );
        out.push((b, elf));
    }
    Ok(out)
}

/// Flash and RAM use of an image.
#[derive(Clone, Copy, Debug, Default)]
pub struct Sizes {
    /// Bytes stored in flash: code, read-only data, and the initial values of `.data` and of
    /// code copied to RAM (ITCM).
    pub flash: u64,
    /// Bytes of RAM taken by statics (`.data`, `.bss`, `.uninit`, ITCM code); the stack
    /// uses the rest.
    pub ram: u64,
}

/// Reads the allocated sections of the ELF (what `size` would report as text+data and
/// data+bss).
pub fn sizes(elf: &Path, board: Board) -> Result<Sizes> {
    use object::{Object, ObjectSection, SectionFlags};
    let data = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let file = object::File::parse(&*data).map_err(|e| format!("{}: {e}", elf.display()))?;
    let flash = board.flash();
    let mut s = Sizes::default();
    for sec in file.sections() {
        let SectionFlags::Elf { sh_flags } = sec.flags() else {
            continue;
        };
        const SHF_ALLOC: u64 = 0x2;
        if sh_flags & SHF_ALLOC == 0 || sec.size() == 0 {
            continue;
        }
        let nobits = sec.kind() == object::SectionKind::UninitializedData;
        if flash.contains(&sec.address()) {
            s.flash += sec.size();
        } else {
            s.ram += sec.size();
            if !nobits {
                // Initial contents are stored in flash and copied at start-up.
                s.flash += sec.size();
            }
        }
    }
    Ok(s)
}

// ---------------------------------------------------------------- defmt

/// Decodes a defmt stream (the QEMU semihosting output) with the image's defmt table.
pub fn decode_defmt(elf: &Path, stream: &Path) -> Result<Vec<String>> {
    let elf_bytes = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let table = defmt_decoder::Table::parse(&elf_bytes)
        .map_err(|e| format!("defmt table of {}: {e}", elf.display()))?
        .ok_or_else(|| format!("{} has no defmt data", elf.display()))?;
    let bytes = std::fs::read(stream).map_err(|e| format!("{}: {e}", stream.display()))?;
    let mut dec = table.new_stream_decoder();
    dec.received(&bytes);
    let mut lines = Vec::new();
    loop {
        match dec.decode() {
            Ok(frame) => lines.push(format!(
                "{} {}",
                frame
                    .level()
                    .map(|l| l.as_str().to_uppercase())
                    .unwrap_or_else(|| "PRINT".into()),
                frame.display_message()
            )),
            Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
            Err(defmt_decoder::DecodeError::Malformed) => {
                return Err(format!("malformed defmt data in {}", stream.display()))
            }
        }
    }
    Ok(lines)
}

// ---------------------------------------------------------------- QEMU sessions

/// Default board configuration sent before measurements and replays: 16-bit converters at
/// 0.1 nm (ADC), 0.2 nm (U DAC) and 1 nm (lateral) per code.
pub const ADC_M_PER_CODE: f64 = 1e-10;
/// See [`ADC_M_PER_CODE`].
pub const DAC_M_PER_CODE: f64 = 2e-10;
/// See [`ADC_M_PER_CODE`].
pub const LATERAL_M_PER_CODE: f64 = 1e-9;
/// Stand-in record length: a record every 500 samples (taps / pixels).
pub const RECORD_EVERY: f64 = 500.0;

fn configure(link: &mut QemuLink) -> Result<()> {
    let e = |e: std::io::Error| e.to_string();
    for (id, v) in [
        (param::ADC_METRES_PER_CODE, ADC_M_PER_CODE),
        (param::DAC_METRES_PER_CODE, DAC_M_PER_CODE),
        (param::LATERAL_METRES_PER_CODE, LATERAL_M_PER_CODE),
        (
            visco_firmware::core_glue::standin_param::RECORD_EVERY,
            RECORD_EVERY,
        ),
    ] {
        link.command_ok(&Cmd::SetParam { id, value: v })
            .map_err(e)?;
    }
    link.command_ok(&Cmd::ApplyConfig).map_err(e)
}

/// The same configuration on the host: the staged values and scales used above.
pub fn host_config() -> (StagedConfig, Scale, Scale) {
    let mut cfg = StagedConfig::new();
    cfg.stage(
        visco_firmware::core_glue::standin_param::RECORD_EVERY,
        RECORD_EVERY,
    );
    let adc = Scale::new_16bit(ADC_M_PER_CODE as f32).expect("valid scale");
    let dac = Scale::new_16bit(DAC_M_PER_CODE as f32).expect("valid scale");
    (cfg, adc, dac)
}

fn spawn(elf: &Path, icount_shift: Option<u32>, tag: &str) -> Result<(QemuLink, PathBuf)> {
    spawn_on(M7, elf, icount_shift, tag)
}

fn spawn_on(
    m: Machine,
    elf: &Path,
    icount_shift: Option<u32>,
    tag: &str,
) -> Result<(QemuLink, PathBuf)> {
    let mut opts = QemuOptions::new(elf);
    opts.machine = m.machine.into();
    opts.cpu = m.cpu.into();
    opts.defmt_out = elf.with_extension(format!("{tag}.defmt"));
    opts.icount_shift = icount_shift;
    opts.timeout = Duration::from_secs(120);
    let link = QemuLink::spawn(&opts).map_err(|e| format!("QEMU ({tag}): {e}"))?;
    Ok((link, opts.defmt_out))
}

fn finish(link: QemuLink, elf: &Path, defmt: &Path) -> Result<Vec<String>> {
    let status = link.exit(0).map_err(|e| e.to_string())?;
    let log = decode_defmt(elf, defmt)?;
    if !status.success() {
        return Err(format!(
            "QEMU exited with {status}; firmware log:\n{}",
            log.join("\n")
        ));
    }
    Ok(log)
}

/// `cargo xtask qemu-smoke`: boots the QEMU image, runs `steps` timer-driven loop samples
/// in each mode, checks the counters, the records and the defmt log, and exits cleanly.
pub fn qemu_smoke(steps: u32) -> Result<()> {
    ensure_tools()?;
    let elf = build(Board::Qemu, &[])?;
    let (mut link, defmt) = spawn(&elf, None, "smoke")?;
    let e = |e: std::io::Error| e.to_string();
    configure(&mut link)?;
    for mode in [Mode::Dive, Mode::Sve] {
        let before = link.status().map_err(e)?.samples;
        link.command_ok(&Cmd::Start(mode)).map_err(e)?;
        // 10 kHz loop (2500 ticks of 25 MHz) in QEMU's virtual time.
        link.command_ok(&Cmd::SetSource(visco_protocol::Source::Timer {
            period_ticks: 2500,
        }))
        .map_err(e)?;
        let deadline = Instant::now() + Duration::from_secs(120);
        let status = loop {
            std::thread::sleep(Duration::from_millis(50));
            let s = link.status().map_err(e)?;
            if s.samples.wrapping_sub(before) >= steps {
                break s;
            }
            if Instant::now() > deadline {
                return Err(format!(
                    "only {} of {steps} loop samples in 120 s",
                    s.samples - before
                ));
            }
        };
        link.command_ok(&Cmd::SetSource(visco_protocol::Source::Timer {
            period_ticks: 0,
        }))
        .map_err(e)?;
        link.command_ok(&Cmd::Stop).map_err(e)?;
        let records = link
            .backlog
            .drain(..)
            .filter(|m| matches!(m, Telemetry::Record(_)))
            .count();
        println!(
            "qemu-smoke {mode:?}: {} samples, {records} records, {} starved, {} telemetry dropped",
            status.samples - before,
            status.starved,
            status.telemetry_dropped
        );
        if status.state == 0 {
            return Err(format!("{mode:?}: the core was not running"));
        }
        if records == 0 {
            return Err(format!("{mode:?}: no records in {steps} samples"));
        }
        if status.starved != 0 || status.telemetry_dropped != 0 {
            return Err(format!("{mode:?}: firmware counted losses: {status:?}"));
        }
    }
    let stats = link.reader.stats();
    if !stats.is_clean() {
        return Err(format!("link not clean: {stats}"));
    }
    let log = finish(link, &elf, &defmt)?;
    for l in &log {
        println!("  defmt: {l}");
    }
    let want = ["visco firmware: board qemu-mps2-an500", "exit 0 after"];
    for w in want {
        if !log.iter().any(|l| l.contains(w)) {
            return Err(format!("defmt log lacks {w:?}"));
        }
    }
    println!("qemu-smoke: ok ({stats})");
    Ok(())
}

// ---------------------------------------------------------------- panic check

/// The symbol the `panic-never` handler references (firmware/src/app.rs).
const PANIC_SYMBOL: &str = "visco_firmware_has_a_reachable_panic_path";

/// `cargo xtask panic-check`: links both boards with a panic handler that references an
/// undefined symbol, so any panic path left after optimisation fails the link; and checks
/// that the check bites by linking a canary image with one deliberate panic in the loop.
pub fn panic_check() -> Result<()> {
    ensure_tools()?;
    for b in [Board::Qemu, Board::Stm32h743] {
        build(b, &["panic-never"])
            .map_err(|e| format!("{}: a panic path is reachable ({e})", b.name()))?;
        println!("panic-check {}: no reachable panic", b.name());
    }
    // The canary must fail, naming the symbol; otherwise the check proves nothing.
    let mut cmd = Command::new(cargo());
    cmd.current_dir(root())
        .args([
            "build",
            "--release",
            "-p",
            "visco-firmware",
            "--target",
            TARGET,
        ])
        .args(["--features", "panic-never", "--features", "panic-canary"]);
    let out = cmd.output().map_err(|e| e.to_string())?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    if out.status.success() || !stderr.contains(PANIC_SYMBOL) {
        return Err(format!(
            "the panic canary linked (or failed for another reason): the check is broken\n{stderr}"
        ));
    }
    println!("panic-check canary: a deliberate panic in the loop fails the link, as it must");
    Ok(())
}

// ---------------------------------------------------------------- measurement

/// The SysTick clock of mps2-an500 under QEMU: the 25 MHz system clock.
pub const SYSTICK_HZ: f64 = 25e6;

/// Expected instructions per SysTick tick at `-icount shift=N`: one instruction every 2^N ns,
/// one tick every 40 ns.
pub fn expected_insns_per_tick(shift: u32) -> f64 {
    1e9 / SYSTICK_HZ / f64::from(1u32 << shift)
}

/// One calibration point.
#[derive(Clone, Copy, Debug)]
pub struct CalPoint {
    /// icount shift.
    pub shift: u32,
    /// Loop iterations.
    pub iterations: u32,
    /// Instructions between the SysTick reads (2 per iteration + 1).
    pub instructions: u32,
    /// Ticks measured.
    pub ticks: u32,
}

/// The calibration: per shift, the measured instructions per tick (slope between two loop
/// lengths, so fixed costs cancel) and the raw points.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Raw points.
    pub points: Vec<CalPoint>,
    /// (shift, measured instructions per tick from the slope, expected).
    pub slopes: Vec<(u32, f64, f64)>,
}

/// `cargo xtask calibrate`: runs the counted `subs`/`bne` loop at several lengths and icount
/// shifts and checks ticks × 40 / 2^shift = instructions.
pub fn calibrate(elf: &Path, shifts: &[u32]) -> Result<Calibration> {
    calibrate_on(M7, elf, shifts)
}

/// [`calibrate`] on a given machine.
pub fn calibrate_on(m: Machine, elf: &Path, shifts: &[u32]) -> Result<Calibration> {
    let e = |e: std::io::Error| e.to_string();
    let mut points = Vec::new();
    let mut slopes = Vec::new();
    for &shift in shifts {
        let (mut link, defmt) = spawn_on(m, elf, Some(shift), &format!("cal{shift}"))?;
        // Keep the window below 2^24 ticks (SysTick is 24 bits).
        let max_insns = (expected_insns_per_tick(shift) * 15e6) as u64;
        let big = (max_insns / 2).min(2_000_000) as u32;
        let mut pts = Vec::new();
        for iterations in [big / 10, big / 2, big] {
            link.command_ok(&Cmd::Calibrate { iterations }).map_err(e)?;
            let c = link
                .backlog
                .drain(..)
                .find_map(|m| match m {
                    Telemetry::Calibration(c) => Some(c),
                    _ => None,
                })
                .ok_or("no Calibration frame")?;
            if c.ticks == 0 {
                return Err(format!("calibration window wrapped at shift {shift}"));
            }
            pts.push(CalPoint {
                shift,
                iterations: c.iterations,
                instructions: c.instructions,
                ticks: c.ticks,
            });
        }
        finish(link, elf, &defmt)?;
        let (a, b) = (pts[0], pts[2]);
        let slope = f64::from(b.instructions - a.instructions) / f64::from(b.ticks - a.ticks);
        slopes.push((shift, slope, expected_insns_per_tick(shift)));
        points.extend(pts);
    }
    Ok(Calibration { points, slopes })
}

/// Result of one instruction-count measurement.
#[derive(Clone, Copy, Debug)]
pub struct BenchResult {
    /// Mode (`None`: core stopped, the interrupt's cost around `step`).
    pub mode: Option<Mode>,
    /// icount shift used.
    pub shift: u32,
    /// Loop interrupts measured.
    pub steps: u32,
    /// Ticks of the window.
    pub ticks: u32,
    /// Idle iterations in the window.
    pub idle_iterations: u32,
    /// Instructions per loop interrupt (everything the interrupt executes).
    pub insns_per_step: f64,
    /// Resolution of the figure: one tick's worth of instructions divided by the steps.
    pub resolution: f64,
}

/// Measures instructions per loop interrupt in `mode` with `steps` timer-driven samples
/// at `-icount shift=shift`.
pub fn bench(elf: &Path, mode: Option<Mode>, steps: u32, shift: u32) -> Result<BenchResult> {
    bench_on(M7, elf, mode, steps, shift)
}

/// [`bench`] on a given machine (the image must be built for its target).
pub fn bench_on(
    m: Machine,
    elf: &Path,
    mode: Option<Mode>,
    steps: u32,
    shift: u32,
) -> Result<BenchResult> {
    let e = |e: std::io::Error| e.to_string();
    let (mut link, defmt) = spawn_on(m, elf, Some(shift), &format!("bench-{mode:?}"))?;
    configure(&mut link)?;
    let ipt = expected_insns_per_tick(shift);
    // A period long enough for any interrupt of < 2000 instructions.
    let period_ticks = ((4000.0 / ipt).ceil() as u32).max(4);
    link.command_ok(&Cmd::Bench {
        mode,
        steps,
        period_ticks,
    })
    .map_err(e)?;
    let b = link
        .backlog
        .drain(..)
        .find_map(|m| match m {
            Telemetry::Bench(b) => Some(b),
            _ => None,
        })
        .ok_or("no Bench frame")?;
    finish(link, elf, &defmt)?;
    if b.ticks == 0 {
        return Err("bench window wrapped SysTick".into());
    }
    let total = f64::from(b.ticks) * ipt;
    let idle = f64::from(b.idle_iterations) * f64::from(b.idle_insns_per_iteration)
        + f64::from(b.fixed_insns);
    Ok(BenchResult {
        mode,
        shift,
        steps: b.steps,
        ticks: b.ticks,
        idle_iterations: b.idle_iterations,
        insns_per_step: (total - idle) / f64::from(b.steps),
        resolution: ipt / f64::from(b.steps),
    })
}

// ---------------------------------------------------------------- replay

/// A deterministic test input of `n` ADC codes: a tap-like ramp with a tone and noise.
pub fn test_codes(n: usize) -> Vec<i16> {
    let mut x: u32 = 0x1234_5678;
    (0..n)
        .map(|i| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let ramp = ((i % 4000) as i32 - 2000) * 8;
            let tone = ((i as i32 * 37) % 600) - 300;
            let noise = (x % 64) as i32 - 32;
            (ramp + tone + noise).clamp(-32768, 32767) as i16
        })
        .collect()
}

/// The host build of the same loop on the same input: code → metres (ADC scale), the core,
/// the DAC word; what the firmware's Step frames must equal bit for bit.
pub fn host_reference(codes: &[i16], mode: Mode) -> Result<Vec<StepFrame>> {
    let (cfg, adc, dac) = host_config();
    let mut core = build_core(&cfg, &dac).map_err(|e| format!("host core: {e:?}"))?;
    core.command(CoreCommand::Start(mode));
    Ok(codes
        .iter()
        .enumerate()
        .map(|(i, &c)| {
            let d = adc.to_metres(c as i32);
            let o = core.step(d);
            StepFrame {
                index: i as u32,
                d_m: d,
                u_code: o.u_code,
                dac_word: ad5541::word_for(o.u_code),
                u_m: o.u_m,
                x_m: o.x_m,
                y_m: o.y_m,
                status: o.status,
                estimates: core.estimates(),
            }
        })
        .collect())
}

/// Compares bit for bit; returns the first differing sample index and a description.
pub fn first_difference(a: &[StepFrame], b: &[StepFrame]) -> Option<(usize, String)> {
    let bits = |s: &StepFrame| {
        (
            s.index,
            s.d_m.to_bits(),
            s.u_code,
            s.dac_word,
            s.u_m.to_bits(),
            s.x_m.to_bits(),
            s.y_m.to_bits(),
            s.status,
            s.estimates.map(f32::to_bits),
        )
    };
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        if bits(x) != bits(y) {
            return Some((i, format!("firmware {x:?}\n host    {y:?}")));
        }
    }
    if a.len() != b.len() {
        return Some((
            a.len().min(b.len()),
            format!("lengths differ: {} vs {}", a.len(), b.len()),
        ));
    }
    None
}

/// Checks compact blocks against the host's full frames: the blocks must cover every sample
/// in order and each must match bit for bit. Returns the first failing sample range.
pub fn check_blocks(blocks: &[StepBlockFrame], reference: &[StepFrame]) -> Option<(usize, String)> {
    let mut next = 0usize;
    for b in blocks {
        let first = b.first_index as usize;
        let end = first + b.len as usize;
        if first != next {
            return Some((next, format!("samples {next}..{first} missing")));
        }
        match reference.get(first..end) {
            Some(r) if b.matches(r) => {}
            Some(_) => {
                let codes = (0..b.len as usize).find(|&i| {
                    b.u_codes[i] != reference[first + i].u_code.clamp(-32768, 32767) as i16
                        || b.status[i] != reference[first + i].status
                });
                return Some((
                    first,
                    match codes {
                        Some(i) => format!(
                            "sample {}: firmware u_code {} status {:#x}, host u_code {} status {:#x}",
                            first + i,
                            b.u_codes[i],
                            b.status[i],
                            reference[first + i].u_code,
                            reference[first + i].status
                        ),
                        None => format!(
                            "samples {first}..{end}: same DAC codes and status, different digest \
                             (U in metres, X/Y or estimates differ): rerun with --full"
                        ),
                    },
                ));
            }
            None => return Some((first, format!("block {first}..{end} beyond the input"))),
        }
        next = end;
    }
    (next != reference.len()).then(|| (next, format!("samples {next}.. missing")))
}

/// One replay under QEMU.
#[derive(Clone, Debug)]
pub struct ReplayResult {
    /// Mode.
    pub mode: Mode,
    /// Samples fed.
    pub samples: usize,
    /// Bit-identical to the host build.
    pub bit_identical: bool,
    /// Samples per second of wall time (feed, step, report).
    pub samples_per_s: f64,
    /// The raw output.
    pub output: ReplayOutput,
}

/// Replays `n` test samples through the QEMU image in `mode` and compares with the host,
/// with compact blocks (`full == false`) or every field of every sample.
pub fn replay(elf: &Path, mode: Mode, n: usize, full: bool) -> Result<ReplayResult> {
    let codes = test_codes(n);
    let (mut link, defmt) = spawn(elf, None, &format!("replay-{mode:?}"))?;
    configure(&mut link)?;
    let per_sample = if full {
        PerSample::Full
    } else {
        PerSample::Blocks
    };
    let out = link
        .replay(ReplayInput::Codes(&codes), mode, per_sample)
        .map_err(|e| format!("replay {mode:?}: {e}"))?;
    finish(link, elf, &defmt)?;
    let reference = host_reference(&codes, mode)?;
    let diff = if full {
        first_difference(&out.steps, &reference)
    } else {
        check_blocks(&out.blocks, &reference)
    };
    if let Some((i, what)) = &diff {
        eprintln!("replay {mode:?}: first difference at sample {i}:\n {what}");
    }
    let status = out.status.unwrap_or_default();
    if !out.stats.is_clean() || status.telemetry_dropped != 0 || status.starved != 0 {
        return Err(format!(
            "replay {mode:?}: losses: link {} / firmware {status:?}",
            out.stats
        ));
    }
    Ok(ReplayResult {
        mode,
        samples: n,
        bit_identical: diff.is_none(),
        samples_per_s: n as f64 / out.elapsed.as_secs_f64(),
        output: out,
    })
}

// ---------------------------------------------------------------- report

/// Everything `firmware-report` measures.
#[derive(Clone, Debug)]
pub struct Report {
    /// Instruction counts (shift 0).
    pub bench: Vec<BenchResult>,
    /// SysTick calibration.
    pub calibration: Calibration,
    /// Image sizes per board.
    pub sizes: Vec<(Board, Sizes)>,
    /// Replays.
    pub replay: Vec<ReplayResult>,
    /// Instruction counts of the `thumbv7m-none-eabi` build (Cortex-M3, soft float).
    pub bench_m3: Vec<BenchResult>,
}

/// Steps measured for the instruction counts.
pub const BENCH_STEPS: u32 = 10_000;

/// Measures everything of the report.
pub fn measure(replay_samples: usize) -> Result<Report> {
    ensure_tools()?;
    let mut sizes_v = Vec::new();
    let mut qemu_elf = None;
    for b in [Board::Qemu, Board::Stm32h743] {
        let elf = build(b, &[])?;
        sizes_v.push((b, sizes(&elf, b)?));
        if b == Board::Qemu {
            qemu_elf = Some(elf);
        }
    }
    let elf = qemu_elf.ok_or("no QEMU image")?;
    let calibration = calibrate(&elf, &[0, 3])?;
    for &(shift, slope, expected) in &calibration.slopes {
        if (slope - expected).abs() > 1e-3 * expected {
            return Err(format!(
                "SysTick calibration at shift {shift}: {slope} instructions per tick, expected \
                 {expected}: the instruction counts would be wrong"
            ));
        }
    }
    let mut bench_v = Vec::new();
    for mode in [None, Some(Mode::Dive), Some(Mode::Sve)] {
        bench_v.push(bench(&elf, mode, BENCH_STEPS, 0)?);
    }
    let elf_m3 = build_for(TARGET_M3, Board::Qemu, &[])?;
    let cal_m3 = calibrate_on(M3, &elf_m3, &[0])?;
    for &(shift, slope, expected) in &cal_m3.slopes {
        if (slope - expected).abs() > 1e-3 * expected {
            return Err(format!(
                "SysTick calibration on mps2-an385 at shift {shift}: {slope} vs {expected}"
            ));
        }
    }
    let mut bench_m3 = Vec::new();
    for mode in [None, Some(Mode::Dive), Some(Mode::Sve)] {
        bench_m3.push(bench_on(M3, &elf_m3, mode, BENCH_STEPS, 0)?);
    }
    let mut replay_v = Vec::new();
    if replay_samples > 0 {
        for mode in [Mode::Dive, Mode::Sve] {
            replay_v.push(replay(&elf, mode, replay_samples, false)?);
        }
    }
    Ok(Report {
        bench: bench_v,
        calibration,
        sizes: sizes_v,
        replay: replay_v,
        bench_m3,
    })
}

impl Report {
    /// The JSON of `firmware-report --json`.
    pub fn json(&self) -> String {
        let mut s = String::from("{\n");
        let per_mode = |f: &dyn Fn(Mode) -> String| {
            format!("{{\"dive\": {}, \"sve\": {}}}", f(Mode::Dive), f(Mode::Sve))
        };
        let ins = |m: Mode| {
            self.bench
                .iter()
                .find(|b| b.mode == Some(m))
                .map(|b| format!("{}", b.insns_per_step.round() as i64))
                .unwrap_or_else(|| "null".into())
        };
        let _ = writeln!(s, "  \"instructions_per_step\": {},", per_mode(&ins));
        let exact = |m: Mode| {
            self.bench
                .iter()
                .find(|b| b.mode == Some(m))
                .map(|b| format!("{:.3}", b.insns_per_step))
                .unwrap_or_else(|| "null".into())
        };
        let _ = writeln!(
            s,
            "  \"instructions_per_step_exact\": {},",
            per_mode(&exact)
        );
        let overhead = |v: &[BenchResult]| {
            v.iter()
                .find(|b| b.mode.is_none())
                .map(|b| format!("{:.3}", b.insns_per_step))
                .unwrap_or_else(|| "null".into())
        };
        let _ = writeln!(
            s,
            "  \"instructions_per_step_core_stopped\": {},",
            overhead(&self.bench)
        );
        let rep = |m: Mode| self.replay.iter().find(|r| r.mode == m);
        let _ = writeln!(
            s,
            "  \"replay_bit_identical\": {},",
            per_mode(&|m| rep(m)
                .map(|r| r.bit_identical.to_string())
                .unwrap_or_else(|| "null".into()))
        );
        let _ = writeln!(
            s,
            "  \"replay_samples\": {},",
            per_mode(&|m| rep(m)
                .map(|r| r.samples.to_string())
                .unwrap_or_else(|| "0".into()))
        );
        let _ = writeln!(
            s,
            "  \"replay_samples_per_s\": {},",
            per_mode(&|m| rep(m)
                .map(|r| format!("{:.0}", r.samples_per_s))
                .unwrap_or_else(|| "null".into()))
        );
        let product = self
            .sizes
            .iter()
            .find(|(b, _)| *b == Board::Stm32h743)
            .map(|(_, s)| *s)
            .unwrap_or_default();
        let _ = writeln!(s, "  \"flash_bytes\": {},", product.flash);
        let _ = writeln!(s, "  \"ram_bytes\": {},", product.ram);
        let _ = writeln!(s, "  \"sizes_board\": \"stm32h743\",");
        let sizes: Vec<String> = self
            .sizes
            .iter()
            .map(|(b, z)| {
                format!(
                    "\"{}\": {{\"flash_bytes\": {}, \"ram_bytes\": {}}}",
                    b.name(),
                    z.flash,
                    z.ram
                )
            })
            .collect();
        let _ = writeln!(s, "  \"sizes\": {{{}}},", sizes.join(", "));
        let _ = writeln!(s, "  \"core\": \"{}\",", core_name());
        let m3 = |m: Mode| {
            self.bench_m3
                .iter()
                .find(|b| b.mode == Some(m))
                .map(|b| format!("{}", b.insns_per_step.round() as i64))
                .unwrap_or_else(|| "null".into())
        };
        let _ = writeln!(
            s,
            "  \"cortex_m3\": {{\"target\": \"{TARGET_M3}\", \"machine\": \"mps2-an385\", \
             \"number_format\": \"f32 (soft float)\", \"instructions_per_step\": {}, \
             \"instructions_per_step_core_stopped\": {}}},",
            per_mode(&m3),
            overhead(&self.bench_m3)
        );
        let _ = writeln!(
            s,
            "  \"method\": {{\"machine\": \"qemu-system-arm -machine mps2-an500 -cpu cortex-m7\", \
             \"icount_shift\": 0, \"steps\": {BENCH_STEPS}, \"systick_hz\": {SYSTICK_HZ}, \
             \"what\": \"instructions per loop interrupt: timer-driven interrupts, SysTick around \
             the window, minus the counted idle loop\"}},"
        );
        let slopes: Vec<String> = self
            .calibration
            .slopes
            .iter()
            .map(|(shift, m, e)| {
                format!(
                    "{{\"icount_shift\": {shift}, \"instructions_per_tick\": {m:.6}, \"expected\": {e:.6}}}"
                )
            })
            .collect();
        let _ = writeln!(s, "  \"calibration\": [{}]", slopes.join(", "));
        s.push_str("}\n");
        s
    }
}

fn core_name() -> &'static str {
    match visco_firmware::core_glue::CORE_ID {
        0 => "stand-in",
        _ => "visco-core",
    }
}

/// `cargo xtask firmware-report --json FILE`.
pub fn firmware_report(json: Option<&Path>, replay_samples: usize) -> Result<()> {
    let r = measure(replay_samples)?;
    for c in &r.calibration.points {
        println!(
            "calibration shift={} iterations={} instructions={} ticks={}",
            c.shift, c.iterations, c.instructions, c.ticks
        );
    }
    for (shift, m, e) in &r.calibration.slopes {
        println!("calibration shift={shift}: {m:.6} instructions/tick (expected {e:.6})");
    }
    let name = |m: Option<Mode>| m.map_or("core stopped".to_string(), |m| format!("{m:?}"));
    for b in &r.bench {
        println!(
            "{}: {:.3} instructions per loop interrupt (±{:.3}; {} steps, {} ticks, {} idle iterations, shift {}) [{} core]",
            name(b.mode), b.insns_per_step, b.resolution, b.steps, b.ticks, b.idle_iterations, b.shift, core_name()
        );
    }
    for (b, s) in &r.sizes {
        println!(
            "{}: flash {} bytes, static RAM {} bytes",
            b.name(),
            s.flash,
            s.ram
        );
    }
    for p in &r.replay {
        println!(
            "replay {:?}: {} samples, bit-identical {}, {:.0} samples/s, {}",
            p.mode, p.samples, p.bit_identical, p.samples_per_s, p.output.stats
        );
    }
    let j = r.json();
    match json {
        Some(path) => {
            std::fs::write(path, &j).map_err(|e| format!("{}: {e}", path.display()))?;
            println!("wrote {}", path.display());
        }
        None => print!("{j}"),
    }
    Ok(())
}

// ---------------------------------------------------------------- the test entry

/// Everything firmware-side that `cargo xtask test` runs: the firmware library's host tests,
/// both boards built, the zero-panic link check, the QEMU smoke test, the SysTick
/// calibration, a bit-identical replay in both modes, and a short closed-loop lockstep run.
pub fn firmware_tests() -> Result<()> {
    ensure_tools()?;
    run(Command::new(cargo()).current_dir(root()).args([
        "test",
        "-p",
        "visco-firmware",
        "-p",
        "visco-protocol",
    ]))?;
    build_all()?;
    panic_check()?;
    qemu_smoke(20_000)?;
    let elf = build(Board::Qemu, &[])?;
    let cal = calibrate(&elf, &[0])?;
    for (shift, m, e) in &cal.slopes {
        if (m - e).abs() > 1e-3 * e {
            return Err(format!("SysTick calibration at shift {shift}: {m} vs {e}"));
        }
    }
    for mode in [Mode::Dive, Mode::Sve] {
        let r = replay(&elf, mode, 20_000, false)?;
        println!(
            "replay {mode:?}: {} samples, {:.0} samples/s, bit-identical {}",
            r.samples, r.samples_per_s, r.bit_identical
        );
        if !r.bit_identical {
            return Err(format!("replay {mode:?} is not bit-identical"));
        }
    }
    lockstep(2_000)?;
    println!("firmware tests: ok");
    Ok(())
}

/// `cargo xtask link-throughput`: measures the two directions of the QEMU UART link
/// separately (diagnostic for the replay speed).
pub fn link_throughput() -> Result<()> {
    use visco_protocol::{FeedBlock, FeedSamples, Source, MAX_FEED};
    let e = |e: std::io::Error| e.to_string();
    ensure_tools()?;
    let elf = build(Board::Qemu, &[])?;
    // Firmware → host: Step frames produced by the timer-driven loop at 250 kHz (virtual).
    let (mut link, defmt) = spawn(&elf, None, "tx")?;
    configure(&mut link)?;
    link.command_ok(&Cmd::SetTelemetry {
        per_sample: PerSample::Full,
        status_every: 0,
    })
    .map_err(e)?;
    link.command_ok(&Cmd::Start(Mode::Dive)).map_err(e)?;
    link.command_ok(&Cmd::SetSource(visco_protocol::Source::Timer {
        period_ticks: 100,
    }))
    .map_err(e)?;
    let t = Instant::now();
    let mut frames = 0u64;
    while t.elapsed() < Duration::from_secs(3) {
        if let Ok(Telemetry::Step(_)) = link.next_message() {
            frames += 1;
        }
    }
    let secs = t.elapsed().as_secs_f64();
    link.command_ok(&Cmd::SetSource(visco_protocol::Source::Timer {
        period_ticks: 0,
    }))
    .map_err(e)?;
    link.command_ok(&Cmd::SetTelemetry {
        per_sample: PerSample::Off,
        status_every: 0,
    })
    .map_err(e)?;
    let st = link.status().map_err(e)?;
    println!(
        "firmware → host: {:.0} Step frames/s ({:.0} bytes/s); loop ran {} samples, {} telemetry items dropped (counted)",
        frames as f64 / secs,
        link.reader.stats().bytes as f64 / secs,
        st.samples,
        st.telemetry_dropped
    );
    link.backlog.clear();
    // Host → firmware: replay blocks without per-sample telemetry.
    link.command_ok(&Cmd::SetSource(Source::Feed)).map_err(e)?;
    let n: usize = std::env::var("VISCO_RX_SAMPLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000);
    let before = link.status().map_err(e)?.samples;
    let t = Instant::now();
    let mut first = 0;
    while first < n {
        let len = (n - first).min(MAX_FEED);
        link.writer
            .send(&Cmd::Feed(FeedBlock {
                first_index: first as u32,
                len: len as u8,
                samples: FeedSamples::Codes([7; MAX_FEED]),
            }))
            .map_err(e)?;
        first += len;
    }
    loop {
        let s = link.status().map_err(e)?;
        if s.samples.wrapping_sub(before) as usize >= n {
            break;
        }
    }
    let secs = t.elapsed().as_secs_f64();
    println!(
        "host → firmware: {:.0} samples/s ({:.0} bytes/s)",
        n as f64 / secs,
        (n as f64 * 2.2) / secs
    );
    finish(link, &elf, &defmt)?;
    Ok(())
}

/// `cargo xtask flash-stm32h743 [--chip NAME]`: builds the STM32H743 image and runs it on a
/// connected board with probe-rs (flash, reset, defmt over RTT on the terminal).
pub fn flash_stm32h743(chip: &str) -> Result<()> {
    ensure_tools()?;
    let elf = build(Board::Stm32h743, &[])?;
    if Command::new("probe-rs").arg("--version").output().is_err() {
        return Err(format!(
            "probe-rs is not installed; install it (`cargo install probe-rs-tools --locked`) \
             and rerun, or flash {} with your own tool",
            elf.display()
        ));
    }
    run(Command::new("probe-rs")
        .args(["run", "--chip", chip])
        .arg(&elf))
}

/// `cargo xtask lockstep [--samples N]`: closed-loop transport check. A toy plant on the host
/// (D follows the firmware's U through a first-order lag) runs in lockstep with the firmware
/// under QEMU, one UART round trip per sample; the host reference runs the same plant with
/// the host build of the loop, and the two trajectories must be bit-identical.
pub fn lockstep(n: usize) -> Result<()> {
    let e = |e: std::io::Error| e.to_string();
    ensure_tools()?;
    let elf = build(Board::Qemu, &[])?;
    let (mut link, defmt) = spawn(&elf, None, "lockstep")?;
    configure(&mut link)?;
    let plant = |d: f32, u: f32| d + 0.05 * (0.5 * u - d);
    link.start_lockstep(Mode::Sve).map_err(e)?;
    let t = Instant::now();
    let mut d = 1e-9f32;
    let mut fw = Vec::with_capacity(n);
    for _ in 0..n {
        let s = link.lockstep(d).map_err(e)?;
        d = plant(d, s.u_m);
        fw.push(s);
    }
    let secs = t.elapsed().as_secs_f64();
    finish(link, &elf, &defmt)?;
    let (cfg, _adc, dac) = host_config();
    let mut core = build_core(&cfg, &dac).map_err(|e| format!("{e:?}"))?;
    core.command(CoreCommand::Start(Mode::Sve));
    let mut d = 1e-9f32;
    let mut host = Vec::with_capacity(n);
    for i in 0..n {
        let o = core.step(d);
        host.push(StepFrame {
            index: i as u32,
            d_m: d,
            u_code: o.u_code,
            dac_word: ad5541::word_for(o.u_code),
            u_m: o.u_m,
            x_m: o.x_m,
            y_m: o.y_m,
            status: o.status,
            estimates: core.estimates(),
        });
        d = plant(d, o.u_m);
    }
    match first_difference(&fw, &host) {
        None => {
            println!(
                "lockstep: {n} closed-loop samples in {secs:.2} s = {:.0} samples/s, bit-identical",
                n as f64 / secs
            );
            Ok(())
        }
        Some((i, what)) => Err(format!("lockstep differs at sample {i}:\n{what}")),
    }
}
