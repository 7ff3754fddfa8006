//! Tuning exploration: a reduced DIVE and SVE on the phantom, errors printed.
use std::time::Instant;
use visco::experiment::{metrics, run_dive, run_sve, Setup};
use visco::sample::Sample;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let fs: f64 = args.get(1).and_then(|v| v.parse().ok()).unwrap_or(500e3);
    let what = args.get(2).cloned().unwrap_or("both".into());
    let n: u32 = args.get(3).and_then(|v| v.parse().ok()).unwrap_or(5);
    let mut setup = Setup::paper(Sample::cell_phantom(), fs, 1);
    setup.config.dive.nx = n;
    setup.config.dive.ny = n;
    setup.config.dive.dx_m = 5e-6 / n as f64;
    setup.config.dive.dy_m = 5e-6 / n as f64;
    setup.config.dive.x0_m = 2.5e-6 / n as f64;
    setup.config.dive.y0_m = 2.5e-6 / n as f64;
    setup.config.sve.lines = n;
    setup.config.sve.dy_m = 5e-6 / n as f64;
    setup.config.sve.y0_m = 2.5e-6 / n as f64;
    if let Some(p) = args.get(4).and_then(|v| v.parse().ok()) {
        setup.config.sve.line_period_s = p;
    }
    if what == "both" || what == "dive" {
        let t = Instant::now();
        let o = run_dive(&setup, &mut (), |_| {}).unwrap();
        let wall = t.elapsed().as_secs_f64();
        let st = metrics::steep_slope(450e-9, 300e-9);
        let e = metrics::image_errors(
            o.taps
                .iter()
                .filter(|t| !t.failed)
                .map(|t| (&t.scaled.paper, &t.touched.reference, t.slope)),
            &metrics::PAPER_MAX,
            st,
        );
        let ei = metrics::image_errors(
            o.taps
                .iter()
                .filter(|t| !t.failed)
                .map(|t| (&t.scaled.instrument, &t.touched.reference, t.slope)),
            &metrics::PAPER_MAX,
            st,
        );
        println!(
            "instrument scaling:\n  h {:?}\n  c {:?}\n  k {:?}",
            ei.h, ei.c, ei.k
        );
        println!(
            "DIVE {} taps, {:.1} s simulated in {:.2} s wall ({:.0} ns/step); failed {}",
            o.taps.len(),
            o.simulated_s,
            wall,
            wall / (o.simulated_s * fs) * 1e9,
            o.taps.iter().filter(|t| t.failed).count()
        );
        println!("  h {:?}\n  c {:?}\n  k {:?}", e.h, e.c, e.k);
        for t in o.taps.iter().take(40) {
            let err =
                metrics::percent_errors(&t.scaled.paper, &t.touched.reference, &metrics::PAPER_MAX);
            let erri = metrics::percent_errors(
                &t.scaled.instrument,
                &t.touched.reference,
                &metrics::PAPER_MAX,
            );
            println!("  tap {:3} ({:.2},{:.2}) n {:.1} nW {:.1} slope {:.2} err h {:+.2} c {:+.2} k {:+.2} % (instr h {:+.2} c {:+.2} k {:+.2}) depth {:.0} nm flags {:#x}", t.record.index, t.record.x_m * 1e6, t.record.y_m * 1e6, t.scaled.n_estimated, t.touched.n, t.slope, err[0], err[1], err[2], erri[0], erri[1], erri[2], t.record.depth_m * 1e9, t.record.flags);
        }
    }
    if what == "both" || what == "sve" {
        let t = Instant::now();
        let o = run_sve(&setup, &mut (), |_| {}).unwrap();
        let wall = t.elapsed().as_secs_f64();
        let st = metrics::steep_slope(150e-9, 260e-9);
        let e = metrics::image_errors(
            o.pixels
                .iter()
                .map(|p| (&p.scaled.paper, &p.touched.reference, p.slope)),
            &metrics::PAPER_MAX,
            st,
        );
        let ei = metrics::image_errors(
            o.pixels
                .iter()
                .map(|p| (&p.scaled.instrument, &p.touched.reference, p.slope)),
            &metrics::PAPER_MAX,
            st,
        );
        println!(
            "instrument scaling:\n  h {:?}\n  c {:?}\n  k {:?}",
            ei.h, ei.c, ei.k
        );
        println!(
            "SVE {} px, {:.1} s simulated in {:.2} s wall ({:.0} ns/step)",
            o.pixels.len(),
            o.simulated_s,
            wall,
            wall / (o.simulated_s * fs) * 1e9
        );
        println!("  h {:?}\n  c {:?}\n  k {:?}", e.h, e.c, e.k);
        for p in o.pixels.iter().filter(|p| p.pixel % 5 == 0).take(40) {
            let err =
                metrics::percent_errors(&p.scaled.paper, &p.touched.reference, &metrics::PAPER_MAX);
            let erri = metrics::percent_errors(
                &p.scaled.instrument,
                &p.touched.reference,
                &metrics::PAPER_MAX,
            );
            println!("  px ({:2},{:2}) x {:.2} n {:.1} nW {:.1} slope {:.2} err h {:+.2} c {:+.2} k {:+.2} % (instr h {:+.2} c {:+.2} k {:+.2})", p.line, p.pixel, p.x_m * 1e6, p.scaled.n_estimated, p.touched.n, p.slope, err[0], err[1], err[2], erri[0], erri[1], erri[2]);
        }
    }
}
