//! Hardware-in-the-loop replay of recordings through the firmware under QEMU, the
//! closed-loop (processor-in-the-loop) run, and the host reference both are checked against.
//!
//! * [`simulate`]: the host plant ([`crate::plant::Plant`]) in closed loop with the host
//!   build of the core, with the deflection going through the firmware's ADC path (a 16-bit
//!   code, `code as f32 × metres_per_code`), so that what it logs is exactly what the board
//!   would have measured. It yields a [`Recording`] (the contract's CSV), the per-sample
//!   outputs as the firmware reports them ([`StepFrame`]) and the finished taps and pixels
//!   ([`RecordFrame`]).
//! * [`replay_qemu`]: a recording's D fed sample by sample to the firmware running under
//!   QEMU (`visco replay REC --target qemu`); U codes, status words and estimates compared
//!   bit for bit with [`reference`], the host build of the same core on the same input.
//! * [`lockstep_qemu`]: the firmware in QEMU drives the host plant, one UART round trip per
//!   sample, compared with the host-only run of [`simulate`].
//!
//! Both ends build their `visco_core::Config` with [`core_config`], which is the firmware's
//! own source file (`firmware/src/core_config.rs`) included here: `Config::paper` at the
//! staged sample rate with the staged fields replaced ([`FirmwareConfig`]).
//!
//! The firmware's core runs in f32 or, built with the feature `fixed-point`, in Q31.32
//! (issue 8). The functions ending in `_in` take the number type ([`LoopReal`]: `f32` or
//! `visco_core::fixed::Q32`); the conversions at the loop's edge are the firmware's own
//! source file too ([`core_number`]), so the host reference of either build is bit-identical
//! by construction. The functions without `_in` are the f32 build.

#[path = "../../firmware/src/core_config.rs"]
#[allow(missing_docs)]
pub mod core_config;

#[path = "../../firmware/src/core_number.rs"]
pub mod core_number;

pub use core_number::LoopReal;

use crate::plant::{Plant, PlantConfig};
use crate::recording::{self, Column, Metadata, Recording};
use crate::sample::Sample;
use crate::telemetry::qemu::{QemuLink, QemuOptions};
use crate::telemetry::{
    check_blocks, first_difference, first_record_difference, ReplayInput, ReplayOutput,
};
use core_config::{record_frame, StagedConfig};
use std::error::Error;
use std::path::Path;
use std::time::{Duration, Instant};
use visco_core::{status, Command, Config, ConfigError, Controller, Phase};
use visco_protocol::{param, Command as Cmd, Mode, PerSample, RecordFrame, StepFrame, Telemetry};

/// Any error of this module, as a message.
pub type Result<T> = std::result::Result<T, Box<dyn Error>>;

/// The core's configuration error as a message (`invalid configuration: `field` = …`).
fn config_error(e: ConfigError) -> Box<dyn Error> {
    e.to_string().into()
}

/// Metadata key of the core fields a recording was made with (`name=value`, space-separated).
pub const CONFIG_KEY: &str = "visco_config";
/// Metadata key of the ADC's metres per code.
pub const ADC_KEY: &str = "adc_metres_per_code";

/// The configuration both ends build from: the staged core fields and the ADC scale.
#[derive(Clone, Copy, Debug, Default)]
pub struct FirmwareConfig {
    /// Core fields replacing those of `Config::paper` (at the staged sample rate).
    pub staged: StagedConfig,
    /// The ADC's metres per code; `None`: the core's full scale over 16 bits.
    pub adc_metres_per_code: Option<f64>,
}

impl FirmwareConfig {
    /// Sets a core field by its dotted name (see [`core_config::PARAMS`]), or
    /// `adc_metres_per_code`.
    pub fn set(&mut self, name: &str, value: f64) -> Result<()> {
        if name == ADC_KEY {
            self.adc_metres_per_code = Some(value);
            return Ok(());
        }
        if self.staged.stage_name(name, value) {
            Ok(())
        } else {
            Err(format!(
                "unknown configuration field `{name}`; known: {ADC_KEY}, {}",
                core_config::PARAMS.join(", ")
            )
            .into())
        }
    }

