//! The controller's DIVE and SVE sequences end to end on the exact aggregate plant: the whole
//! per-sample path (input, prefilters, regressor, estimator, contact detector, depth
//! controller, excitation, DAC grid, sequencer, records) in f32, as the board runs it.

mod common;

use common::AggregatePlant;
use visco_core::{
    status, units, Command, Config, Controller, DiveRegressor, Mode, Phase, Record, SveRegressor,
};

const FS: f64 = 1e6;
const K: f64 = 0.099;
const C: f64 = 1.7e-5;

fn run(
    ctrl: &mut Controller<f32>,
    plant: &mut AggregatePlant,
    max_steps: usize,
    mut surface: impl FnMut(f64) -> f64,
) -> Vec<Record<f32>> {
    let mut records = Vec::new();
    let mut d = 0.0f32;
    for _ in 0..max_steps {
        let out = ctrl.step(d);
        if out.status & status::RECORD_READY != 0 {
            records.push(ctrl.take_record().unwrap());
        }
        if ctrl.phase() == Phase::Done {
            break;
        }
        plant.h = surface(out.x_m as f64) / units::LENGTH;
        d = (plant.step(out.u_m as f64 / units::LENGTH) * units::LENGTH) as f32;
    }
    records
}

#[test]
fn dive_taps_recover_the_aggregate_contact() {
    for regressor in [DiveRegressor::Offset, DiveRegressor::Paper] {
        let mut cfg = Config::paper(FS);
        cfg.dive.nx = 2;
        cfg.dive.ny = 2;
        cfg.dive.regressor = regressor;
        let mut ctrl = Controller::<f32>::new(&cfg).unwrap();
        let h = 120e-9;
        let mut plant = AggregatePlant::paper(K, C, h, 1.0 / FS);
        plant.settle_at(cfg.approach.u_start_m / units::LENGTH);
        ctrl.command(Command::Start(Mode::Dive));
        let recs = run(&mut ctrl, &mut plant, 2_000_000, |_| h);
        assert_eq!(recs.len(), 4, "{regressor:?}: one record per tap");
        for r in recs {
            let Record::Tap(t) = r else {
                panic!("not a tap")
            };
            let (c, k) = (t.c_ns_per_m as f64, t.k_n_per_m as f64);
            let h_err = t.bed_height_m() - h;
            println!(
                "{regressor:?} tap {}: c {:.4e} ({:+.3} %), k {:.4e} ({:+.3} %), contact {:.2} nm, bed {:.2} nm ({:+.2} nm), depth {:.1} nm, flags {:#x}, n {}",
                t.index, c, (c / C - 1.0) * 100.0, k, (k / K - 1.0) * 100.0, t.contact_height_m as f64 * 1e9, t.bed_height_m() * 1e9, h_err * 1e9, t.depth_m as f64 * 1e9, t.flags, t.samples
            );
            assert_eq!(
                t.flags & (status::NO_CONTACT | status::SHORT_DWELL | status::EST_RESET),
                0
            );
            assert!((c / C - 1.0).abs() < 2e-3, "c {c}");
            assert!((k / K - 1.0).abs() < 2e-3, "k {k}");
            // The contact detector fires within a few nm of the surface (γ = 0.3 nm of
            // deflection on k = 0.1 N/m: 0.54 nm, plus the low-pass lag at 100 µm/s);
            // the offset form finds the surface itself.
            assert!(t.contact_height_m as f64 <= h && (h - t.contact_height_m as f64) < 10e-9);
            if regressor == DiveRegressor::Offset {
                assert!(h_err.abs() < 0.2e-9, "bed height off by {h_err}");
            }
            assert!((t.depth_m as f64 - cfg.dive.indent_depth_m).abs() < 30e-9);
        }
    }
}

/// A 100 nm rise over the 5 µm line, with a 40 nm bump in the middle.
fn bumpy(x: f64) -> f64 {
    100e-9 + 20e-9 * x / 1e-6 + 40e-9 * (-((x - 2.5e-6) / 0.6e-6).powi(2)).exp()
}

