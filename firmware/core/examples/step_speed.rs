//! Rough host timing of `Controller::step` (f32) in DIVE and SVE, fed a synthetic deflection.
//! Not a test: machines are noisy. `cargo run --release -p visco-core --example step_speed`.
use std::time::Instant;
use visco_core::{Command, Config, Controller, Mode};

fn main() {
    for mode in [Mode::Dive, Mode::Sve] {
        let cfg = Config::paper(1e6);
        let mut c = Controller::<f32>::new(&cfg).unwrap();
        c.command(Command::Start(mode));
        let n: u32 = std::env::args()
            .nth(1)
            .and_then(|v| v.parse().ok())
            .unwrap_or(20_000_000);
        let t = Instant::now();
        let mut d = 0.0f32;
        let mut acc = 0.0f32;
        for k in 0..n {
            let out = c.step(d);
            acc += out.u_m;
            // A fake contact: deflection follows U below 0.
            d = if out.u_m < 0.0 {
                out.u_m * 0.3 + 1e-10 * ((k % 7) as f32)
            } else {
                0.0
            };
        }
        let dt = t.elapsed().as_secs_f64();
        println!("{mode:?}: {:.1} ns/step ({acc:e})", dt / n as f64 * 1e9);
    }
}