    /// Applies `name=value`.
    pub fn set_assignment(&mut self, a: &str) -> Result<()> {
        let (name, value) = a
            .split_once('=')
            .ok_or_else(|| format!("`{a}`: expected NAME=VALUE"))?;
        let v: f64 = value
            .trim()
            .parse()
            .map_err(|_| format!("`{a}`: `{value}` is not a number"))?;
        self.set(name.trim(), v)
    }

    /// The core's configuration (validated; the error names the field).
    pub fn core_config(&self) -> std::result::Result<Config, ConfigError> {
        core_config::build_config(&self.staged)
    }

    /// The ADC conversion the firmware will use.
    pub fn adc(&self, cfg: &Config) -> Result<Adc> {
        let m = self
            .adc_metres_per_code
            .unwrap_or_else(|| core_config::default_adc_metres_per_code(cfg));
        let m32 = m as f32;
        if !m32.is_finite() || m32 == 0.0 {
            return Err(format!("{ADC_KEY} = {m}: must be finite and non-zero").into());
        }
        Ok(Adc {
            metres_per_code: m32,
        })
    }

    /// The staged fields as `name=value` pairs, exact (the shortest round-trip notation).
    pub fn to_metadata(&self) -> String {
        let mut out = String::new();
        for (id, v) in self.staged.iter() {
            if !out.is_empty() {
                out.push(' ');
            }
            out.push_str(core_config::param_name(id).unwrap_or("?"));
            out.push('=');
            recording::format_f64(v, &mut out);
        }
        out
    }

    /// Reads what [`Self::to_metadata`] wrote, and the ADC key, from a recording's metadata.
    pub fn from_metadata(meta: &Metadata) -> Result<Self> {
        let mut c = FirmwareConfig::default();
        if let Some(s) = meta.get(CONFIG_KEY) {
            for a in s.split_whitespace() {
                c.set_assignment(a)?;
            }
        }
        if let Some(v) = meta.get(ADC_KEY) {
            c.adc_metres_per_code = Some(
                v.parse()
                    .map_err(|_| format!("metadata {ADC_KEY}: `{v}` is not a number"))?,
            );
        }
        Ok(c)
    }

    /// Sends the configuration to the firmware and applies it (a fresh, idle core).
    pub fn send(&self, link: &mut QemuLink) -> Result<()> {
        if let Some(m) = self.adc_metres_per_code {
            link.command_ok(&Cmd::SetParam {
                id: param::ADC_METRES_PER_CODE,
                value: m,
            })?;
        }
        for (id, value) in self.staged.iter() {
            link.command_ok(&Cmd::SetParam { id, value })?;
        }
        link.command_ok(&Cmd::ApplyConfig)?;
        Ok(())
    }
}

/// The firmware's ADC path on the host: a signed 16-bit code and `code as f32 ×
/// metres_per_code` (one correctly rounded f32 multiplication, as on the target).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adc {
    /// Metres per code, as the firmware holds it (f32).
    pub metres_per_code: f32,
}

impl Adc {
    /// The deflection the firmware computes from `code`.
    pub fn metres(&self, code: i16) -> f32 {
        code as i32 as f32 * self.metres_per_code
    }
    /// The nearest code to `d_m`, saturated to 16 bits.
    pub fn code(&self, d_m: f64) -> i16 {
        let c = (d_m / self.metres_per_code as f64).round();
        c.clamp(-32768.0, 32767.0) as i16
    }
    /// The code whose conversion is exactly `d_m`, if there is one.
    pub fn exact_code(&self, d_m: f64) -> Option<i16> {
        let c = self.code(d_m);
        (self.metres(c) as f64 == d_m).then_some(c)
    }
    /// The code → `R` factor, as the firmware built for `R` computes it.
    pub fn scale<R: LoopReal>(&self) -> Result<R::AdcScale> {
        R::adc_scale(self.metres_per_code).ok_or_else(|| {
            format!(
                "{ADC_KEY} = {:e}: not representable in the {} core",
                self.metres_per_code,
                R::NAME
            )
            .into()
        })
    }
}

/// The AD5541 word for a signed code (as `firmware/src/drivers/ad5541.rs`).
pub fn dac_word(code: i32) -> u16 {
    (code.clamp(-32768, 32767) + 32768) as u16
}

fn core_mode(m: Mode) -> visco_core::Mode {
    match m {
        Mode::Dive => visco_core::Mode::Dive,
        Mode::Sve => visco_core::Mode::Sve,
    }
}

