//! The firmware's form of the estimator task, `EstimatorTask::run_in_place` (a block's samples
//! in a buffer it overwrites, in two passes), against the reference `run` (one pass over an
//! iterator) on long runs of blocks with every combination of what a sample is for: the
//! discarded samples before a block, the SVE high-passes on and at rest, estimating or not,
//! restarts, both estimators. Every block's result must be the same bit for bit, in f32 and
//! Q31.32, so that the firmware's blocks give the host's results.

use visco_core::excitation::SineTable;
use visco_core::fixed::Q32;
use visco_core::schedule::{
    Block, EstimatorTask, Sample, Target, SAMPLE_EST, SAMPLE_HP, SAMPLE_HP_REST,
};
use visco_core::{Config, Controller};

/// A small deterministic generator (no test dependency needed for a few thousand numbers).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 33) as u32
    }
    fn unit(&mut self) -> f64 {
        f64::from(self.next()) / f64::from(1u32 << 31)
    }
}

fn check<T: SineTable>(name: &str, rate_hz: f64) {
    // DIVE's information sums take one sample in 4 at 1 MHz, in 2 at 500 kHz: the task's
    // prefilter pass forms w and φ only where a later pass reads them.
    let cfg = Config::paper(rate_hz);
    let ctrl = Controller::<T>::new(&cfg).unwrap();
    let mut reference: EstimatorTask<T> = ctrl.estimator_task();
    let mut in_place: EstimatorTask<T> = ctrl.estimator_task();
    let mut rng = Lcg(7);
    let targets = [Target::Sve2, Target::Dive3, Target::Sve3, Target::Dive2];
    let mut updated = 0;
    let mut k = 0u32;
    for block in 0..3000u32 {
        let target = targets[(block / 50) as usize % targets.len()];
        let skip = if rng.next() % 4 == 0 {
            rng.next() % 12
        } else {
            0
        };
        let own = 1 + rng.next() % 40;
        // Z and U in nm around a tip 450 nm in, with tones and noise, so that the filters'
        // outputs and the sums differ from block to block.
        let samples: Vec<Sample<T>> = (0..skip + own)
            .map(|_| {
                k += 1;
                let t = f64::from(k) * 1e-6;
                let u = 900.0 + 40.0 * (t * 6.1e4).sin() + 3.0 * (t * 2.3e5).sin();
                let z = u - 450.0 - 20.0 * (t * 6.1e4 + 0.3).sin() + rng.unit() - 0.5;
                let flags = match rng.next() % 16 {
                    0 => 0,
                    1 => SAMPLE_HP,
                    2 => SAMPLE_EST,
                    3 if rng.next() % 8 == 0 => SAMPLE_HP_REST,
                    _ => SAMPLE_HP | SAMPLE_EST,
                };
                Sample {
                    z: T::from_f64(z),
                    u: T::from_f64(u),
                    r: T::from_f64(455.0),
                    flags,
                }
            })
            .collect();
        let b = Block {
            restart: (block % 97 == 0).then(|| [T::from_f64(1e-5), T::from_f64(0.1), T::ZERO]),
            restart_watch: block % 131 == 0,
            epoch: block,
            target,
            skip,
            samples: own,
            tones: Default::default(),
        };
        let want = reference.run(&b, samples.iter().copied());
        let mut buffer = samples.clone();
        let got = in_place.run_in_place(&b, &mut buffer);
        assert_eq!(
            (got.flags, got.epoch, got.updated),
            (want.flags, want.epoch, want.updated),
            "{name}: block {block}"
        );
        for i in 0..3 {
            assert!(
                got.theta[i].to_f64().to_bits() == want.theta[i].to_f64().to_bits(),
                "{name}: block {block}, θ̂[{i}] {} against {}",
                got.theta[i].to_f64(),
                want.theta[i].to_f64()
            );
        }
        updated += usize::from(want.updated);
    }
    // Nearly every block has an estimating sample: the comparisons above are of updates.
    assert!(updated > 2800, "{name}: only {updated} updates");
}

#[test]
fn run_in_place_equals_run_bit_for_bit_f32() {
    check::<f32>("f32", 1e6);
    check::<f32>("f32, 500 kHz", 5e5);
}

#[test]
fn run_in_place_equals_run_bit_for_bit_q32() {
    check::<Q32>("Q31.32", 1e6);
    check::<Q32>("Q31.32, 500 kHz", 5e5);
}
