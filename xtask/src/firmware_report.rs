//! The JSON of `cargo xtask firmware-report --json FILE` as typed structs (documented in
//! firmware/README.md), with its JSON Schema (`xtask/schemas/firmware-report.schema.json`,
//! written by `cargo xtask schemas`).
//!
//! Numbers keep the precision the report has always printed (instruction counts to whole
//! instructions, shares to 10⁻³, the calibration to 10⁻⁶): rounded here, written by
//! `serde_json` in its shortest form. A value not measured is `null`.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use visco::report::Ordered;
use visco_protocol::Mode;

use crate::firmware::{
    max_rate_hz, per_mode, BenchResult, FixedPointReport, Report, BENCH_STEPS, FIXED, GOAL_DIVE,
    GOAL_SVE, SYSTICK_HZ,
};
use crate::firmware::{Board, Estimator};

/// The firmware report's `schema_version`.
pub const SCHEMA_VERSION: u32 = 1;

/// `v` rounded to `digits` decimals (the precision the report states).
fn round(v: f64, digits: i32) -> f64 {
    let s = 10f64.powi(digits);
    (v * s).round() / s
}

/// One value per mode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct PerMode<T> {
    pub dive: T,
    pub sve: T,
}

impl<T> PerMode<T> {
    fn of(f: impl Fn(Mode) -> T) -> Self {
        PerMode {
            dive: f(Mode::Dive),
            sve: f(Mode::Sve),
        }
    }
}

/// The whole report.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct FirmwareReport {
    /// Version of this report's layout (1): raised when a field is removed or renamed or changes
    /// meaning or unit; adding a field keeps it.
    pub schema_version: u32,
    /// Instructions per loop interrupt, the worst window of each mode.
    pub instructions_per_step: PerMode<Option<f64>>,
    /// The estimator interrupt's instructions per block (issue 14).
    pub estimator_instructions_per_block: PerMode<Option<f64>>,
    /// Samples per estimator block.
    pub block_samples: PerMode<Option<f64>>,
    /// Instructions per sample, loop and estimator interrupts, the worst window.
    pub instructions_per_sample_avg: PerMode<Option<f64>>,
    /// The fastest loop rate at half of a 400 MHz core (Hz).
    pub max_loop_rate_hz_at_50pct_400mhz: PerMode<Option<f64>>,
    /// The replay's samples and records are bit-identical with the host's.
    pub replay_bit_identical: PerMode<Option<bool>>,
    pub replay_samples: PerMode<u64>,
    /// The product board's (stm32h743) image.
    pub flash_bytes: u64,
    pub ram_bytes: u64,
    /// The fixed-point build and the number-format table (issue 8).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fixed_point: Option<FixedPointJson>,
    pub sizes_board: String,
    /// Image sizes per board.
    pub sizes: Ordered<SizesJson>,
    /// Every measured window.
    pub instructions_windows: Ordered<WindowJson>,
    /// The goals of issue 4, instructions per loop interrupt.
    pub goals: PerMode<f64>,
    pub replay_samples_per_s: PerMode<Option<f64>>,
    pub replay_records: PerMode<Option<u64>>,
    /// The closed-loop SVE run against the host, sample for sample.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lockstep_sve: Option<LockstepJson>,
    pub core: String,
    pub method: MethodJson,
    pub calibration: Vec<SlopeJson>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SizesJson {
    pub flash_bytes: u64,
    pub ram_bytes: u64,
}

/// One measured window (instructions).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct WindowJson {
    pub interrupt: f64,
    pub average_per_sample: f64,
    pub estimator_per_block: Option<f64>,
    pub block_samples: Option<f64>,
    pub step: Option<f64>,
    pub interrupt_besides_step: Option<f64>,
    pub steps: u64,
    pub first_sample: u64,
    pub estimating_share: f64,
    pub readout_share: f64,
    pub records: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct LockstepJson {
    pub samples: u64,
    pub pixels: u64,
    pub bit_identical: bool,
    pub samples_per_s: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct MethodJson {
    pub machine: String,
    pub icount_shift: u32,
    pub steps: u32,
    pub systick_hz: f64,
    pub what: String,
}

/// A SysTick calibration point: instructions per tick at an icount shift.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct SlopeJson {
    pub icount_shift: u32,
    pub instructions_per_tick: f64,
    pub expected: f64,
}

