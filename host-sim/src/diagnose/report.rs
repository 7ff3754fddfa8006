//! The diagnosis as a whole: [`analyse`] a recording in memory (no I/O), [`diagnose`] a file
//! and write its report (`recording.md` §2), series and figures, all or nothing.
//!
//! Outputs, next to the report or in `--out DIR`, named after the report's stem:
//! `<stem>_series.csv` (every sample: recorded, nominal and extended D, the residuals, the
//! phase, whether held out), `<stem>_overview.png` (the whole recording), one
//! `<stem>_effect<i>_<effect>.png` per effect found (recorded, nominal and extended D and the
//! residual before and after, over where it acts), `<stem>_spectrum.png` (the residual's
//! spectrum before and after, with the tested lines).

use std::path::{Path, PathBuf};

use super::candidates::Env;
use super::explain::explain;
use super::json_report as jr;
use super::locate::{hold_reading, locate, phases, spans, HoldReading, Located, Phase, Span};
use super::model::{Input, Trace};
use super::noise::HeldOut;
use super::problem::{Problem, BLOCK};
use super::search::{c_a_si, k_a_si, Search, SearchOptions, DETECTION_FLOOR, SCREEN_POLISHED};
use crate::identify::error::{IdentifyError, Result};
use crate::identify::figures::plain;
use crate::identify::files::{push_num, Staged};
use crate::output::figure::{self, LinePanel, LinePlot, Quantity, Series, PALETTE};
use crate::plant::effects::EffectKind;
use crate::recording::{Mode, Recording};
use crate::report::{nums, Num, Ordered};
use visco_core::units::{LENGTH, TIME};

/// The nominal model, in the report's words.
pub const NOMINAL_MODEL: &str =
    "cantilever first mode + spherical tip on a Kelvin–Voigt element bed";

/// Largest recording diagnosed (rows): it is held in memory and simulated a few thousand
/// times.
pub const MAX_ROWS: usize = 4_000_000;

/// What the command line (or a caller) chooses.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The JSON report.
    pub json: PathBuf,
    /// Directory for the figures and the series (default: the report's).
    pub out_dir: Option<PathBuf>,
    /// Family-wise false-alarm rate of each selection stage (and of the locate tests).
    pub alpha: f64,
    /// At most this many effects.
    pub max_effects: usize,
    /// The candidates.
    pub effects: Vec<EffectKind>,
    /// Report each step on stderr.
    pub progress: bool,
    /// Write the figures.
    pub figures: bool,
}

impl Options {
    /// Defaults, writing the report to `json`.
    pub fn new(json: impl Into<PathBuf>) -> Self {
        Options {
            json: json.into(),
            out_dir: None,
            alpha: 0.01,
            max_effects: 3,
            effects: EffectKind::ALL.to_vec(),
            progress: false,
            figures: true,
        }
    }
    fn search(&self) -> SearchOptions {
        SearchOptions {
            alpha: self.alpha,
            max_effects: self.max_effects,
            kinds: self.effects.clone(),
            ..SearchOptions::default()
        }
    }
}

/// One effect found.
#[derive(Clone, Debug)]
pub struct Finding {
    pub kind: EffectKind,
    pub explanation: String,
    pub spans: Vec<Span>,
    /// Parameters by name, SI.
    pub parameters: Vec<(String, f64)>,
    /// Held-out RMS where it acts (its contribution a tenth of its peak or more), before and
    /// after it joined the model (m).
    pub rms_before_m: f64,
    pub rms_after_m: f64,
    pub evidence: HeldOut,
    /// The per-test level it passed.
    pub level: f64,
    /// Its largest contribution to D and the noise it was compared with (m).
    pub peak_m: f64,
    pub noise_m: f64,
    /// Per phase where it acts: held-out RMS before and after it joined the model (m).
    pub phases: Vec<(Phase, f64, f64)>,
}