/// Scan 2 lines of 20 pixels over `surface`; worst pixel errors of c, k (relative), height and
/// depth (m).
fn sve_worst(regressor: SveRegressor, line_period_s: f64, surface: fn(f64) -> f64) -> [f64; 4] {
    let mut cfg = Config::paper(FS);
    cfg.sve.regressor = regressor;
    cfg.sve.lines = 2;
    cfg.sve.pixels = 20;
    cfg.sve.line_period_s = line_period_s;
    let mut ctrl = Controller::<f32>::new(&cfg).unwrap();
    let mut plant = AggregatePlant::paper(K, C, surface(0.0), 1.0 / FS);
    plant.settle_at(cfg.approach.u_start_m / units::LENGTH);
    ctrl.command(Command::Start(Mode::Sve));
    let recs = run(
        &mut ctrl,
        &mut plant,
        (2.5 * line_period_s * FS) as usize + 200_000,
        surface,
    );
    assert_eq!(recs.len(), 2 * 2 * 20, "pixels of 2 lines × 2 directions");
    let depth_eff = cfg.sve_effective_depth_m();
    let mut worst = [0.0f64; 4];
    for r in &recs {
        let Record::Pixel(p) = r else {
            panic!("not a pixel")
        };
        let x = p.x_m as f64;
        let errs = [
            p.c_ns_per_m as f64 / C - 1.0,
            p.k_n_per_m as f64 / K - 1.0,
            p.bed_height_m as f64 - surface(x),
            p.depth_m as f64 - depth_eff,
        ];
        for i in 0..4 {
            worst[i] = worst[i].max(errs[i].abs());
        }
        assert_eq!(p.flags & status::EST_RESET, 0);
    }
    println!("{regressor:?}, line period {line_period_s} s: worst pixel errors c {:.3} %, k {:.3} %, height {:.2} nm, depth {:.2} nm", worst[0] * 100.0, worst[1] * 100.0, worst[2] * 1e9, worst[3] * 1e9);
    worst
}

#[test]
fn sve_decoupled_scan_tracks_a_bumpy_surface_at_depth() {
    // 26 µm/s over a 40 nm bump: the decoupled regression keeps c and k within 0.1 %.
    let worst = sve_worst(SveRegressor::Decoupled, 0.4, bumpy);
    assert!(worst[0] < 1e-3 && worst[1] < 1e-3, "c/k off by {worst:?}");
    assert!(worst[2] < 2e-9, "height off by {} nm", worst[2] * 1e9);
    assert!(worst[3] < 2e-9, "depth off by {} nm", worst[3] * 1e9);
}

#[test]
fn sve_paper_regressor_tracks_a_slope_when_scanning_slowly() {
    // The paper's form must track θ₃ = k·(h − z₀) as the surface rises: on a 20 nm/µm slope at
    // its 2 s line period (5 µm/s) it is accurate; on the bump at 26 µm/s it is not (measured
    // for the record, see the decoupled test).
    fn slope(x: f64) -> f64 {
        100e-9 + 20e-9 * x / 1e-6
    }
    let worst = sve_worst(SveRegressor::Paper, 2.0, slope);
    assert!(worst[0] < 0.01 && worst[1] < 0.02, "c/k off by {worst:?}");
    assert!(worst[2] < 3e-9, "height off by {} nm", worst[2] * 1e9);
    let fast = sve_worst(SveRegressor::Paper, 0.4, bumpy);
    assert!(
        fast[1] > 0.05,
        "expected the paper's form to lag on the fast bump: {fast:?}"
    );
}

