//! `visco diagnose` on a 100 000-sample DIVE tap (the plant's paper lever, a bed of discrete
//! elements, two tones running from before the recording starts), timed on one thread and on
//! the machine's cores, with where the time goes: one simulation of the recording, the
//! nominal fit, each selection stage, the locate and report steps, and the simulations spent.
//!
//! `cargo bench -p visco --bench diagnose` (`-- --quick`: a 10 000-sample tap; `-- --sim`:
//! only the simulation, 40 times, of the continuum nominal and of the same on the paper's
//! lattice; under `valgrind --tool=callgrind` it counts their instructions). Timings on a shared machine are noisy: read them as ratios.

#[path = "../tests/diagnose_support/mod.rs"]
mod diagnose_support;

use diagnose_support::{held_out_rms, mid_oscillation_tap, TapProtocol};
use std::time::Instant;
use visco::diagnose::problem::Problem;
use visco::diagnose::report::analyse;
use visco::diagnose::search::{Model, SearchOptions};

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let p = if quick {
        TapProtocol::short()
    } else {
        TapProtocol::long()
    };
    let t = Instant::now();
    let (rec, clean) = mid_oscillation_tap(&p, 11, [0.37, 0.61]);
    let noise = held_out_rms(&rec.d_m, &clean);
    println!(
        "tap: {} samples at {} kHz, generated in {:.2} s; noise RMS {:.4e} m",
        rec.len(),
        p.rate_hz / 1e3,
        t.elapsed().as_secs_f64(),
        noise
    );
    // One simulation of the nominal model over the whole recording.
    let prob = Problem::new(&rec).expect("a problem");
    let init = prob.initial_nominals();
    let model = Model::nominal(init[0].clone());
    let env = visco::diagnose::environment(&prob, &model, None);
    let sim_only = std::env::args().any(|a| a == "--sim");
    let reps = if sim_only { 40 } else { 5 };
    let t = Instant::now();
    for _ in 0..reps {
        std::hint::black_box(prob.simulate(&model, &env, None));
    }
    let sim_s = t.elapsed().as_secs_f64() / reps as f64;
    println!("one simulation of the recording: {:.2} ms", sim_s * 1e3);
    if sim_only {
        // The same nominal on the paper's lattice (100 nm under the 300 nm tip), whose
        // pieces mostly share a propagator where the continuum's each need their own.
        let mut lattice = model.clone();
        lattice.nominal.bed = visco::diagnose::model::Bed::Lattice {
            pitch_nm: 100.0,
            offset: [0.5, 0.5],
        };
        let t = Instant::now();
        for _ in 0..reps {
            std::hint::black_box(prob.simulate(&lattice, &env, None));
        }
        let lat_s = t.elapsed().as_secs_f64() / reps as f64;
        println!("… on the paper's lattice: {:.2} ms", lat_s * 1e3);
        return;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for threads in [1, cores] {
        let opts = SearchOptions {
            threads,
            ..SearchOptions::default()
        };
        let t0 = Instant::now();
        let mut marks: Vec<(String, f64)> = Vec::new();
        let diag = analyse(&rec, &opts, |s| {
            // The phase a progress line opens: "nominal fit", "stage k: …", "locating …".
            let phase = s.split(':').next().unwrap_or(s).to_string();
            if marks.last().is_none_or(|m| m.0 != phase) {
                marks.push((phase, t0.elapsed().as_secs_f64()));
            }
        })
        .expect("diagnosed");
        let total = t0.elapsed().as_secs_f64();
        println!(
            "threads {threads}: {total:.2} s, {} simulations of {} model evaluations ({:.1} s of one-thread simulation at the rate above); nominal held-out RMS {:.4e} m = {:.2}× noise; named {:?}",
            diag.search.simulations,
            diag.search.evaluations,
            diag.search.simulations as f64 * sim_s,
            diag.rms_before_m,
            diag.rms_before_m / noise,
            diag.findings.iter().map(|f| f.kind.as_str()).collect::<Vec<_>>()
        );
        let mut prev = ("start".to_string(), 0.0);
        for (name, at) in marks.iter().cloned().chain([("end".to_string(), total)]) {
            println!("  {:<28} {:>7.2} s", prev.0, at - prev.1);
            prev = (name, at);
        }
        if threads == 1 {
            // Deterministic, unlike the times: the same on any machine.
            println!("  simulations by phase of the search:");
            for (phase, n) in &diag.search.phases {
                println!("    {phase:<52} {n:>6}");
            }
        }
    }
}