/// One step of the host build, reported as the firmware reports it (`loop_body.rs`).
fn frame<R: LoopReal>(
    index: u32,
    d: R,
    ctrl: &Controller<R>,
    o: &visco_core::StepOut<R>,
) -> StepFrame {
    let [u_m, x_m, y_m] = R::outputs_m(ctrl, o);
    StepFrame {
        index,
        d_m: R::to_metres(d),
        u_code: o.u_code,
        dac_word: dac_word(o.u_code),
        u_m,
        x_m,
        y_m,
        status: o.status,
        estimates: R::estimates_si(ctrl),
    }
}

/// The host build of the firmware's loop on `inputs` (deflections after the ADC path): a
/// fresh controller, `Start(mode)` before the first sample; per-sample frames and records.
pub fn reference(
    cfg: &Config,
    mode: Mode,
    inputs: &[f32],
) -> Result<(Vec<StepFrame>, Vec<RecordFrame>)> {
    reference_in::<f32>(cfg, mode, inputs)
}

/// [`reference`] in the number type `R`; `inputs` as `R::step` takes them
/// ([`Inputs::core_inputs`]).
pub fn reference_in<R: LoopReal>(
    cfg: &Config,
    mode: Mode,
    inputs: &[R],
) -> Result<(Vec<StepFrame>, Vec<RecordFrame>)> {
    let mut ctrl = Controller::<R>::new(cfg).map_err(config_error)?;
    ctrl.command(Command::Start(core_mode(mode)));
    let mut steps = Vec::with_capacity(inputs.len());
    let mut records = Vec::new();
    for (i, &d) in inputs.iter().enumerate() {
        let o = R::step(&mut ctrl, d);
        steps.push(frame(i as u32, d, &ctrl, &o));
        if o.status & status::RECORD_READY != 0 {
            if let Some(r) = R::take_record(&mut ctrl) {
                records.push(record_frame(i as u32, &r));
            }
        }
    }
    Ok((steps, records))
}

/// The plant of an experiment with this core configuration: the paper's instrument with its
/// converters and travel matched to the core's ranges (as `experiment::Setup::paper`).
pub fn plant_config(cfg: &Config) -> PlantConfig {
    let mut plant = PlantConfig::paper();
    let l = &cfg.limits;
    plant.cantilever = cfg.cantilever;
    plant.tip_radius_m = cfg.tip_radius_m;
    plant.time_step_s = 1.0 / cfg.sample_rate_hz;
    plant.adc_deflection.min_m = -l.d_full_scale_m;
    plant.adc_deflection.max_m = l.d_full_scale_m;
    plant.dac_z.min_m = l.u_min_m;
    plant.dac_z.max_m = l.u_max_m;
    plant.dac_z.bits = l.dac_bits;
    plant.travel_z.min_m = l.u_min_m;
    plant.travel_z.max_m = l.u_max_m;
    plant.dac_xy.min_m = l.xy_min_m;
    plant.dac_xy.max_m = l.xy_max_m;
    plant.dac_xy.bits = l.xy_dac_bits;
    plant.travel_xy.min_m = l.xy_min_m;
    plant.travel_xy.max_m = l.xy_max_m;
    plant
}

/// A plant at rest at the approach start above the first tap (as `Setup::build_plant`).
pub fn build_plant(cfg: &Config, sample: &Sample, seed: u64) -> Result<Plant> {
    let mut plant = Plant::new(plant_config(cfg), sample.clone(), seed)?;
    plant.set_time_step(1.0 / cfg.sample_rate_hz)?;
    plant.settle(cfg.approach.u_start_m, cfg.dive.x0_m, cfg.dive.y0_m);
    Ok(plant)
}

/// A closed-loop run on the host.
#[derive(Clone, Debug)]
pub struct Simulation {
    /// The core's configuration.
    pub config: Config,
    /// The ADC conversion used.
    pub adc: Adc,
    /// The recording: U and D at each sample instant (D exactly as the firmware converts it),
    /// lateral position, and the extra columns `u_code` and `status` (of the step taking
    /// that D).
    pub recording: Recording,
    /// The ADC codes, one per sample.
    pub codes: Vec<i16>,
    /// Per-sample outputs as the firmware reports them.
    pub steps: Vec<StepFrame>,
    /// Finished taps and pixels.
    pub records: Vec<RecordFrame>,
}

