//! An effect that acts only on what the detector reports (baseline tilt, thermal drift, a
//! second mode's optical-lever signal) leaves the cantilever's states alone, so `diagnose`
//! computes its candidates' shape grids by replaying the effect on the states of the model
//! without it (`Problem::reading_added`) instead of simulating. Checked here against the full
//! simulation with the effect added, on a DIVE tap from the plant (contact, tones), for every
//! reading-only kind at several shape points and from a base that already carries an effect
//! acting on the motion: the two readings must agree to rounding (the same arithmetic on the
//! same states: 1e-12 nm on readings of ~100 nm allows ~10⁴ ulps of f64; seen ≤ 2e-15), and
//! every kind that is not reading-only must be refused (it needs a simulation).

mod diagnose_support;

use diagnose_support::{mid_oscillation_tap, TapProtocol};
use visco::diagnose::candidates::Candidate;
use visco::diagnose::model::Trace;
use visco::diagnose::problem::Problem;
use visco::diagnose::search::Model;
use visco::plant::effects::EffectKind;

#[test]
fn reading_only_effects_replay_exactly_on_the_base_states() {
    let (rec, _) = mid_oscillation_tap(&TapProtocol::short(), 5, [0.37, 0.61]);
    let prob = Problem::new(&rec).expect("a problem");
    let nominal = Model::nominal(prob.initial_nominals()[0].clone());
    let mut env = visco::diagnose::environment(&prob, &nominal, None);
    env.mode2_peaks_hz.clear();
    // A base that already carries an effect on the motion (a drag), so the replay must keep
    // the order of the hooks: the new effect last.
    let drag = Candidate::new(EffectKind::HydrodynamicDrag, &env).expect("drag");
    let mut with_drag = nominal.clone();
    let mut v = drag.null_values();
    v[0] = 5.0 * drag.params[0].grid[0];
    with_drag.effects.push((drag, v));
    let mut checked = 0;
    for base in [&nominal, &with_drag] {
        let mut trace = Trace::default();
        let base_sim = prob.simulate(base, &env, Some(&mut trace));
        for kind in EffectKind::ALL {
            let Some(cand) = Candidate::new(kind, &env) else {
                continue;
            };
            // Amplitudes at 10× their probes, shapes at their grids' ends and middle.
            let mut points = Vec::new();
            for pick in [0usize, 1, 2] {
                let mut v = cand.null_values();
                for (j, p) in cand.params.iter().enumerate() {
                    if p.shape {
                        let g = &p.grid;
                        v[j] = g[(pick * (g.len() - 1)) / 2];
                    } else {
                        v[j] = 10.0 * p.grid[0];
                    }
                }
                points.push(v);
            }
            for v in &points {
                let replayed = prob.reading_added(base, &env, &cand, v, &base_sim, &trace);
                if !kind.reading_only() {
                    assert!(replayed.is_none(), "{kind} acts on the motion: no replay");
                    continue;
                }
                let replayed = replayed.expect("a reading-only effect replays");
                let mut full = base.clone();
                full.effects.push((cand.clone(), v.clone()));
                let simulated = prob.simulate(&full, &env, None);
                let moved = simulated
                    .iter()
                    .zip(&base_sim)
                    .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
                let worst = simulated
                    .iter()
                    .zip(&replayed)
                    .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
                println!("{kind} at {v:?}: moves the reading by {moved:.3e} nm, replay off by {worst:.1e} nm");
                // The effect must do something here, or the comparison proves nothing.
                assert!(
                    moved > 1e-3,
                    "{kind} at {v:?} moved the reading by {moved} nm"
                );
                assert!(worst < 1e-12, "{kind} at {v:?}: replay off by {worst} nm");
                checked += 1;
            }
        }
    }
    // Tilt, drift and the second mode, three points each, from both bases.
    assert_eq!(checked, 18);
}