/// The result of [`analyse`].
#[derive(Clone, Debug)]
pub struct Diagnosis {
    pub problem: Problem,
    pub search: Search,
    pub env: Env,
    /// Held-out RMS of recorded − simulated D, nominal and final (m).
    pub rms_before_m: f64,
    pub rms_after_m: f64,
    /// The final model's held-out [`super::search::contact_misfit`]: its RMS over that far out
    /// of contact.
    pub contact_misfit: f64,
    /// The final model's held-out RMS over the noise: its sample-to-sample scatter
    /// ([`super::search::misfit_ratio`]) and, for a dynamic model, the free lever's thermal
    /// noise at room temperature (√(k_B·T/K), which the scatter of a resonant lever's samples
    /// does not see), in quadrature.
    pub misfit_over_noise: f64,
    pub findings: Vec<Finding>,
    pub located: Located,
    pub phase: Vec<Phase>,
    /// Simulated D (m) of the nominal and final models, every sample.
    pub nominal_d_m: Vec<f64>,
    pub final_d_m: Vec<f64>,
    /// Simulated D (m) of the model before and after each finding.
    pub stages_d_m: Vec<Vec<f64>>,
    pub alpha: f64,
    /// The longest hold in contact, read for who moved (sample or scanner).
    pub hold: Option<HoldReading>,
}

/// The temperature the lever's thermal noise is counted at (K): a recording does not carry
/// its own; 10 % either way moves the noise by 5 %.
const ROOM_TEMPERATURE_K: f64 = 300.0;

/// The free lever's thermal variance k_B·T/K at [`ROOM_TEMPERATURE_K`] (nm²), part of a
/// dynamic model's noise that no fit removes; 0 for a static model.
pub fn lever_thermal_nm2(p: &Problem) -> f64 {
    if p.inst.dynamic() && p.inst.k > 0.0 {
        // K in N/m = nN/nm.
        crate::plant::BOLTZMANN_J_PER_K * ROOM_TEMPERATURE_K / p.inst.k * 1e18
    } else {
        0.0
    }
}

