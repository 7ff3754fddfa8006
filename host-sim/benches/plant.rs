//! Plant throughput in the three regimes of the demo, with the paper's realism on (thermal
//! noise, 16-bit ADC and DACs) at a 1 µs step:
//!
//! - `free`: out of contact, a 50 nm drive near resonance;
//! - `dive_submerged`: the tip ≈ 450 nm deep in the cell with the two-tone DIVE drive
//!   (1 µm at 19.5 kHz, 0.25 µm at 4 kHz);
//! - `sve_scan_nominal` / `sve_scan_fast`: partial contact ≈ 150 nm deep with the small SVE
//!   drive, scanning the phantom at the paper's speed (5 µm per 1 s half-line =
//!   0.005 nm/µs) and at 10× that; active-set changes every oscillation, lateral refreshes.
//!
//! The budget: 1.2×10⁸ plant steps (plus the core) in ≤ 6 s on one core, i.e. ≲ 20–30 ns per
//! step on average. Inputs are precomputed so only the plant is timed; each iteration runs
//! 10 000 steps, continuing the same plant. Run with `cargo bench -p visco --bench plant`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::f64::consts::PI;
use std::hint::black_box;
use visco::plant::{Plant, PlantConfig};
use visco::sample::Sample;

const BLOCK: usize = 10_000;

struct Scenario {
    u_nm: Vec<f64>,
    x_nm: Vec<f64>,
    y_nm: f64,
}

fn two_tone(t_us: f64, a1: f64, f1_mhz: f64, a2: f64, f2_mhz: f64) -> f64 {
    a1 * (2.0 * PI * f1_mhz * t_us).sin() + a2 * (2.0 * PI * f2_mhz * t_us).sin()
}

fn free() -> Scenario {
    let n = 200_000;
    Scenario {
        u_nm: (0..n)
            .map(|i| 50.0 * (2.0 * PI * 0.0195 * i as f64).sin())
            .collect(),
        x_nm: vec![-2000.0; n],
        y_nm: -2000.0,
    }
}

fn dive(sample: &Sample) -> Scenario {
    let n = 200_000;
    let surface = sample.first_contact_z_m(2.5e-6, 2.5e-6, 300e-9).unwrap() * 1e9;
    let u_low = surface - 610.0;
    Scenario {
        u_nm: (0..n)
            .map(|i| u_low + two_tone(i as f64, 1000.0, 0.0195, 250.0, 0.004))
            .collect(),
        x_nm: vec![2500.0; n],
        y_nm: 2500.0,
    }
}

fn sve(sample: &Sample, speed_nm_per_us: f64) -> Scenario {
    // A 4.5 µm line (0.9 s at the nominal speed: 0.9e6 samples, 14 MB), then the scan wraps.
    let n = (4500.0 / speed_nm_per_us) as usize;
    let y = 2550.0;
    let x0 = 200.0;
    // Feedforward on the first-contact height, tabulated every 10 nm and interpolated.
    let span = speed_nm_per_us * n as f64;
    let table: Vec<f64> = (0..=((span / 10.0) as usize + 2))
        .map(|j| {
            let x = x0 + 10.0 * j as f64;
            sample
                .first_contact_z_m(x.min(4900.0) * 1e-9, y * 1e-9, 300e-9)
                .unwrap_or(0.0)
                * 1e9
        })
        .collect();
    let mut u_nm = Vec::with_capacity(n);
    let mut x_nm = Vec::with_capacity(n);
    for i in 0..n {
        let x = x0 + speed_nm_per_us * i as f64;
        let s = (x - x0) / 10.0;
        let j = s as usize;
        let f = s - j as f64;
        let surf = table[j] * (1.0 - f) + table[j + 1] * f;
        u_nm.push(surf - 180.0 + two_tone(i as f64, 40.0, 0.0195, 13.0, 0.003));
        x_nm.push(x);
    }
    Scenario {
        u_nm,
        x_nm,
        y_nm: y,
    }
}

fn bench_scenario(c: &mut Criterion, name: &str, sc: Scenario) {
    bench_scenario_with(c, name, sc, PlantConfig::paper())
}

fn bench_scenario_with(c: &mut Criterion, name: &str, sc: Scenario, cfg: PlantConfig) {
    let mut plant = Plant::new(cfg, Sample::cell_phantom(), 1).unwrap();
    plant.settle_nm(sc.u_nm[0], sc.x_nm[0], sc.y_nm);
    let n = sc.u_nm.len();
    let mut idx = 0usize;
    // Warm the plant into the regime.
    for i in 0..20_000.min(n) {
        plant.step_nm(sc.u_nm[i], sc.x_nm[i], sc.y_nm);
    }
    let before = plant.stats();
    let mut g = c.benchmark_group("plant");
    g.throughput(Throughput::Elements(BLOCK as u64));
    g.bench_function(name, |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for _ in 0..BLOCK {
                acc += plant.step_nm(sc.u_nm[idx], sc.x_nm[idx], sc.y_nm);
                idx += 1;
                if idx == n {
                    idx = 0;
                }
            }
            black_box(acc)
        })
    });
    g.finish();
    let after = plant.stats();
    let steps = (after.steps - before.steps).max(1) as f64;
    println!(
        "{name}: per step {:.4} events, {:.4} lateral refreshes, {:.2e} matrix builds; active {} of {}",
        (after.events - before.events) as f64 / steps,
        (after.lateral_refreshes - before.lateral_refreshes) as f64 / steps,
        (after.matrix_builds - before.matrix_builds) as f64 / steps,
        plant.active_elements(),
        plant.elements_under_tip()
    );
}

/// One threshold refresh (the lateral-motion cost), moving 0.15 nm (one lateral DAC LSB)
/// each time.
fn footprint_bench(c: &mut Criterion) {
    use visco::plant::contact::{Footprint, SampleNm};
    let s = SampleNm::new(Sample::cell_phantom());
    let mut fp = Footprint::default();
    let mut x = 1000.0;
    c.bench_function("footprint_update", |b| {
        b.iter(|| {
            x += 0.15;
            if x > 4000.0 {
                x = 1000.0;
            }
            fp.update(&s, x, 2550.0, 300.0);
            black_box(fp.len)
        })
    });
}

fn plant_benches(c: &mut Criterion) {
    footprint_bench(c);
    let sample = Sample::cell_phantom();
    bench_scenario(c, "free", free());
    bench_scenario_with(c, "free_ideal", free(), PlantConfig::ideal());
    bench_scenario_with(
        c,
        "free_noquant",
        free(),
        PlantConfig::paper().without_quantisation(),
    );
    bench_scenario_with(
        c,
        "free_nonoise",
        free(),
        PlantConfig::paper().without_noise(),
    );
    bench_scenario(c, "dive_submerged", dive(&sample));
    bench_scenario(c, "sve_scan_nominal", sve(&sample, 0.005));
    bench_scenario(c, "sve_scan_fast", sve(&sample, 0.05));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(3));
    targets = plant_benches
}
criterion_main!(benches);
