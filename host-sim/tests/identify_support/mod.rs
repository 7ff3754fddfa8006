//! Helpers shared by the `identify_*` and `diagnose_*` integration tests: simulated recordings
//! from the plant with the controller in the loop, the real files and the values a user
//! supplies with them, and running the `visco` command.
#![allow(dead_code)]

pub mod pins;

use std::path::{Path, PathBuf};

use visco::plant::{Plant, PlantConfig};
use visco::recording::{Metadata, Mode, Recording};
use visco::sample::Sample;
use visco_core::{status, Command, Config, Controller, Phase, PixelRecord, Record, TapRecord};

/// A simulated experiment: its recording and what the controller itself reported.
pub struct SimRun {
    pub rec: Recording,
    pub taps: Vec<TapRecord<f32>>,
    pub pixels: Vec<PixelRecord<f32>>,
}

/// Runs `cfg`'s mode with the controller (f32, as the board) in closed loop with the plant,
/// recording every sample in the contract's alignment: U held over the period ending at the
/// sample, D read at it, X and Y of that period, and the tap number (DIVE).
pub fn simulate(
    cfg: &Config,
    mode: visco_core::Mode,
    plant_cfg: PlantConfig,
    sample: Sample,
    seed: u64,
    max_steps: usize,
) -> SimRun {
    // The instrument's converters matched to the core's ranges, as the experiments do.
    let mut setup = visco::experiment::Setup::paper(sample, cfg.sample_rate_hz, seed);
    setup.plant.thermal_noise = plant_cfg.thermal_noise;
    let plant_cfg = setup.plant.clone();
    let sample = setup.sample.clone();
    let fs = cfg.sample_rate_hz;
    let mut ctrl = Controller::<f32>::new(cfg).expect("valid configuration");
    let mut plant = Plant::new(plant_cfg.clone(), sample, seed).expect("valid plant");
    plant.set_time_step(1.0 / fs).unwrap();
    let x0 = cfg.dive.x0_m;
    let y0 = cfg.dive.y0_m;
    plant.settle(ctrl.u_m() as f64, x0, y0);
    ctrl.command(Command::Start(mode));
    let mut meta = Metadata::new(
        match mode {
            visco_core::Mode::Dive => Mode::Dive,
            visco_core::Mode::Sve => Mode::Sve,
        },
        fs,
        plant_cfg.cantilever.k_n_per_m,
        plant_cfg.tip_radius_m,
    );
    meta.cantilever_c_ns_per_m = Some(plant_cfg.cantilever.c_ns_per_m);
    meta.cantilever_m_kg = Some(plant_cfg.cantilever.m_kg);
    meta.set(
        "source",
        "visco tests: controller (f32) in closed loop with the plant",
    );
    let mut rec = Recording::new(meta);
    rec.x_m = Some(Vec::new());
    rec.y_m = Some(Vec::new());
    if mode == visco_core::Mode::Dive {
        rec.tap = Some(Vec::new());
    }
    let mut taps = Vec::new();
    let mut pixels = Vec::new();
    let mut d = plant.measured_deflection_m();
    let (mut u, mut x, mut y) = (ctrl.u_m() as f64, x0, y0);
    let mut tap = 0u32;
    let mut prev_phase = Phase::Move;
    for k in 0..max_steps {
        let out = ctrl.step(d as f32);
        if out.status & status::RECORD_READY != 0 {
            match ctrl.take_record() {
                Some(Record::Tap(t)) => taps.push(t),
                Some(Record::Pixel(p)) => pixels.push(p),
                None => {}
            }
        }
        let phase = ctrl.phase();
        if phase == Phase::Done {
            break;
        }
        if prev_phase == Phase::Wait && phase == Phase::Move {
            tap += 1;
        }
        prev_phase = phase;
        let (un, xn, yn) = (out.u_m as f64, out.x_m as f64, out.y_m as f64);
        d = plant.step(un, xn, yn);
        u = un;
        x = xn;
        y = yn;
        rec.t_s.push((k + 1) as f64 / fs);
        rec.u_m.push(u);
        rec.d_m.push(d);
        rec.x_m.as_mut().unwrap().push(x);
        rec.y_m.as_mut().unwrap().push(y);
        if let Some(t) = rec.tap.as_mut() {
            t.push(tap);
        }
    }
    let _ = (u, x, y);
    SimRun { rec, taps, pixels }
}

/// The shared real-data folder, as the recording tests find it.
pub fn real(name: &str) -> PathBuf {
    let mut candidates: Vec<PathBuf> = Vec::new();
    if let Some(dir) = std::env::var_os("VISCO_SHARED_DIR") {
        candidates.push(Path::new(&dir).join("data/real"));
    }
    candidates.push(PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/real/"
    )));
    for anc in Path::new(env!("CARGO_MANIFEST_DIR")).ancestors() {
        candidates.push(anc.join("shared/data/real"));
    }
    for c in &candidates {
        let p = c.join(name);
        if p.is_file() {
            return p;
        }
    }
    panic!("real data file {name} not found in {candidates:?}; set VISCO_SHARED_DIR");
}

/// The real files.
pub const SPOT3: &str = "fmt-jpk-fd_spot3-0192.jpk-force";
pub const SR: &str = "fmt-jpk-sr_cell1-0008.jpk-force";
pub const CC: &str = "fmt-jpk-cc_pr14-polymergel-2021.06.30.jpk-force";
pub const MAP: &str = "fmt-jpk-fd_map2x2_extracted.jpk-force-map";
pub const WORKSHOP: &str = "fmt-afm-workshop-fd_single_2021-10-22_14.16.csv";
pub const NTMDT: &str = "fmt-ntmdt-txt-fd_2015_01_17_gel4-0,1_mQ_adh_6B_Curve_DFL_Height_51.txt";

/// What a user supplies with each real file: the tip radius 5 µm for all (colloidal probes
/// for cells; no vendor stores it); AFM Workshop: 0.1 N/m, 1 kHz; NT-MDT: 0.1 N/m,
/// 50 nm/nA, 1 kHz. JPK files carry their own spring constant, sensitivity and rates.
pub fn real_import_options(name: &str) -> visco::recording::import::ImportOptions {
    let mut o = visco::recording::import::ImportOptions {
        tip_radius_m: Some(5e-6),
        ..Default::default()
    };
    if name == WORKSHOP || name == NTMDT {
        o.spring_constant_n_per_m = Some(0.1);
        o.sample_rate_hz = Some(1000.0);
    }
    if name == NTMDT {
        o.sensitivity_m_per_unit = Some(5e-8);
    }
    o
}

/// Runs the `visco` command.
pub fn visco(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_visco"))
        .args(args)
        .output()
        .expect("run visco")
}

/// Output bytes as text.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A path as `&str`.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The names in a directory, sorted.
pub fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    v.sort();
    v
}