/// Diagnoses a recording held in memory (no files).
pub fn analyse(
    rec: &Recording,
    opts: &SearchOptions,
    mut progress: impl FnMut(&str),
) -> std::result::Result<Diagnosis, String> {
    if rec.meta.mode == Mode::Sve {
        return Err(
            "an SVE scan's topography changes under the tip along every line, which \
                    the flat bed of the nominal model cannot follow; diagnose handles taps \
                    (dive) and force curves"
                .into(),
        );
    }
    if rec.len() > MAX_ROWS {
        return Err(format!(
            "{} rows: a diagnosis holds the recording in memory and simulates it thousands of \
             times, up to {MAX_ROWS} rows",
            rec.len()
        ));
    }
    let p = Problem::new(rec).map_err(|e| e.0)?;
    let search = p.search(opts, &mut progress);
    progress("locating the misfit");
    let env = search.env.clone();
    let mut tr_nom = Trace::default();
    let sim_nom = p.simulate(&search.nominal, &env, Some(&mut tr_nom));
    let sim_fin = p.simulate(&search.model, &env, None);
    let d = &p.data.d;
    let r_nom: Vec<f64> = d.iter().zip(&sim_nom).map(|(a, b)| a - b).collect();
    let r_fin: Vec<f64> = d.iter().zip(&sim_fin).map(|(a, b)| a - b).collect();
    let phase = phases(&p, &tr_nom);
    let located = locate(
        &p,
        &phase,
        &tr_nom,
        &r_nom,
        &r_fin,
        &search.nominal_noise,
        opts.alpha,
    );
    // Held-out RMS of a residual in nm, over the samples `idx` selects, in metres.
    let held_rms = |r: &[f64], idx: &dyn Fn(usize) -> bool| {
        let (s, n) = r
            .iter()
            .enumerate()
            .filter(|&(i, _)| p.held[i] && idx(i))
            .fold((0.0, 0usize), |(s, n), (_, x)| (s + x * x, n + 1));
        if n == 0 {
            f64::NAN
        } else {
            (s / n as f64).sqrt() * LENGTH
        }
    };
    let hold = hold_reading(&p, &phase, search.nominal_noise.raw_sigma);
    // Each finding against the model before it.
    let mut findings = Vec::new();
    let mut stages_d = vec![sim_nom.iter().map(|x| x * LENGTH).collect::<Vec<f64>>()];
    for (k, t) in search.chosen.iter().enumerate() {
        let sim_a = p.simulate(&t.model, &env, None);
        let sp = spans(&p, &phase, &t.contribution, t.noise_rms, 6);
        let (cand, vals) = t.model.effects.last().expect("an effect was added");
        let peak = t.peak() * LENGTH;
        // Per phase, over the held-out samples where it acts.
        let before = stages_d.last().expect("the nominal stage").clone();
        let acts = |i: usize| t.contribution[i].abs() >= 0.1 * t.peak();
        let by_phase: Vec<(Phase, f64, f64)> = Phase::ALL
            .iter()
            .filter_map(|&ph| {
                let sel = |i: usize| phase[i] == ph && acts(i);
                let n = (0..d.len()).filter(|&i| p.held[i] && sel(i)).count();
                if n < 16 {
                    return None;
                }
                let rb: Vec<f64> = d.iter().zip(&before).map(|(a, b)| a - b / LENGTH).collect();
                let ra: Vec<f64> = d.iter().zip(&sim_a).map(|(a, b)| a - b).collect();
                Some((ph, held_rms(&rb, &sel), held_rms(&ra, &sel)))
            })
            .collect();
        findings.push(Finding {
            phases: by_phase,
            kind: t.kind,
            explanation: {
                let mut e = explain(t.kind, vals, &env, &sp, peak);
                // Creep of the sample or of the scanner: the hold says which.
                if let (EffectKind::StressRelaxation | EffectKind::PiezoCreep, Some(h)) =
                    (t.kind, &hold)
                {
                    e.push_str("; ");
                    e.push_str(&h.reading);
                }
                e
            },
            parameters: cand.spec(vals, &env).parameters(),
            rms_before_m: t.rms_where_before * LENGTH,
            rms_after_m: t.rms_where_after * LENGTH,
            evidence: t.test,
            level: search.levels.get(k).copied().unwrap_or(f64::NAN),
            peak_m: peak,
            noise_m: t.noise_rms * LENGTH,
            spans: sp,
        });
        stages_d.push(sim_a.iter().map(|x| x * LENGTH).collect());
    }
    let all = |_: usize| true;
    // The final model's depths: the nominal's where nothing was named.
    let depth_fin = if search.model.effects.is_empty() {
        tr_nom.depth.clone()
    } else {
        let mut tr = Trace::default();
        let _ = p.simulate(&search.model, &env, Some(&mut tr));
        tr.depth
    };
    let contact_misfit = super::search::contact_misfit(&r_fin, &depth_fin, &p.held);
    let held_fin: Vec<f64> = r_fin
        .iter()
        .zip(&p.held)
        .filter(|(_, h)| **h)
        .map(|(x, _)| *x)
        .collect();
    // The thermal term joins the scatter in quadrature.
    let rms_fin =
        (held_fin.iter().map(|x| x * x).sum::<f64>() / held_fin.len().max(1) as f64).sqrt();
    let scatter = super::search::sample_scatter(&held_fin);
    let thermal_nm2 = lever_thermal_nm2(&p);
    let misfit_over_noise = rms_fin / (scatter * scatter + thermal_nm2).sqrt().max(1e-300);
    Ok(Diagnosis {
        rms_before_m: held_rms(&r_nom, &all),
        rms_after_m: held_rms(&r_fin, &all),
        contact_misfit,
        misfit_over_noise,
        // What a user compares with the recording: the models with the baseline wave.
        nominal_d_m: with_wave_m(&p, &sim_nom),
        final_d_m: with_wave_m(&p, &sim_fin),
        stages_d_m: stages_d
            .into_iter()
            .map(|s| with_wave_m(&p, &s.iter().map(|x| x / LENGTH).collect::<Vec<f64>>()))
            .collect(),
        problem: p,
        search,
        env,
        findings,
        located,
        phase,
        alpha: opts.alpha,
        hold,
    })
}

/// A simulated D (nm) with the problem's baseline wave, in metres.
fn with_wave_m(p: &Problem, sim_nm: &[f64]) -> Vec<f64> {
    p.with_wave(sim_nm.to_vec())
        .into_iter()
        .map(|x| x * LENGTH)
        .collect()
}

