//! The closed loop the demo runs, timed: `Controller::<f32>::step` (the core, as on the board)
//! followed by `Plant::step_nm`, through the demo's sequences from the first estimating sample
//! on — DIVE taps (dwell, retract, move, approach, as they come) and SVE lines — on the cell
//! phantom at 500 kHz, as the demo runs them. The demo's budget is 120 s
//! simulated at 500 kHz (6×10⁷ loop samples) in ≤ 6 s, i.e. ≤ 100 ns per sample on average.
//! `cargo bench -p visco --bench closed_loop`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use visco::experiment::Setup;
use visco::plant::Plant;
use visco::sample::Sample;
use visco_core::{status, Command, Controller, Mode, Phase};

const BLOCK: u64 = 10_000;

/// A controller and plant advanced until `ready` holds.
fn prepared(
    mode: Mode,
    ready: impl Fn(&Controller<f32>, u32) -> bool,
) -> (Controller<f32>, Plant, f32) {
    let setup = Setup::paper(Sample::cell_phantom(), 500e3, 1);
    let mut ctrl = Controller::<f32>::new(&setup.config).unwrap();
    let mut plant = setup.build_plant().unwrap();
    ctrl.command(Command::Start(mode));
    let mut d = 0.0f32;
    for _ in 0..20_000_000 {
        let out = ctrl.step(d);
        if out.status & status::RECORD_READY != 0 {
            ctrl.take_record();
        }
        d = (plant.step_nm(
            out.u_m as f64 * 1e9,
            out.x_m as f64 * 1e9,
            out.y_m as f64 * 1e9,
        ) * 1e-9) as f32;
        if ready(&ctrl, out.status) {
            break;
        }
    }
    (ctrl, plant, d)
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("closed_loop");
    g.throughput(Throughput::Elements(BLOCK));
    for (name, mode, ready) in [
        (
            "dive_taps",
            Mode::Dive,
            (|_: &Controller<f32>, st: u32| st & status::ESTIMATING != 0)
                as fn(&Controller<f32>, u32) -> bool,
        ),
        ("sve_lines", Mode::Sve, |c: &Controller<f32>, _| {
            c.phase() == Phase::Forward
        }),
    ] {
        let (mut ctrl, mut plant, mut d) = prepared(mode, ready);
        g.bench_function(name, |b| {
            b.iter(|| {
                for _ in 0..BLOCK {
                    let out = ctrl.step(black_box(d));
                    if out.status & status::RECORD_READY != 0 {
                        ctrl.take_record();
                    }
                    d = (plant.step_nm(
                        out.u_m as f64 * 1e9,
                        out.x_m as f64 * 1e9,
                        out.y_m as f64 * 1e9,
                    ) * 1e-9) as f32;
                }
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
