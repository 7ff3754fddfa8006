//! Exponent of the force–depth law at every DIVE tap (exploration).
use visco::experiment::{demo, run_dive, Observer, Setup};
use visco::plant::Plant;
use visco::sample::Sample;
use visco_core::{Controller, Phase, StepOut};
struct Fd {
    tap: usize,
    pts: Vec<Vec<(f64, f64)>>,
}
impl Observer for Fd {
    fn sample(&mut self, ctrl: &Controller<f32>, _o: &StepOut<f32>, plant: &Plant) {
        if ctrl.phase() == Phase::Indent {
            if self.pts.len() <= self.tap {
                self.pts.resize(self.tap + 1, Vec::new());
            }
            self.pts[self.tap].push((plant.contact_depth_m(), plant.elastic_force_n()));
        }
    }
    fn record(&mut self, _r: &visco_core::Record<f32>, _p: &Plant) {
        self.tap += 1;
    }
}
fn main() {
    let setup = Setup::paper(Sample::cell_phantom(), 500e3, 1);
    let mut fd = Fd {
        tap: 0,
        pts: Vec::new(),
    };
    let o = run_dive(&setup, &mut fd, |_| {}).unwrap();
    let mut ex = Vec::new();
    for (i, p) in fd.pts.iter().enumerate() {
        let q: Vec<(f64, f64)> = p
            .iter()
            .cloned()
            .filter(|(d, f)| *d > 0.0 && *d <= 200e-9 && *f > 0.0)
            .collect();
        if q.len() < 20 {
            continue;
        }
        if let Some((law, _)) = visco::output::figure::fit_power_law(&q) {
            let l = demo::fit_power_law_least_squares(&q, law);
            let t = &o.taps[i];
            ex.push((
                l.b,
                law.b,
                t.slope,
                t.touched.reference.h_m,
                i,
                q.last().unwrap().1,
            ));
        }
    }
    ex.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = ex.len();
    println!(
        "taps {n}: LS exponent quartiles {:.3} {:.3} {:.3}; loglog median {:.3}",
        ex[n / 4].0,
        ex[n / 2].0,
        ex[3 * n / 4].0,
        {
            let mut v: Vec<f64> = ex.iter().map(|e| e.1).collect();
            v.sort_by(|a, b| a.total_cmp(b));
            v[n / 2]
        }
    );
    let cell: Vec<_> = ex.iter().filter(|e| e.3 > 100e-9).collect();
    println!(
        "on the cell (h > 100 nm): {} taps, LS median {:.3}",
        cell.len(),
        cell[cell.len() / 2].0
    );
    let flat_cell: Vec<_> = ex.iter().filter(|e| e.3 > 100e-9 && e.2 < 0.2).collect();
    println!(
        "flat cell: {} taps, LS median {:.3}, F(200) median {:.2} nN",
        flat_cell.len(),
        flat_cell[flat_cell.len() / 2].0,
        flat_cell[flat_cell.len() / 2].5 * 1e9
    );
}