impl Diagnosis {
    /// The report (`recording.md` §2 and more); the files written beside it are the caller's.
    pub fn to_json(&self, recording: &str, rec: &Recording) -> jr::DiagnoseReport {
        let p = &self.problem;
        let left_out: Vec<jr::LeftOut> = self
            .findings
            .iter()
            .map(|f| jr::LeftOut {
                effect: f.kind.as_str().into(),
                explanation: f.explanation.clone(),
                where_: f.spans.iter().map(Span::to_json).collect(),
                parameters: Ordered(
                    f.parameters
                        .iter()
                        .map(|(k, v)| (k.clone(), Num(*v)))
                        .collect(),
                ),
                rms_before_m: f.rms_before_m.into(),
                rms_after_m: f.rms_after_m.into(),
                phases: f
                    .phases
                    .iter()
                    .map(|(ph, b, a)| jr::PhaseRms {
                        phase: ph.as_str().into(),
                        rms_before_m: (*b).into(),
                        rms_after_m: (*a).into(),
                    })
                    .collect(),
                evidence: jr::Evidence {
                    statistic: "held-out likelihood ratio".into(),
                    value: (2.0 * f.evidence.loglik_gain).into(),
                    z: f.evidence.z.into(),
                    p_value: f.evidence.p_value.into(),
                    level: f.level.into(),
                    held_out_samples: f.evidence.n as u64,
                    peak_contribution_m: f.peak_m.into(),
                    noise_rms_m: f.noise_m.into(),
                    physics: f.kind.physics().into(),
                },
            })
            .collect();
        let s = &self.search;
        let contacts: Vec<jr::ContactJson> = s
            .nominal
            .nominal
            .contacts
            .iter()
            .enumerate()
            .map(|(u, c)| {
                let (a, b) = p.unit_rows[u];
                let xy = p.unit_xy_m[u];
                jr::ContactJson {
                    unit: u as u64,
                    rows: [a as u64 + 1, b as u64],
                    in_contact: c.k_a > 0.0,
                    contact_height_m: (c.h * LENGTH).into(),
                    k_a_n_per_m3: k_a_si(c.k_a).into(),
                    c_a_ns_per_m3: c_a_si(c.c_a).into(),
                    x_m: xy.map(|(x, _)| x),
                    y_m: xy.map(|(_, y)| y),
                }
            })
            .collect();
        let stages: Vec<jr::Stage> = s
            .levels
            .iter()
            .enumerate()
            .map(|(stage, level)| jr::Stage {
                stage: stage as u64 + 1,
                level: (*level).into(),
                candidates: s
                    .tested
                    .iter()
                    .filter(|(st, _, _)| *st == stage)
                    .map(|(_, t, chosen)| jr::Candidate {
                        effect: t.kind.as_str().into(),
                        z: t.test.z.into(),
                        p_value: t.test.p_value.into(),
                        held_out_loglik_gain: t.test.loglik_gain.into(),
                        ranking_gain: t.rank_gain.into(),
                        peak_contribution_m: (t.peak() * LENGTH).into(),
                        noise_rms_m: (t.noise_rms * LENGTH).into(),
                        passed_test: t.test.p_value < *level,
                        passed_floor: t.peak() >= DETECTION_FLOOR * t.noise_rms,
                        amplitude_at_limit: t.at_limit(),
                        rms_where_before_m: (t.rms_where_before * LENGTH).into(),
                        rms_where_after_m: (t.rms_where_after * LENGTH).into(),
                        chosen: *chosen,
                    })
                    .collect(),
                screened_out: s
                    .screened_out
                    .iter()
                    .filter(|(st, _, _)| *st == stage)
                    .map(|(_, kind, gain)| jr::ScreenedOut {
                        effect: kind.as_str().into(),
                        linear_ssr_gain: (*gain).into(),
                    })
                    .collect(),
            })
            .collect();
        let nn = &s.nominal_noise;
        let nom = &s.nominal.nominal;
        let (initial_state, calibration) = if p.inst.dynamic() {
            let cal = nom.instrument(&p.inst);
            (
                Some(jr::InitialState {
                    model: "fitted: Z's departure from static equilibrium with the first U, and \
                            Ż, at the first sample"
                        .into(),
                    z0_m: (nom.z0 * LENGTH).into(),
                    v0_m_per_s: (nom.v0 * LENGTH / TIME).into(),
                }),
                Some(jr::Calibration {
                    model: if p.resonance_resolved() {
                        format!(
                            "the header's f0 and Q as calibrations: corrections fitted under a \
                             Gaussian prior of {:.1} % (f0) and {:.0} % (Q), K kept",
                            100.0 * super::search::F0_TOLERANCE,
                            100.0 * super::search::Q_TOLERANCE
                        )
                    } else {
                        "the header's f0 and Q as given: the sampling aliases the resonance, \
                         so a correction would only shift the sampled phase of the lever's \
                         ringing (a lag of the response, which a drag also makes)"
                            .into()
                    },
                    f0_correction: nom.f0_scale.into(),
                    q_correction: nom.q_scale.into(),
                    f0_hz: cal.f0_mhz().map_or(f64::NAN, |f| f / TIME).into(),
                    q: cal
                        .m
                        .map_or(f64::NAN, |m| (cal.k * m).sqrt() / cal.c.max(1e-300))
                        .into(),
                }),
            )
        } else {
            (None, None)
        };
        jr::DiagnoseReport {
            schema_version: jr::SCHEMA_VERSION,
            recording: recording.into(),
            nominal_model: NOMINAL_MODEL.into(),
            rms_before_m: self.rms_before_m.into(),
            rms_after_m: self.rms_after_m.into(),
            contact_misfit: self.contact_misfit.into(),
            misfit_over_noise: self.misfit_over_noise.into(),
            verdict: self.verdict(),
            left_out,
            visco_version: env!("CARGO_PKG_VERSION").into(),
            mode: rec.meta.mode.as_str().into(),
            nominal: jr::Nominal {
                model: "M·Z̈ = K·(U − Z) + C·(U̇ − Ż) + F_ts, D = U − Z + d0, \
                        F_ts = k_a·V(δ) − c_a·A(δ)·Ż (sphere on the element bed: V, A of \
                        its continuum limit or of a lattice of elements, see `bed`)"
                    .into(),
                dynamics: p.dynamics_source.clone(),
                input_between_samples: if !p.inst.dynamic()
                    && s.nominal.nominal.input == Input::Held
                {
                    "not used (quasi-static)"
                } else {
                    s.nominal.nominal.input.describe()
                }
                .into(),
                bed: format!("{}: {}", s.nominal.nominal.bed.describe(), s.bed_reason),
                initial_state,
                calibration,
                offset_m: (s.nominal.nominal.offset * LENGTH).into(),
                baseline_wave: p
                    .baseline_wave
                    .as_ref()
                    .and_then(crate::identify::report::BaselineWave::of),
                contacts,
                noise: jr::NoiseJson {
                    model: "autoregressive, Burg, order by BIC".into(),
                    order: nn.a.len() as u64,
                    innovation_sigma_m: (nn.sigma * LENGTH).into(),
                    residual_sigma_m: (nn.raw_sigma * LENGTH).into(),
                },
            },
            held_out: jr::HeldOutJson {
                scheme: "interleaved blocks: every other block fits, the rest is held out".into(),
                samples_per_block: BLOCK as u64,
                held_out_samples: p.held.iter().filter(|h| **h).count() as u64,
                fit_samples: p.fit.iter().filter(|h| **h).count() as u64,
            },
            selection: jr::Selection {
                method: format!(
                    "forward selection: each candidate screened by its linearised fit, the \
                     {SCREEN_POLISHED} best (and adhesion beside surface attraction) fitted \
                     on the fit samples, the others only where a brief fit already beats the \
                     worst of those; each fitted one tested on the held-out samples \
                     (whitened likelihood ratio, one-sided z); the significant one with the \
                     largest held-out likelihood gain joins the model"
                ),
                family_alpha: self.alpha,
                correction: "Bonferroni over the candidates of each stage".into(),
                detection_floor: format!(
                    "an effect must also change D by {DETECTION_FLOOR}× the noise RMS somewhere"
                ),
                simulations: s.simulations as u64,
                stages,
            },
            locate: jr::LocateJson {
                correction: format!("Holm, family-wise α = {}", self.alpha),
                tones_hz: nums(self.located.tones_hz.iter().copied()),
                phases: self
                    .located
                    .phases
                    .iter()
                    .map(|m| jr::PhaseSamples {
                        phase: m.phase.as_str().into(),
                        held_out_samples: m.samples as u64,
                        rms_before_m: m.rms_before_m.into(),
                        rms_after_m: m.rms_after_m.into(),
                    })
                    .collect(),
                tests: self.located.tests.iter().map(|t| t.to_json()).collect(),
            },
            hold: self.hold.as_ref().map(|h| jr::HoldJson {
                rows: [h.rows.0 as u64 + 1, h.rows.1 as u64],
                kind: h.kind.into(),
                base_towards_sample_m: h.base_towards_sample_m.into(),
                force_change_n: h.force_change_n.into(),
                reading: h.reading.clone(),
            }),
            units: jr::Units::default(),
            series_csv: None,
            figures: None,
        }
    }

