use visco::experiment::{run_sve, scaling, Setup};
use visco::sample::Sample;
use visco_core::Mode;
fn main() {
    let sample = Sample::flat(50, 50, 100e-9, [50e-9, 50e-9], 100e-9, 6e-7, 3.5e-3).unwrap();
    let mut setup = Setup::paper(sample, 500e3, 1);
    setup.config.sve.lines = 1;
    setup.config.sve.line_period_s = 0.5;
    setup.config.sve.y0_m = 2.5e-6;
    let o = run_sve(&setup, &mut (), |_| {}).unwrap();
    let sw = setup.tip_swing(Mode::Sve);
    println!(
        "swing amplitude {:?}",
        sw.iter().cloned().fold(0.0f64, f64::max)
    );
    for p in o.pixels.iter().step_by(7) {
        // model scan in H
        let mut line = String::new();
        for hnm in [140, 145, 150, 155, 160] {
            let h = hnm as f64 * 1e-9;
            let (mut n, mut f) = (0.0, 0.0);
            for o in &sw {
                setup.sample.for_each_within(p.x_m, p.y_m, 300e-9, |e| {
                    let sag = 300e-9 - (9e-14 - e.r_m * e.r_m).sqrt();
                    if h + o - sag > 0.0 {
                        n += 1.0;
                        f += h + o - sag;
                    }
                });
            }
            line += &format!(
                " H{hnm}: n {:.1} ratio {:.1};",
                n / sw.len() as f64,
                f / n * 1e9
            );
        }
        println!("{line}");
        println!(
            "x {:.2} k̂/k_el {:.2} nW {:.2} n_est {:.2} (instr k {:.3e}, paper k {:.3e})",
            p.x_m * 1e6,
            p.scaled.paper.k_n_per_m * p.touched.n / 3.5e-3,
            p.touched.n,
            p.scaled.n_estimated,
            p.scaled.instrument.k_n_per_m,
            p.scaled.paper.k_n_per_m
        );
    }
}