/// Runs `mode` with the host plant and the host core in closed loop until the sequence is
/// done or `max_samples` have been stepped. The deflection goes through the firmware's ADC
/// path, so replaying the recording through the firmware reproduces the run bit for bit.
pub fn simulate(
    fw: &FirmwareConfig,
    mode: Mode,
    sample: &Sample,
    seed: u64,
    max_samples: usize,
) -> Result<Simulation> {
    simulate_in::<f32>(fw, mode, sample, seed, max_samples)
}

/// [`simulate`] with the core in the number type `R` (the firmware built for it replays the
/// recording bit for bit). The recording's D is the ADC's value in metres either way.
pub fn simulate_in<R: LoopReal>(
    fw: &FirmwareConfig,
    mode: Mode,
    sample: &Sample,
    seed: u64,
    max_samples: usize,
) -> Result<Simulation> {
    let cfg = fw.core_config().map_err(config_error)?;
    let adc = fw.adc(&cfg)?;
    let scale = adc.scale::<R>()?;
    let mut plant = build_plant(&cfg, sample, seed)?;
    let mut ctrl = Controller::<R>::new(&cfg).map_err(config_error)?;
    ctrl.command(Command::Start(core_mode(mode)));
    let fs = cfg.sample_rate_hz;
    let mut meta = Metadata::new(
        match mode {
            Mode::Dive => recording::Mode::Dive,
            Mode::Sve => recording::Mode::Sve,
        },
        fs,
        cfg.cantilever.k_n_per_m,
        cfg.tip_radius_m,
    );
    meta.cantilever_c_ns_per_m = Some(cfg.cantilever.c_ns_per_m);
    meta.cantilever_m_kg = Some(cfg.cantilever.m_kg);
    meta.set(
        "source",
        format!(
            "visco::replay::simulate: host plant (cell phantom, seed {seed}) in closed loop \
             with the host core ({}), D through the firmware's ADC path",
            R::NAME
        ),
    );
    meta.set(CONFIG_KEY, fw.to_metadata());
    meta.set(ADC_KEY, format!("{:e}", adc.metres_per_code as f64));
    let mut rec = Recording::new(meta);
    rec.x_m = Some(Vec::new());
    rec.y_m = Some(Vec::new());
    let mut u_code_col = Vec::new();
    let mut status_col = Vec::new();
    let mut codes = Vec::new();
    let mut steps = Vec::new();
    let mut records = Vec::new();
    // What the DACs held over the period that ends at the sample: the previous step's output.
    let mut held = (R::u_m(&ctrl), cfg.dive.x0_m, cfg.dive.y0_m);
    let mut d_nm = plant.measured_deflection_m() * 1e9;
    for i in 0..max_samples {
        let code = adc.code(d_nm * 1e-9);
        let d = R::from_code(&scale, adc.metres_per_code, code as i32);
        let o = R::step(&mut ctrl, d);
        codes.push(code);
        rec.t_s.push(i as f64 / fs);
        rec.u_m.push(held.0 as f64);
        rec.d_m.push(adc.metres(code) as f64);
        if let (Some(x), Some(y)) = (rec.x_m.as_mut(), rec.y_m.as_mut()) {
            x.push(held.1);
            y.push(held.2);
        }
        u_code_col.push(o.u_code as f64);
        status_col.push(o.status as f64);
        let f = frame(i as u32, d, &ctrl, &o);
        steps.push(f);
        if o.status & status::RECORD_READY != 0 {
            if let Some(r) = R::take_record(&mut ctrl) {
                records.push(record_frame(i as u32, &r));
            }
        }
        if ctrl.phase() == Phase::Done {
            break;
        }
        // The plant moves as the firmware's telemetry says (as in lockstep).
        held = (f.u_m, f.x_m as f64, f.y_m as f64);
        d_nm = plant.step_nm(f.u_m as f64 * 1e9, f.x_m as f64 * 1e9, f.y_m as f64 * 1e9);
    }
    rec.extra = vec![
        Column {
            name: "u_code".into(),
            values: u_code_col,
        },
        Column {
            name: "status".into(),
            values: status_col,
        },
    ];
    Ok(Simulation {
        config: cfg,
        adc,
        recording: rec,
        codes,
        steps,
        records,
    })
}