    /// The outcome in words. "Explains the recording to within its noise" only where the
    /// held-out RMS is within 1.5× the noise ([`Diagnosis::misfit_over_noise`]; a clean tap
    /// whose lattice the nominal fit missed, 2.7× the noise at the touch, used to read as
    /// explained); above, it says whether the misfit sits where the tip touches
    /// ([`Diagnosis::contact_misfit`]) or everywhere.
    pub fn verdict(&self) -> String {
        use super::search::WITHIN_NOISE;
        let (touch, noise) = (self.contact_misfit, self.misfit_over_noise);
        let left = if self.findings.is_empty() {
            "no effect of the vocabulary passes the held-out test".to_string()
        } else {
            let names: Vec<&str> = self.findings.iter().map(|f| f.kind.as_str()).collect();
            format!("left out: {}", names.join(", "))
        };
        if noise <= WITHIN_NOISE {
            if self.findings.is_empty() {
                "the nominal model explains the recording to within its noise".into()
            } else {
                format!("{left}; the extended model explains it to within its noise")
            }
        } else if touch.is_nan() {
            format!(
                "{left}; yet the held-out RMS is {noise:.2}× the noise: a misfit remains (too few \
                 samples far out of contact to say whether it sits where the tip touches)"
            )
        } else if touch > WITHIN_NOISE {
            format!(
                "{left}; yet the held-out RMS is {touch:.2}× its RMS far out of contact: a misfit \
                 remains where the tip touches (physics outside the vocabulary, or a nominal fit \
                 that missed)"
            )
        } else {
            format!(
                "{left}; yet the held-out RMS is {noise:.2}× the noise, as much out of contact \
                 as in it: a misfit everywhere (see the located misfit and the spectrum)"
            )
        }
    }