/// Largest error against the f64 core, % of each property's maximum.
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct HckJson {
    pub h: f64,
    pub c: f64,
    pub k: f64,
}

impl HckJson {
    /// From `[c, k, h]`, to 10⁻⁴ %.
    fn new(c_k_h: [f64; 3]) -> Self {
        HckJson {
            h: round(c_k_h[2], 4),
            c: round(c_k_h[0], 4),
            k: round(c_k_h[1], 4),
        }
    }
}

/// The fixed-point build (issue 8).
#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct FixedPointJson {
    pub target: String,
    pub number_format: String,
    pub estimator: String,
    pub instructions_per_step: PerMode<Option<f64>>,
    pub error_vs_f64_pct: HckJson,
    pub replay_bit_identical: PerMode<Option<bool>>,
    pub flash_bytes: u64,
    pub ram_bytes: u64,
    pub calibration: Vec<SlopeJson>,
    pub error_method: String,
    /// One row per (machine, number format, estimator).
    pub table: Vec<TableRow>,
}

#[derive(Debug, Clone, Serialize, Deserialize, JsonSchema)]
pub struct TableRow {
    pub format: String,
    pub estimator: String,
    pub target: String,
    pub qemu: String,
    pub instructions_per_step: PerMode<Option<f64>>,
    /// Instructions per loop interrupt per window.
    pub windows: Ordered<f64>,
    pub error_vs_f64_pct: PerMode<Option<HckJson>>,
}

fn slopes(s: &[(u32, f64, f64)]) -> Vec<SlopeJson> {
    s.iter()
        .map(|&(shift, m, e)| SlopeJson {
            icount_shift: shift,
            instructions_per_tick: round(m, 6),
            expected: round(e, 6),
        })
        .collect()
}

/// The worst window's instructions per loop interrupt, to whole instructions.
fn counts(bench: &[BenchResult]) -> PerMode<Option<f64>> {
    PerMode::of(|m| per_mode(bench, m).map(|b| b.insns_per_step.round()))
}