/// What a replay feeds the firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// ADC codes when every D of the recording is exactly on the ADC's grid, else metres.
    Auto,
    /// ADC codes through the firmware's ADC path (D rounded to the grid if it is not on it).
    Codes,
    /// D in metres (f32), handed to `step` as it is.
    Metres,
}

/// The inputs a replay feeds: codes (if chosen) and the deflections `step` receives.
#[derive(Clone, Debug)]
pub struct Inputs {
    /// `Codes` or `Metres` (resolved).
    pub kind: InputKind,
    /// The codes (empty for metres).
    pub codes: Vec<i16>,
    /// What `step` receives, sample by sample.
    pub d: Vec<f32>,
    /// Samples whose D was not on the ADC grid and was rounded (codes only).
    pub rounded: usize,
}

impl Inputs {
    /// The deflections as the core in `R` receives them: `R::from_code` of the codes, or
    /// `R::from_metres` (for f32 both equal [`Self::d`]).
    pub fn core_inputs<R: LoopReal>(&self, adc: &Adc) -> Result<Vec<R>> {
        Ok(match self.kind {
            InputKind::Codes => {
                let s = adc.scale::<R>()?;
                self.codes
                    .iter()
                    .map(|&c| R::from_code(&s, adc.metres_per_code, c as i32))
                    .collect()
            }
            _ => self.d.iter().map(|&d| R::from_metres(d)).collect(),
        })
    }
}

/// Resolves `kind` for the deflections `d_m` and converts them.
pub fn inputs(d_m: &[f64], adc: &Adc, kind: InputKind) -> Inputs {
    let exact: Option<Vec<i16>> = match kind {
        InputKind::Metres => None,
        _ => d_m.iter().map(|&d| adc.exact_code(d)).collect(),
    };
    match (kind, exact) {
        (InputKind::Metres, _) | (InputKind::Auto, None) => Inputs {
            kind: InputKind::Metres,
            codes: Vec::new(),
            d: d_m.iter().map(|&d| d as f32).collect(),
            rounded: 0,
        },
        (_, Some(codes)) => Inputs {
            kind: InputKind::Codes,
            d: codes.iter().map(|&c| adc.metres(c)).collect(),
            codes,
            rounded: 0,
        },
        (InputKind::Codes, None) => {
            let codes: Vec<i16> = d_m.iter().map(|&d| adc.code(d)).collect();
            let d: Vec<f32> = codes.iter().map(|&c| adc.metres(c)).collect();
            let rounded = d_m
                .iter()
                .zip(&d)
                .filter(|(a, b)| **a != **b as f64)
                .count();
            Inputs {
                kind: InputKind::Codes,
                codes,
                d,
                rounded,
            }
        }
    }
}

/// How QEMU is run.
#[derive(Clone, Debug)]
pub struct Target {
    /// The QEMU board's firmware image.
    pub elf: std::path::PathBuf,
    /// Time allowed for QEMU to start and for any answer.
    pub timeout: Duration,
    /// QEMU machine and CPU: `mps2-an500`/`cortex-m7` (default), or `mps2-an385`/`cortex-m3`
    /// for the `thumbv7m-none-eabi` build.
    pub machine: (String, String),
}

impl Target {
    /// The image at `elf`, 120 s time-out, on the Cortex-M7 machine.
    pub fn new(elf: impl Into<std::path::PathBuf>) -> Self {
        Self {
            elf: elf.into(),
            timeout: Duration::from_secs(120),
            machine: ("mps2-an500".into(), "cortex-m7".into()),
        }
    }

    /// The same on another QEMU machine and CPU.
    pub fn on(mut self, machine: &str, cpu: &str) -> Self {
        self.machine = (machine.into(), cpu.into());
        self
    }

    /// Starts QEMU with the image; the defmt log goes next to the image (`<elf>.<tag>.defmt`).
    pub fn spawn(&self, tag: &str) -> Result<QemuLink> {
        if !self.elf.is_file() {
            return Err(format!(
                "firmware image {} not found: build it with `cargo xtask firmware` (it leaves \
                 target/thumbv7em-none-eabihf/release/visco-firmware-qemu) or pass --elf",
                self.elf.display()
            )
            .into());
        }
        let mut opts = QemuOptions::new(&self.elf);
        opts.defmt_out = self.elf.with_extension(format!("{tag}.defmt"));
        opts.timeout = self.timeout;
        opts.machine = self.machine.0.clone();
        opts.cpu = self.machine.1.clone();
        Ok(QemuLink::spawn(&opts).map_err(|e| format!("QEMU: {e}"))?)
    }