    /// One line per finding, for the terminal.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "held-out RMS misfit {:.4e} m nominal, {:.4e} m with {} effect(s)",
            self.rms_before_m,
            self.rms_after_m,
            self.findings.len()
        );
        s.push_str(": ");
        s.push_str(&self.verdict());
        for (i, f) in self.findings.iter().enumerate() {
            s.push_str(&format!(
                "\n  {}. {} (z = {:.1}, p = {:.2e}): {}",
                i + 1,
                f.kind,
                f.evidence.z,
                f.evidence.p_value,
                f.explanation
            ));
        }
        s
    }

    /// Every sample: recorded, nominal and final D, residuals, phase, held out.
    pub fn series_csv(&self) -> String {
        let p = &self.problem;
        let mut s = String::from(
            "# visco diagnose: recorded and simulated deflection per sample\n\
             t_s,u_m,d_recorded_m,d_nominal_m,d_extended_m,residual_before_m,\
             residual_after_m,phase,held_out\n",
        );
        for i in 0..p.data.len() {
            let d = p.recorded_nm(i) * LENGTH;
            for v in [
                p.data.t[i] * TIME,
                p.data.u[i] * LENGTH,
                d,
                self.nominal_d_m[i],
                self.final_d_m[i],
                d - self.nominal_d_m[i],
                d - self.final_d_m[i],
            ] {
                push_num(&mut s, v);
                s.push(',');
            }
            s.push_str(self.phase[i].as_str());
            s.push(',');
            s.push_str(if p.held[i] { "1" } else { "0" });
            s.push('\n');
        }
        s
    }
}

/// Reads, analyses and writes (module docs). All outputs or none.
pub fn diagnose(path: &Path, opts: &Options) -> Result<Diagnosis> {
    if !(opts.alpha > 0.0 && opts.alpha < 1.0) {
        return Err(IdentifyError::new(&opts.json, "--alpha must be in (0, 1)"));
    }
    let (dir, stem) =
        crate::identify::files::plan_outputs(&opts.json, opts.out_dir.as_deref(), path)?;
    let rec = Recording::read(path)?;
    let mut progress = |s: &str| {
        if opts.progress {
            eprintln!("diagnose: {s}");
        }
    };
    let diag =
        analyse(&rec, &opts.search(), &mut progress).map_err(|e| IdentifyError::new(path, e))?;
    let created = crate::identify::files::create_missing_dir(&dir)?;
    let result = write(&diag, path, &rec, opts, &dir, &stem);
    if result.is_err() && created {
        let _ = std::fs::remove_dir(&dir);
    }
    result.map(|_| diag)
}

