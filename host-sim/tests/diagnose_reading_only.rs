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
use visco::diagnose::model::{Bed, Trace};
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
    let (prob, mut model, env) = short_tap(7);
    for kind in [EffectKind::HydrodynamicDrag, EffectKind::ThermalDrift] {
        let cand = Candidate::new(kind, &env).expect("a candidate");
        let mut v = cand.null_values();
        v[0] = 5.0 * cand.params[0].grid[0];
        model.effects.push((cand, v));
    }
    let run = |bed: Bed, offset: f64, before: bool| {
        let mut m = model.clone();
        m.nominal.bed = bed;
        m.nominal.offset = offset;
        let mut fx = m.build_effects(&env);
        if before {
            simulate_before_offset(&prob.inst, &m.nominal, &mut fx, &prob.data, None)
        } else {
            simulate(&prob.inst, &m.nominal, &mut fx, &prob.data, None)
        }
    };
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    // The continuum bed, then a lattice (its event search in contact).
    for bed in [
        model.nominal.bed,
        Bed::Lattice {
            pitch_nm: 100.0,
            offset: [0.3, 0.6],
        },
    ] {
        let base = run(bed, 0.0, true);
        assert!(base.len() == prob.data.len() && base.iter().all(|x| x.is_finite()));
        for offset in [-3.7e2, 0.123, 41.0] {
            assert_eq!(
                bits(&run(bed, offset, true)),
                bits(&base),
                "{bed:?}, offset {offset}"
            );
            let full = run(bed, offset, false);
            let added: Vec<f64> = base.iter().map(|y| y + offset).collect();
            assert_eq!(bits(&full), bits(&added), "{bed:?}, offset {offset}");
        }
    }
}

/// The fits' residuals (`Problem::fit_residual`, and `Problem::residual` over every sample)
/// come from the thread's recent simulations
/// where the model differs from one of them in the detector offset alone, and are then what a
/// fresh simulation gives, bit for bit; a model that differs in anything else (a contact's
/// stiffness, an effect's value, the scales the effects are built with) is simulated anew.
#[test]
fn the_fits_residuals_reuse_a_recent_simulation_only_across_the_offset() {
    use visco::diagnose::candidates::Env;
    let (prob, mut m0, env) = short_tap(9);
    let drag = Candidate::new(EffectKind::HydrodynamicDrag, &env).expect("drag");
    let mut v = drag.null_values();
    v[0] = 5.0 * drag.params[0].grid[0];
    m0.effects.push((drag, v));
    // A fresh simulation's residual on the fit samples, with the prior rows (the model's own
    // simulation, outside the problem and its cache).
    let fresh = |m: &Model, env: &Env| -> Vec<u64> {
        let mut fx = m.build_effects(env);
        let sim =
            visco::diagnose::model::simulate(&prob.inst, &m.nominal, &mut fx, &prob.data, None);
        let r: Vec<f64> = prob.data.d.iter().zip(&sim).map(|(a, b)| a - b).collect();
        // `Problem::residual` (every sample) goes through the cache too.
        let through: Vec<u64> = prob.residual(m, env).iter().map(|x| x.to_bits()).collect();
        assert_eq!(through, r.iter().map(|x| x.to_bits()).collect::<Vec<u64>>());
        let mut out: Vec<f64> = r
            .iter()
            .zip(&prob.fit)
            .filter(|(_, &fit)| fit)
            .map(|(&x, _)| x)
            .collect();
        out.extend(prob.prior_rows(m, env));
        out.iter().map(|x| x.to_bits()).collect()
    };
    // The residual, and whether it took a simulation.
    let cached = |m: &Model, env: &Env| -> (Vec<u64>, usize) {
        let before = prob.simulations_run();
        let r = prob.fit_residual(m, env).expect("finite");
        (
            r.iter().map(|x| x.to_bits()).collect(),
            prob.simulations_run() - before,
        )
    };
    let mut m1 = m0.clone();
    m1.nominal.offset += 3.7;
    let mut m2 = m1.clone();
    m2.nominal.contacts[0].k_a *= 1.01;
    let mut m3 = m2.clone();
    m3.effects[0].1[0] *= 2.0;
    let mut env2 = env.clone();
    env2.k_n_per_m *= 1.5;
    for (what, m, e, simulated) in [
        ("the first", &m0, &env, 1),
        ("another offset", &m1, &env, 0),
        ("another contact stiffness", &m2, &env, 1),
        ("another drag", &m3, &env, 1),
        ("the first again, with another offset", &m1, &env, 0),
        ("other scales", &m3, &env2, 1),
    ] {
        let (r, runs) = cached(m, e);
        assert_eq!(r, fresh(m, e), "{what}: the residual of a fresh simulation");
        assert_eq!(runs, simulated, "{what}: simulations run");
    }
}

/// A short plant tap recorded mid-oscillation, its problem, nominal model and scales.
fn short_tap(seed: u64) -> (Problem, Model, visco::diagnose::candidates::Env) {
    let (rec, _) = mid_oscillation_tap(&TapProtocol::short(), seed, [0.37, 0.61]);
    let prob = Problem::new(&rec).expect("a problem");
    let model = Model::nominal(prob.initial_nominals()[0].clone());
    let env = visco::diagnose::environment(&prob, &model, None);
    (prob, model, env)
}
