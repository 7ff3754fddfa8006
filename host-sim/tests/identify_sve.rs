//! SVE recordings simulated with the plant identify to the sample's known parameters.

mod identify_support;

use identify_support::*;
use visco::identify::{identify, Options, Outcome};
use visco::plant::PlantConfig;
use visco::sample::Sample;
use visco_core::Config;

#[test]
#[ignore]
fn dev_write_sve_recording() {
    let mut cfg = Config::paper(1e6);
    cfg.sve.lines = 2;
    cfg.sve.pixels = 10;
    cfg.sve.x0_m = 1.0e-6;
    cfg.sve.x1_m = 4.0e-6;
    cfg.sve.y0_m = 2.0e-6;
    cfg.sve.dy_m = 0.5e-6;
    cfg.sve.line_period_s = 0.2;
    cfg.dive.nx = 1;
    cfg.dive.ny = 1;
    cfg.dive.x0_m = 1.0e-6;
    cfg.dive.y0_m = 2.0e-6;
    let (k_el, c_el) = (3.5e-3, 6e-7);
    let sample = Sample::from_fn(50, 50, 100e-9, [50e-9, 50e-9], |x, _y| {
        (100e-9 + 0.02 * x, c_el, k_el)
    })
    .unwrap();
    let run = simulate(
        &cfg,
        visco_core::Mode::Sve,
        PlantConfig::paper(),
        sample.clone(),
        11,
        1_000_000,
    );
    for p in run.pixels.iter().take(40) {
        println!(
            "ctrl line {} px {} fwd {} x {:.3e} c {:.4e} k {:.4e} bed {:.3e} depth {:.3e}",
            p.line, p.pixel, p.forward, p.x_m, p.c_ns_per_m, p.k_n_per_m, p.bed_height_m, p.depth_m
        );
    }
    println!("rows {}", run.rec.len());
    run.rec
        .write(std::path::Path::new("/tmp/idr/sve_sim.csv"))
        .unwrap();
    let mut o = Options::new("/tmp/idr/out/sve_sim.json");
    o.pixels = 10;
    let report = identify(std::path::Path::new("/tmp/idr/sve_sim.csv"), &o).unwrap();
    if let Outcome::Sve(s) = &report.outcome {
        println!("{}", s.summary());
        for (name, _, v) in &s.maps {
            println!(
                "{name}: {:?}",
                v.iter().map(|x| format!("{x:.4e}")).collect::<Vec<_>>()
            );
        }
        println!("passes {:?}", s.passes);
    }
}