fn write(
    diag: &Diagnosis,
    path: &Path,
    rec: &Recording,
    opts: &Options,
    dir: &Path,
    stem: &str,
) -> Result<Vec<PathBuf>> {
    let mut staged = Staged::new();
    let out = |suffix: &str| dir.join(format!("{stem}_{suffix}"));
    let series = out("series.csv");
    staged.write(&series, &diag.series_csv())?;
    let mut figures: Vec<PathBuf> = Vec::new();
    if opts.figures {
        let name = path
            .file_name()
            .map_or(String::new(), |n| n.to_string_lossy().into_owned());
        let f = out("overview.png");
        let plot = overview_plot(diag, &name);
        staged.render(&f, |tmp| figure::lines(tmp, &plot))?;
        figures.push(f);
        for (i, finding) in diag.findings.iter().enumerate() {
            let f = out(&format!("effect{}_{}.png", i + 1, finding.kind));
            let plot = effect_plot(diag, i, &name);
            staged.render(&f, |tmp| figure::lines(tmp, &plot))?;
            figures.push(f);
        }
        if diag.located.spectrum_before.f_hz.len() > 4 {
            let f = out("spectrum.png");
            let plot = spectrum_plot(diag, &name);
            staged.render(&f, |tmp| figure::lines(tmp, &plot))?;
            figures.push(f);
        }
    }
    let mut json = diag.to_json(&path.display().to_string(), rec);
    json.series_csv = Some(series.display().to_string());
    json.figures = Some(figures.iter().map(|f| f.display().to_string()).collect());
    staged.write(&opts.json, &crate::report::to_pretty(&json))?;
    staged.commit()
}

/// At most this many points per series in a figure (min and max per bucket beyond it).
const FIGURE_POINTS: usize = 4000;

/// (t, y) points of rows `a..b`, as bucket minima and maxima when there are too many.
fn points(t: &[f64], y: &[f64], a: usize, b: usize) -> Vec<(f64, f64)> {
    let n = b - a;
    if n <= FIGURE_POINTS {
        return (a..b).map(|i| (t[i], y[i])).collect();
    }
    let per = n.div_ceil(FIGURE_POINTS / 2);
    let mut out = Vec::with_capacity(FIGURE_POINTS + 2);
    let mut i = a;
    while i < b {
        let j = (i + per).min(b);
        let (mut lo, mut hi) = (i, i);
        for k in i..j {
            if y[k] < y[lo] {
                lo = k;
            }
            if y[k] > y[hi] {
                hi = k;
            }
        }
        let (first, second) = if lo < hi { (lo, hi) } else { (hi, lo) };
        out.push((t[first], y[first]));
        out.push((t[second], y[second]));
        i = j;
    }
    out
}

fn overview_plot(diag: &Diagnosis, name: &str) -> LinePlot {
    let p = &diag.problem;
    let t: Vec<f64> = p.data.t.iter().map(|x| x * TIME).collect();
    let d: Vec<f64> = (0..p.data.len())
        .map(|i| p.recorded_nm(i) * LENGTH)
        .collect();
    let n = t.len();
    let rb: Vec<f64> = d
        .iter()
        .zip(&diag.nominal_d_m)
        .map(|(a, b)| a - b)
        .collect();
    let ra: Vec<f64> = d.iter().zip(&diag.final_d_m).map(|(a, b)| a - b).collect();
    let found: Vec<&str> = diag.findings.iter().map(|f| f.kind.as_str()).collect();
    LinePlot {
        title: Some(plain(&format!(
            "{name}: {}",
            if found.is_empty() && diag.misfit_over_noise <= super::search::WITHIN_NOISE {
                "nothing left out (the nominal model explains it to within its noise)".to_string()
            } else if found.is_empty() {
                "no effect named (see the report's verdict)".to_string()
            } else {
                format!("left out: {}", found.join(", "))
            }
        ))),
        x: Quantity::new("t", "s"),
        panels: vec![
            LinePanel {
                y: Quantity::new("D", "m"),
                series: vec![
                    Series::line("recorded", points(&t, &d, 0, n)).with_color(PALETTE[0]),
                    Series::dashed("nominal", points(&t, &diag.nominal_d_m, 0, n))
                        .with_color(PALETTE[1]),
                    Series::dashed("extended", points(&t, &diag.final_d_m, 0, n))
                        .with_color(PALETTE[2]),
                ],
                ..Default::default()
            },
            LinePanel {
                y: Quantity::new("recorded − model", "m"),
                series: vec![
                    Series::line("nominal", points(&t, &rb, 0, n)).with_color(PALETTE[1]),
                    Series::line("extended", points(&t, &ra, 0, n)).with_color(PALETTE[2]),
                ],
                ..Default::default()
            },
        ],
        ..Default::default()
    }
}