impl Report {
    /// The typed report of `firmware-report --json`.
    pub fn to_report(&self) -> FirmwareReport {
        let window = |m: Mode| per_mode(&self.bench, m);
        let avg = |m: Mode| {
            self.bench
                .iter()
                .filter(|b| b.mode == Some(m))
                .map(|b| b.avg_insns)
                .max_by(f64::total_cmp)
        };
        let rep = |m: Mode| self.replay.iter().find(|r| r.mode == m);
        let product = self
            .sizes
            .iter()
            .find(|(b, _)| *b == Board::Stm32h743)
            .map(|(_, s)| *s)
            .unwrap_or_default();
        FirmwareReport {
            schema_version: SCHEMA_VERSION,
            instructions_per_step: counts(&self.bench),
            estimator_instructions_per_block: PerMode::of(|m| {
                window(m)
                    .and_then(|b| b.estimator_per_block)
                    .map(f64::round)
            }),
            block_samples: PerMode::of(|m| window(m).and_then(|b| b.block_samples).map(f64::round)),
            instructions_per_sample_avg: PerMode::of(|m| avg(m).map(f64::round)),
            max_loop_rate_hz_at_50pct_400mhz: PerMode::of(|m| {
                avg(m)
                    .zip(window(m))
                    .map(|(a, w)| max_rate_hz(a, w.insns_per_step).round())
            }),
            replay_bit_identical: PerMode::of(|m| {
                rep(m).map(|r| r.bit_identical && r.records_identical)
            }),
            replay_samples: PerMode::of(|m| rep(m).map_or(0, |r| r.samples as u64)),
            flash_bytes: product.flash,
            ram_bytes: product.ram,
            fixed_point: self.fixed_point.as_ref().map(FixedPointReport::to_json),
            sizes_board: "stm32h743".into(),
            sizes: Ordered(
                self.sizes
                    .iter()
                    .map(|(b, z)| {
                        (
                            b.name().to_string(),
                            SizesJson {
                                flash_bytes: z.flash,
                                ram_bytes: z.ram,
                            },
                        )
                    })
                    .collect(),
            ),
            instructions_windows: Ordered(
                self.bench
                    .iter()
                    .map(|b| {
                        let opt = |v: Option<f64>| v.map(|v| round(v, 2));
                        (
                            b.name.clone(),
                            WindowJson {
                                interrupt: round(b.insns_per_step, 3),
                                average_per_sample: round(b.avg_insns, 3),
                                estimator_per_block: opt(b.estimator_per_block),
                                block_samples: opt(b.block_samples),
                                step: opt(b.step_insns),
                                interrupt_besides_step: opt(b.overhead()),
                                steps: u64::from(b.steps),
                                first_sample: b.start as u64,
                                estimating_share: round(b.estimating, 3),
                                readout_share: round(b.readout, 3),
                                records: b.records as u64,
                            },
                        )
                    })
                    .collect(),
            ),
            goals: PerMode {
                dive: GOAL_DIVE,
                sve: GOAL_SVE,
            },
            replay_samples_per_s: PerMode::of(|m| rep(m).map(|r| r.samples_per_s.round())),
            replay_records: PerMode::of(|m| rep(m).map(|r| r.records as u64)),
            lockstep_sve: self.lockstep.as_ref().map(|l| LockstepJson {
                samples: l.samples as u64,
                pixels: l.pixels as u64,
                bit_identical: l.bit_identical,
                samples_per_s: l.samples_per_s.round(),
            }),
            core: "visco-core".into(),
            method: MethodJson {
                machine: "qemu-system-arm -machine mps2-an500 -cpu cortex-m7".into(),
                icount_shift: 0,
                steps: BENCH_STEPS,
                systick_hz: SYSTICK_HZ,
                what: "instructions per loop interrupt: timer-driven interrupts over the ADC \
                       codes of a closed-loop recording, from the state the replay of the \
                       recording up to the window left; SysTick around the window, minus the \
                       counted idle loop"
                    .into(),
            },
            calibration: slopes(&self.calibration.slopes),
        }
    }
}

impl FixedPointReport {
    /// The report's `fixed_point` object.
    pub fn to_json(&self) -> FixedPointJson {
        let (m, n) = FIXED;
        let e = Estimator::LeastSquares;
        FixedPointJson {
            target: m.target.into(),
            number_format: n.name().into(),
            estimator: e.name().into(),
            instructions_per_step: self
                .variant(m, n, e)
                .map_or(PerMode::of(|_| None), |v| counts(&v.bench)),
            error_vs_f64_pct: HckJson::new(self.error(n, e)),
            replay_bit_identical: PerMode::of(|mode| {
                self.replay
                    .iter()
                    .find(|r| r.mode == mode)
                    .map(|r| r.bit_identical && r.records_identical && r.reproduces_recording)
            }),
            flash_bytes: self.sizes.flash,
            ram_bytes: self.sizes.ram,
            calibration: slopes(&self.calibration.slopes),
            error_method: "largest difference from the f64 core at the records, in % of each \
                           property's maximum, over the DIVE (3 x 3 taps) and SVE (one line, 25 \
                           pixels each way) closed loops on the cell phantom at 500 kHz \
                           (visco::experiment::fixed_point)"
                .into(),
            table: self
                .variants
                .iter()
                .map(|v| TableRow {
                    format: v.number.name().into(),
                    estimator: v.estimator.name().into(),
                    target: v.machine.target.into(),
                    qemu: format!("{} {}", v.machine.machine, v.machine.cpu),
                    instructions_per_step: counts(&v.bench),
                    windows: Ordered(
                        v.bench
                            .iter()
                            .map(|b| (b.name.clone(), round(b.insns_per_step, 2)))
                            .collect(),
                    ),
                    error_vs_f64_pct: PerMode::of(|mode| {
                        self.errors
                            .iter()
                            .find(|f| {
                                f.number == v.number && f.estimator == v.estimator && f.mode == mode
                            })
                            .map(|f| HckJson::new(f.c_k_h))
                    }),
                })
                .collect(),
        }
    }
}