    /// [`Self::spawn`], checking that the firmware's core computes in `R` (its Hello): a
    /// host reference in another number type could never match.
    pub fn spawn_for<R: LoopReal>(&self, tag: &str) -> Result<QemuLink> {
        let link = self.spawn(tag)?;
        if link.core != R::CORE_ID {
            return Err(format!(
                "{} runs core {} but the host reference is {} (core {}): build the firmware \
                 {} the feature `fixed-point`",
                self.elf.display(),
                link.core,
                R::NAME,
                R::CORE_ID,
                if R::CORE_ID == 2 { "with" } else { "without" }
            )
            .into());
        }
        Ok(link)
    }
}

/// The default location of the QEMU image (`cargo xtask firmware` leaves it there), relative
/// to the workspace root.
pub const DEFAULT_ELF: &str = "target/thumbv7em-none-eabihf/release/visco-firmware-qemu";

/// The outcome of a replay.
#[derive(Clone, Debug)]
pub struct ReplayRun {
    /// Mode replayed.
    pub mode: Mode,
    /// What was fed (codes or metres) and how many D had to be rounded to the ADC grid.
    pub input: InputKind,
    /// Samples fed.
    pub samples: usize,
    /// D values rounded to the ADC grid (codes input only).
    pub rounded: usize,
    /// Every per-sample output (U code, DAC word, U, X, Y, status, estimates) identical to
    /// the host build, bit for bit.
    pub bit_identical: bool,
    /// The records (taps, pixels) identical too.
    pub records_identical: bool,
    /// Where and how they first differ.
    pub difference: Option<String>,
    /// Records from the firmware.
    pub records: Vec<RecordFrame>,
    /// The host reference's per-sample outputs.
    pub host: Vec<StepFrame>,
    /// The firmware's per-sample outputs (full frames) or blocks.
    pub firmware: ReplayOutput,
    /// Samples per second of wall time.
    pub samples_per_s: f64,
}

/// Feeds `d_m` to the firmware under QEMU in `mode` and compares with [`reference`].
/// `per_sample`: `Full` (every field of every sample back; ~2 000 samples/s) or `Blocks`
/// (DAC codes, status and a CRC-32 digest per 48 samples; ~10 000 samples/s).
pub fn replay_qemu(
    target: &Target,
    fw: &FirmwareConfig,
    mode: Mode,
    d_m: &[f64],
    kind: InputKind,
    per_sample: PerSample,
) -> Result<ReplayRun> {
    replay_qemu_in::<f32>(target, fw, mode, d_m, kind, per_sample)
}

/// [`replay_qemu`] for the firmware whose core computes in `R`.
pub fn replay_qemu_in<R: LoopReal>(
    target: &Target,
    fw: &FirmwareConfig,
    mode: Mode,
    d_m: &[f64],
    kind: InputKind,
    per_sample: PerSample,
) -> Result<ReplayRun> {
    let cfg = fw.core_config().map_err(config_error)?;
    let adc = fw.adc(&cfg)?;
    let inp = inputs(d_m, &adc, kind);
    let (host, host_records) = reference_in::<R>(&cfg, mode, &inp.core_inputs::<R>(&adc)?)?;
    let mut link = target.spawn_for::<R>(&format!("replay-{mode:?}"))?;
    fw.send(&mut link)?;
    let input = match inp.kind {
        InputKind::Codes => ReplayInput::Codes(&inp.codes),
        _ => ReplayInput::Metres(&inp.d),
    };
    let out = link.replay(input, Some(mode), per_sample, false)?;
    finish(link)?;
    let diff = match per_sample {
        PerSample::Blocks => check_blocks(&out.blocks, &host),
        _ => first_difference(&out.steps, &host),
    };
    let rdiff = first_record_difference(&out.records, &host_records);
    let lost = !out.stats.is_clean();
    let difference = match (&diff, &rdiff) {
        (Some((i, d)), _) => Some(format!("sample {i}: {d}")),
        (None, Some((i, d))) => Some(format!("record {i}: {d}")),
        _ if lost => Some(format!("link not clean: {}", out.stats)),
        _ => None,
    };
    Ok(ReplayRun {
        mode,
        input: inp.kind,
        samples: d_m.len(),
        rounded: inp.rounded,
        bit_identical: diff.is_none() && !lost,
        records_identical: rdiff.is_none(),
        difference,
        records: out.records.clone(),
        host,
        samples_per_s: d_m.len() as f64 / out.elapsed.as_secs_f64().max(1e-9),
        firmware: out,
    })
}

