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

/// The fits' offset column costs no simulation (`Problem::polish`: a point that differs from
/// the last simulated one in the detector offset alone reuses its reading before the offset).
/// That holds bit for bit only if nothing in a simulation reads the offset but the last
/// addition: checked on a tap with effects on the motion and on the reading.
#[test]
fn the_reading_before_the_offset_does_not_depend_on_it() {
    use visco::diagnose::model::{simulate, simulate_before_offset};
    let (rec, _) = mid_oscillation_tap(&TapProtocol::short(), 7, [0.37, 0.61]);
    let prob = Problem::new(&rec).expect("a problem");
    let mut model = Model::nominal(prob.initial_nominals()[0].clone());
    let env = visco::diagnose::environment(&prob, &model, None);
    for kind in [EffectKind::HydrodynamicDrag, EffectKind::ThermalDrift] {
        let cand = Candidate::new(kind, &env).expect("a candidate");
        let mut v = cand.null_values();
        v[0] = 5.0 * cand.params[0].grid[0];
        model.effects.push((cand, v));
    }
    let run = |offset: f64, before: bool| {
        let mut m = model.clone();
        m.nominal.offset = offset;
        let mut fx = m.build_effects(&env);
        if before {
            simulate_before_offset(&prob.inst, &m.nominal, &mut fx, &prob.data, None)
        } else {
            simulate(&prob.inst, &m.nominal, &mut fx, &prob.data, None)
        }
    };
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let base = run(0.0, true);
    assert!(base.len() == prob.data.len() && base.iter().all(|x| x.is_finite()));
    for offset in [-3.7e2, 0.123, 41.0] {
        assert_eq!(bits(&run(offset, true)), bits(&base), "offset {offset}");
        let full = run(offset, false);
        let added: Vec<f64> = base.iter().map(|y| y + offset).collect();
        assert_eq!(bits(&full), bits(&added), "offset {offset}");
    }
}