/// The firmware's schedule — every estimating sample queued by the step (`step_loop`'s sink),
/// at a block close the estimator's result adopted, then the block's header handed over
/// (`close_block`) before the step, the task run apart on its own copy (`estimator_task`)
/// over the samples the header counts after discarding those it skips, as the estimator
/// interrupt does — gives the host's `step` bit for bit, for both targets (three parameters
/// in DIVE with the offset regressor, two in decoupled SVE). Every block has at most N
/// samples; the samples discarded after the restarts of a new tap or line are exercised too.
#[test]
fn firmware_schedule_matches_step_bit_for_bit() {
    use std::collections::VecDeque;
    use visco_core::excitation::{fill_chunk, ChunkKey, ToneChunk, ToneSource};
    use visco_core::schedule::{Sample, SampleSink};
    /// The firmware's link in short: the samples queued, and the chunks of tones the task
    /// computed ahead (issue 14, round 7), taken as the firmware's `QueueLink` takes them.
    struct Sink {
        queue: VecDeque<Sample<f32>>,
        ready: VecDeque<ToneChunk<f32>>,
        cur: ToneChunk<f32>,
        taken: u32,
        late: u32,
    }
    impl ToneSource<f32> for Sink {
        fn take_tones(&mut self, key: &ChunkKey<f32>) -> bool {
            while let Some(c) = self.ready.front() {
                if c.key.chunk.wrapping_sub(key.chunk) as i32 > 0 {
                    break;
                }
                let c = self.ready.pop_front().unwrap();
                if c.key == *key {
                    self.cur = c;
                    self.taken += 1;
                    return true;
                }
            }
            self.late += 1;
            false
        }
        fn tone(&self, left: u32) -> f32 {
            self.cur.values[left as usize]
        }
    }
    impl SampleSink<f32> for Sink {
        fn push(&mut self, s: Sample<f32>) {
            self.queue.push_back(s);
        }
    }
    let h = 120e-9;
    let mut dive = Config::paper(FS);
    dive.dive.nx = 1;
    dive.dive.ny = 1;
    dive.dive.regressor = DiveRegressor::Offset;
    let mut sve = Config::paper(FS);
    sve.sve.regressor = SveRegressor::Decoupled;
    sve.sve.lines = 1;
    sve.sve.pixels = 10;
    sve.sve.line_period_s = 0.1;
    for (cfg, mode, steps, want_three) in [
        (dive, Mode::Dive, 200_000usize, true),
        (sve, Mode::Sve, 250_000, false),
    ] {
        let n = cfg
            .dive
            .estimator
            .decimation
            .max(cfg.sve.estimator.decimation);
        let mut host = Controller::<f32>::new(&cfg).unwrap();
        let mut fw = Controller::<f32>::new(&cfg).unwrap();
        let mut task = fw.estimator_task();
        // The firmware's two-pass form on the same blocks (`run_in_place`, the samples in a
        // buffer it overwrites), compared with `run` block by block.
        let mut task2 = fw.estimator_task();
        let mut plant = AggregatePlant::paper(K, C, h, 1.0 / FS);
        plant.settle_at(cfg.approach.u_start_m / units::LENGTH);
        host.command(Command::Start(mode));
        fw.command(Command::Start(mode));
        let (mut result, mut blocks, mut skipped) = (None, 0u32, 0u32);
        let mut sink = Sink {
            queue: VecDeque::new(),
            ready: VecDeque::new(),
            cur: ToneChunk::new(0.0),
            taken: 0,
            late: 0,
        };
        let mut next_chunk = 1u32;
        let mut d = 0.0f32;
        for i in 0..steps {
            if fw.block_due() {
                if let Some(r) = result.take() {
                    fw.deliver(&r);
                }
                fw.close_block(|b| {
                    // Before the first restart (the mode's approach) the blocks only feed the
                    // task's filters, for the estimator the controller was built with.
                    if b.epoch > 0 {
                        assert_eq!(!b.target.two(), want_three, "{mode:?}: target");
                    }
                    let samples = b.samples;
                    assert!(samples >= 1 && samples <= n, "{mode:?}: {samples} samples");
                    assert!(
                        sink.queue.len() == (b.skip + samples) as usize,
                        "{mode:?}: {} queued for {} + {samples}",
                        sink.queue.len(),
                        b.skip
                    );
                    skipped += b.skip;
                    let mut buf: Vec<Sample<f32>> = sink.queue.iter().copied().collect();
                    let r2 = task2.run_in_place(&b, &mut buf);
                    let r = task.run(&b, sink.queue.drain(..));
                    // The chunks of tones the block asks for, computed at once.
                    task.tones_ahead(&b.tones, |key, p| {
                        if (key.chunk.wrapping_sub(next_chunk) as i32) < 0 {
                            return;
                        }
                        next_chunk = key.chunk.wrapping_add(1);
                        let mut c = ToneChunk::new(0.0);
                        c.key = *key;
                        fill_chunk(p, key, &mut c.values);
                        sink.ready.push_back(c);
                    });
                    assert_eq!(
                        (r.theta.map(f32::to_bits), r.flags, r.epoch, r.updated),
                        (r2.theta.map(f32::to_bits), r2.flags, r2.epoch, r2.updated),
                        "{mode:?}: block {blocks} in place"
                    );
                    result = Some(r);
                    blocks += 1;
                });
            }
            let a = host.step(d);
            let b = fw.step_loop_m(d, &mut sink);
            assert_eq!(
                (a.u_code, a.x_code, a.y_code, a.status, a.u_m.to_bits()),
                (b.u_code, b.x_code, b.y_code, b.status, b.u_m.to_bits()),
                "{mode:?}: sample {i}"
            );
            if ctrl_done(&host) {
                break;
            }
            d = (plant.step(a.u_m as f64 / units::LENGTH) * units::LENGTH) as f32;
        }
        // Thousands of hand-overs (5 466 in DIVE, 4 064 in SVE when written), each block's
        // effect compared sample by sample above.
        println!(
            "{mode:?}: {blocks} blocks handed over, {skipped} samples discarded; chunks of tones \
             {} precomputed, {} by the loop",
            sink.taken, sink.late
        );
        assert!(blocks > 300, "{mode:?}: only {blocks} blocks");
        // The loop's own chunks: the first of each mode's stretches with blocks, and where
        // the tones stood still (no chunk of the task's then).
        assert!(
            sink.taken > 20 * sink.late,
            "{mode:?}: {} precomputed, {} by the loop",
            sink.taken,
            sink.late
        );
    }
}