fn effect_plot(diag: &Diagnosis, k: usize, name: &str) -> LinePlot {
    let p = &diag.problem;
    let f = &diag.findings[k];
    let n = p.data.len();
    // The largest span, with a margin of its own length on each side.
    let (a, b) = f
        .spans
        .iter()
        .max_by(|x, y| x.share.total_cmp(&y.share))
        .map(|s| {
            let len = (s.rows.1 - s.rows.0).max(20);
            (s.rows.0.saturating_sub(len), (s.rows.1 + len).min(n))
        })
        .unwrap_or((0, n));
    let t: Vec<f64> = p.data.t.iter().map(|x| x * TIME).collect();
    let d: Vec<f64> = (0..p.data.len())
        .map(|i| p.recorded_nm(i) * LENGTH)
        .collect();
    let before = &diag.stages_d_m[k];
    let after = &diag.stages_d_m[k + 1];
    let rb: Vec<f64> = d.iter().zip(before).map(|(x, y)| x - y).collect();
    let ra: Vec<f64> = d.iter().zip(after).map(|(x, y)| x - y).collect();
    let label_b = if k == 0 {
        "nominal".to_string()
    } else {
        format!(
            "with {}",
            diag.findings[..k]
                .iter()
                .map(|f| f.kind.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    LinePlot {
        title: Some(plain(&format!(
            "{name}: {}, RMS {} → {} where it acts",
            f.kind,
            super::explain::length(f.rms_before_m),
            super::explain::length(f.rms_after_m)
        ))),
        x: Quantity::new("t", "s"),
        panels: vec![
            LinePanel {
                y: Quantity::new("D", "m"),
                series: vec![
                    Series::line("recorded", points(&t, &d, a, b)).with_color(PALETTE[0]),
                    Series::dashed(label_b.clone(), points(&t, before, a, b))
                        .with_color(PALETTE[1]),
                    Series::dashed(format!("+ {}", f.kind), points(&t, after, a, b))
                        .with_color(PALETTE[2]),
                ],
                ..Default::default()
            },
            LinePanel {
                y: Quantity::new("recorded − model", "m"),
                series: vec![
                    Series::line(format!("before ({label_b})"), points(&t, &rb, a, b))
                        .with_color(PALETTE[1]),
                    Series::line(format!("after (+ {})", f.kind), points(&t, &ra, a, b))
                        .with_color(PALETTE[2]),
                ],
                ..Default::default()
            },
        ],
        ..Default::default()
    }
}

fn spectrum_plot(diag: &Diagnosis, name: &str) -> LinePlot {
    let sb = &diag.located.spectrum_before;
    let sa = &diag.located.spectrum_after;
    let l2 = LENGTH * LENGTH;
    let pts = |s: &super::spectrum::Spectrum| -> Vec<(f64, f64)> {
        s.f_hz
            .iter()
            .zip(&s.psd)
            .skip(1)
            .map(|(f, p)| (*f, p * l2))
            .collect()
    };
    let mut series = vec![
        Series::line("residual, nominal", pts(sb)).with_color(PALETTE[1]),
        Series::line("residual, extended", pts(sa)).with_color(PALETTE[2]),
    ];
    let lines: Vec<(f64, f64)> = diag
        .located
        .tests
        .iter()
        .filter(|t| t.group == "frequency" && t.significant)
        .filter_map(|t| {
            let f = t.freq_hz?;
            let k = sb.bin(f)?;
            Some((f, sb.psd[k] * l2))
        })
        .collect();
    if !lines.is_empty() {
        series.push(Series::markers("significant lines (locate)", lines).with_color(PALETTE[3]));
    }
    LinePlot {
        title: Some(plain(&format!("{name}: residual spectrum (Welch)"))),
        x: Quantity::new("f", "Hz"),
        x_log: true,
        panels: vec![LinePanel {
            y: Quantity::new("PSD", "m²/Hz"),
            series,
            y_log: true,
            ..Default::default()
        }],
        ..Default::default()
    }
}