/// The JSON Schema of the firmware report, pretty-printed with a final newline.
pub fn schema() -> String {
    visco::report::to_pretty(&schemars::schema_for!(FirmwareReport))
}

/// Where the firmware report's schema is committed.
pub fn schema_path() -> std::path::PathBuf {
    crate::firmware::root().join("xtask/schemas/firmware-report.schema.json")
}

/// `cargo xtask schemas`: every report's schema, written where it is committed.
pub fn write_schemas() -> crate::firmware::Result<()> {
    let host = crate::firmware::root().join("host-sim/schemas");
    let mut all: Vec<(std::path::PathBuf, String)> = visco::report::REPORTS
        .iter()
        .filter_map(|(name, _)| {
            visco::report::schema(name).map(|s| (host.join(format!("{name}.schema.json")), s))
        })
        .collect();
    all.push((schema_path(), schema()));
    for (path, text) in all {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        visco::output::write_atomic(&path, text.as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("{}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::firmware::{
        BenchResult, Calibration, FixedError, LockstepResult, Number, ReplayResult, Sizes, Variant,
        M3, M7,
    };

    fn bench(name: &str, mode: Option<Mode>, insns: f64) -> BenchResult {
        BenchResult {
            name: name.into(),
            mode,
            shift: 0,
            steps: 10_000,
            ticks: 1234,
            idle_iterations: 7,
            insns_per_step: insns,
            avg_insns: insns * 0.871_234_5,
            estimator_per_block: mode.map(|_| 812.345_6),
            block_samples: mode.map(|_| 16.0),
            step_insns: mode.map(|_| insns - 41.123),
            resolution: 0.01,
            start: 1500,
            estimating: 0.123_456,
            readout: 0.654_321,
            records: 3,
        }
    }

    fn replay(mode: Mode) -> ReplayResult {
        ReplayResult {
            name: "dive tap",
            mode,
            samples: 24_000,
            bit_identical: true,
            records: 1,
            records_identical: true,
            reproduces_recording: true,
            samples_per_s: 123_456.789,
            stats: Default::default(),
        }
    }

    /// A report with every part present and values that need rounding.
    pub(crate) fn synthetic() -> Report {
        let cal = Calibration {
            points: Vec::new(),
            slopes: vec![(0, 16.000_000_4, 16.0), (3, 2.000_000_1, 2.0)],
        };
        Report {
            bench: vec![
                bench("idle", None, 12.0),
                bench("dive_contact", Some(Mode::Dive), 487.456_7),
                bench("sve_scan", Some(Mode::Sve), 576.543_2),
            ],
            calibration: cal.clone(),
            sizes: vec![
                (
                    Board::Qemu,
                    Sizes {
                        flash: 50_000,
                        ram: 9000,
                    },
                ),
                (
                    Board::Stm32h743,
                    Sizes {
                        flash: 52_000,
                        ram: 9100,
                    },
                ),
            ],
            replay: vec![replay(Mode::Dive), replay(Mode::Sve)],
            lockstep: Some(LockstepResult {
                samples: 100_000,
                pixels: 25,
                bit_identical: true,
                samples_per_s: 45_678.9,
            }),
            fixed_point: Some(FixedPointReport {
                calibration: cal,
                sizes: Sizes {
                    flash: 60_000,
                    ram: 9500,
                },
                variants: vec![
                    Variant {
                        machine: M3,
                        number: Number::Q32,
                        estimator: Estimator::LeastSquares,
                        bench: vec![bench("dive_contact", Some(Mode::Dive), 1523.4)],
                    },
                    Variant {
                        machine: M7,
                        number: Number::F32,
                        estimator: Estimator::Gradient,
                        bench: vec![bench("sve_scan", Some(Mode::Sve), 321.987)],
                    },
                ],
                errors: vec![FixedError {
                    number: Number::Q32,
                    estimator: Estimator::LeastSquares,
                    mode: Mode::Dive,
                    c_k_h: [0.012_345_6, 0.234_567_8, 0.000_012_3],
                    records: 9,
                }],
                replay: vec![replay(Mode::Dive)],
            }),
        }
    }

    /// The committed schema is the generated one (`cargo xtask schemas` rewrites it).
    #[test]
    fn committed_schema_is_the_generated_one() {
        let committed = std::fs::read_to_string(schema_path()).unwrap_or_default();
        assert!(
            committed == schema(),
            "xtask/schemas/firmware-report.schema.json is stale: run `cargo xtask schemas`"
        );
    }

    /// A full report (every optional part present) and one without the optional parts
    /// validate against the committed schema; a broken one does not.
    #[test]
    fn reports_validate_against_the_schema() {
        let s: serde_json::Value = serde_json::from_str(&schema()).unwrap();
        let v = jsonschema::validator_for(&s).unwrap();
        let full = serde_json::to_value(synthetic().to_report()).unwrap();
        assert!(
            v.is_valid(&full),
            "{:?}",
            v.iter_errors(&full)
                .map(|e| e.to_string())
                .collect::<Vec<_>>()
        );
        let mut bare = synthetic();
        bare.fixed_point = None;
        bare.lockstep = None;
        bare.replay.clear();
        let bare = serde_json::to_value(bare.to_report()).unwrap();
        assert!(v.is_valid(&bare));
        assert!(
            bare.get("fixed_point").is_none() && bare["replay_bit_identical"]["dive"].is_null()
        );
        let mut broken = full;
        broken["flash_bytes"] = "many".into();
        assert!(!v.is_valid(&broken));
    }

    /// The numbers keep the precision the hand-written report printed (the typed report was
    /// checked equal to it on this synthetic report, number for number, in the commit that
    /// introduced it): whole instructions, 10⁻³ for windows and shares, 10⁻² for the splits,
    /// 10⁻⁶ for the calibration, 10⁻⁴ % for the fixed-point errors; nothing measured is null.
    #[test]
    fn numbers_keep_the_stated_precision() {
        let v = serde_json::to_value(synthetic().to_report()).unwrap();
        let f = |path: &str| {
            v.pointer(path)
                .and_then(serde_json::Value::as_f64)
                .unwrap_or_else(|| panic!("{path}"))
        };
        assert_eq!(f("/schema_version"), 1.0);
        assert_eq!(f("/instructions_per_step/dive"), 487.0);
        assert_eq!(f("/instructions_per_step/sve"), 577.0);
        // 487.4567 × 0.8712345 = 424.6883…, whole instructions.
        assert_eq!(f("/instructions_per_sample_avg/dive"), 425.0);
        assert_eq!(f("/instructions_windows/dive_contact/interrupt"), 487.457);
        assert_eq!(f("/instructions_windows/dive_contact/step"), 446.33);
        assert_eq!(
            f("/instructions_windows/dive_contact/estimating_share"),
            0.123
        );
        assert!(v
            .pointer("/instructions_windows/idle/step")
            .unwrap()
            .is_null());
        assert_eq!(f("/calibration/0/instructions_per_tick"), 16.0);
        assert_eq!(f("/replay_samples_per_s/dive"), 123_457.0);
        assert_eq!(f("/lockstep_sve/samples_per_s"), 45_679.0);
        assert_eq!(f("/flash_bytes"), 52_000.0);
        // [c, k, h] = [0.0123456, 0.2345678, 0.0000123] % → h 0, c 0.0123, k 0.2346.
        assert_eq!(f("/fixed_point/error_vs_f64_pct/h"), 0.0);
        assert_eq!(f("/fixed_point/error_vs_f64_pct/c"), 0.0123);
        assert_eq!(f("/fixed_point/error_vs_f64_pct/k"), 0.2346);
        assert_eq!(f("/fixed_point/instructions_per_step/dive"), 1523.0);
        assert!(v
            .pointer("/fixed_point/instructions_per_step/sve")
            .unwrap()
            .is_null());
        assert_eq!(f("/fixed_point/table/1/windows/sve_scan"), 321.99);
        assert!(v
            .pointer("/fixed_point/table/1/error_vs_f64_pct/dive")
            .unwrap()
            .is_null());
    }
}