/// Ends QEMU cleanly (the firmware exits through semihosting) and checks its status.
pub fn finish(link: QemuLink) -> Result<()> {
    let status = link.exit(0)?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("QEMU exited with {status}").into())
    }
}

/// The outcome of a closed-loop run.
#[derive(Clone, Debug)]
pub struct LockstepRun {
    /// Samples stepped.
    pub samples: usize,
    /// The firmware's trajectory equals the host-only run bit for bit.
    pub bit_identical: bool,
    /// The records too.
    pub records_identical: bool,
    /// Where they first differ.
    pub difference: Option<String>,
    /// The firmware's records (taps, pixels) in order.
    pub records: Vec<RecordFrame>,
    /// The host-only run's records.
    pub host_records: Vec<RecordFrame>,
    /// Samples per second of wall time (one UART round trip each).
    pub samples_per_s: f64,
    /// The host-only run.
    pub host: Simulation,
}

/// The firmware under QEMU drives the host plant in `mode`, one sample per UART round trip
/// (the ADC code goes down, U, X, Y come back and step the plant), for as many samples as
/// the host-only run of [`simulate`] with the same seed takes (at most `max_samples`); the
/// two trajectories and their records are compared bit for bit.
pub fn lockstep_qemu(
    target: &Target,
    fw: &FirmwareConfig,
    mode: Mode,
    sample: &Sample,
    seed: u64,
    max_samples: usize,
) -> Result<LockstepRun> {
    lockstep_qemu_in::<f32>(target, fw, mode, sample, seed, max_samples)
}

/// [`lockstep_qemu`] for the firmware whose core computes in `R`.
pub fn lockstep_qemu_in<R: LoopReal>(
    target: &Target,
    fw: &FirmwareConfig,
    mode: Mode,
    sample: &Sample,
    seed: u64,
    max_samples: usize,
) -> Result<LockstepRun> {
    let host = simulate_in::<R>(fw, mode, sample, seed, max_samples)?;
    let n = host.steps.len();
    let cfg = &host.config;
    let adc = host.adc;
    let mut plant = build_plant(cfg, sample, seed)?;
    let mut link = target.spawn_for::<R>(&format!("lockstep-{mode:?}"))?;
    fw.send(&mut link)?;
    link.start_lockstep(mode)?;
    let started = Instant::now();
    let mut fw_steps = Vec::with_capacity(n);
    let mut d_nm = plant.measured_deflection_m() * 1e9;
    for i in 0..n {
        let s = link.lockstep_code(adc.code(d_nm * 1e-9))?;
        fw_steps.push(s);
        if i + 1 < n {
            d_nm = plant.step_nm(s.u_m as f64 * 1e9, s.x_m as f64 * 1e9, s.y_m as f64 * 1e9);
        }
    }
    let elapsed = started.elapsed();
    link.command_ok(&Cmd::Stop)?;
    let records: Vec<RecordFrame> = link
        .backlog
        .iter()
        .filter_map(|m| match m {
            Telemetry::Record(r) => Some(*r),
            _ => None,
        })
        .collect();
    finish(link)?;
    let diff = first_difference(&fw_steps, &host.steps);
    let rdiff = first_record_difference(&records, &host.records);
    Ok(LockstepRun {
        samples: n,
        bit_identical: diff.is_none(),
        records_identical: rdiff.is_none(),
        difference: diff
            .map(|(i, d)| format!("sample {i}: {d}"))
            .or(rdiff.map(|(i, d)| format!("record {i}: {d}"))),
        host_records: host.records.clone(),
        records,
        samples_per_s: n as f64 / elapsed.as_secs_f64().max(1e-9),
        host,
    })
}

/// Reads a recording and its configuration metadata (if it carries any).
pub fn read_recording(path: &Path) -> Result<(Recording, FirmwareConfig)> {
    let rec = Recording::read(path)?;
    let fw = FirmwareConfig::from_metadata(&rec.meta)?;
    Ok((rec, fw))
}