fn ctrl_done(c: &Controller<f32>) -> bool {
    c.phase() == Phase::Done
}

/// The block headers' counts (`skip + samples`, derived from the block clock, not counted per
/// sample) equal the samples the sink holds at every close, also when the modes' block
/// lengths differ, one of them blocks of one (no sample handed over, the clock standing), and
/// commands switch between them in the middle of blocks, of taps and of restarts.
#[test]
fn block_counts_follow_the_sink_across_modes_of_other_block_lengths() {
    use std::collections::VecDeque;
    let h = 120e-9;
    for (dec_dive, dec_sve) in [(1, 32), (32, 1), (16, 40), (64, 64)] {
        let mut cfg = Config::paper(FS);
        cfg.dive.nx = 2;
        cfg.dive.ny = 1;
        cfg.dive.estimator.decimation = dec_dive;
        cfg.sve.estimator.decimation = dec_sve;
        cfg.sve.lines = 1;
        cfg.sve.pixels = 10;
        cfg.sve.line_period_s = 0.1;
        let mut fw = Controller::<f32>::new(&cfg).unwrap();
        let mut plant = AggregatePlant::paper(K, C, h, 1.0 / FS);
        plant.settle_at(cfg.approach.u_start_m / units::LENGTH);
        let mut queue: VecDeque<u32> = VecDeque::new();
        let (mut blocks, mut skipped) = (0u32, 0u32);
        let mut d = 0.0f32;
        // Commands mid-block and mid-run: SVE, a stop, DIVE, SVE again, two commands between
        // the same two steps, DIVE to the end.
        let commands: &[(usize, &[Command])] = &[
            (0, &[Command::Start(Mode::Sve)]),
            (40_013, &[Command::Stop]),
            (40_101, &[Command::Start(Mode::Dive)]),
            (90_007, &[Command::Start(Mode::Sve)]),
            (140_003, &[Command::Stop, Command::Start(Mode::Dive)]),
        ];
        for i in 0..260_000usize {
            for (at, cmds) in commands {
                if *at == i {
                    for c in *cmds {
                        fw.command(*c);
                    }
                }
            }
            if fw.block_due() {
                fw.close_block(|b| {
                    assert_eq!(
                        (b.skip + b.samples) as usize,
                        queue.len(),
                        "decimation {dec_dive}/{dec_sve}: block {blocks} at step {i}"
                    );
                    assert!(
                        b.samples >= 1,
                        "decimation {dec_dive}/{dec_sve}: empty block"
                    );
                    skipped += b.skip;
                    queue.clear();
                    blocks += 1;
                });
            }
            let out = fw.step_loop_m(d, &mut |_| queue.push_back(0));
            d = (plant.step(out.u_m as f64 / units::LENGTH) * units::LENGTH) as f32;
        }
        println!("decimation {dec_dive}/{dec_sve}: {blocks} blocks, {skipped} samples discarded");
        assert!(
            blocks > 1000,
            "decimation {dec_dive}/{dec_sve}: only {blocks} blocks"
        );
    }
}
