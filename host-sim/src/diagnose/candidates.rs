//! Each effect of the vocabulary as a candidate extension of the model: its parameters, their
//! bounds, where the search starts, and how they make the plant's [`EffectSpec`].
//!
//! A candidate's parameters are of two kinds:
//!
//! * **amplitudes** — zero is the nominal model (a force, a stiffness ratio, a tilt, a gain);
//!   to first order the simulated D is linear in them, so their best values at a given shape
//!   come from one simulation each ("sensitivity") and a linear least-squares solve, jointly
//!   with the nominal parameters' corrections;
//! * **shapes** — they enter nonlinearly (a relaxation time, a decay length, an exponent, a
//!   frequency): searched over a grid spanning the physically plausible range for this
//!   recording (sampling interval to its duration, nm to the tip radius), refined by golden
//!   section where smooth, then polished with everything else by Levenberg–Marquardt.
//!
//! Scales come from the recording ([`Env`]): the noise, the forces, the travel, the duration.

use super::fit::Param;
use crate::plant::effects::{EffectKind, EffectSpec};

/// What the candidates need to know of the recording and the nominal fit (SI).
#[derive(Clone, Debug, PartialEq)]
pub struct Env {
    /// First sample time and duration (s).
    pub t0_s: f64,
    pub duration_s: f64,
    /// Median sampling interval (s).
    pub dt_s: f64,
    /// U at the first sample and its range (m).
    pub u_ref_m: f64,
    pub u_span_m: f64,
    /// Deepest apex depth of the nominal fit (m).
    pub depth_max_m: f64,
    /// Largest contact force of the nominal fit (N).
    pub force_max_n: f64,
    /// Cantilever K (N/m).
    pub k_n_per_m: f64,
    /// First-mode resonance (Hz), when the recording is dynamic.
    pub f0_hz: Option<f64>,
    /// Sampling rate (Hz).
    pub fs_hz: f64,
    /// Noise of D (m).
    pub noise_m: f64,
    /// Tip radius (m).
    pub r_tip_m: f64,
    /// Typical slow speed of the base (m/s).
    pub speed_m_per_s: f64,
    /// Relaxation times already in the model (s): a further arm is searched a decade away.
    pub relaxation_times_s: Vec<f64>,
    /// Peaks of the nominal residual's spectrum between 4 and 9 f₀ (Hz), strongest first.
    pub mode2_peaks_hz: Vec<f64>,
}

/// One parameter of a candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct EffectParam {
    /// Bounds, scale, the value (the null value for an amplitude).
    pub param: Param,
    /// A shape (grid-searched) rather than an amplitude.
    pub shape: bool,
    /// For a shape: whether the fit is smooth in it (refined and polished); a shape that
    /// moves an event between samples (a reach, a choice) stays at its grid value.
    pub smooth: bool,
    /// For a shape: the grid. For an amplitude: the probe value of its sensitivity.
    pub grid: Vec<f64>,
    /// For an amplitude: only values ≥ the null value are physical.
    pub nonneg: bool,
}

impl EffectParam {
    fn amplitude(param: Param, probe: f64, nonneg: bool) -> Self {
        EffectParam {
            param,
            shape: false,
            smooth: true,
            grid: vec![probe],
            nonneg,
        }
    }
    fn shape(param: Param, grid: Vec<f64>, smooth: bool) -> Self {
        EffectParam {
            param,
            shape: true,
            smooth,
            grid,
            nonneg: false,
        }
    }
}

/// A candidate extension: one effect with its parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    pub kind: EffectKind,
    pub params: Vec<EffectParam>,
}

/// Largest creep fraction: piezos creep by a few per cent of a move, rarely a fifth (a
/// closed-loop z sensor removes it altogether); beyond this the "creep" would be a stand-in
/// for other physics.
pub const PIEZO_CREEP_MAX: f64 = 0.25;

/// Largest |gain| of a second mode in the reading.
const GAIN_MAX: f64 = 3.0;

/// `n` points spaced logarithmically from `a` to `b`.
pub fn log_grid(a: f64, b: f64, n: usize) -> Vec<f64> {
    if n <= 1 || !(b > a) {
        return vec![a];
    }
    (0..n)
        .map(|i| a * (b / a).powf(i as f64 / (n - 1) as f64))
        .collect()
}

impl Candidate {
    /// The candidate for `kind` on this recording; `None` when the recording cannot show it
    /// (the second eigenmode needs a dynamic recording sampled above its frequency).
    pub fn new(kind: EffectKind, env: &Env) -> Option<Candidate> {
        let force_probe = (3.0 * env.k_n_per_m * env.noise_m).max(1e-15);
        let t_lo = (5.0 * env.dt_s).max(1e-7);
        let t_hi = (2.0 * env.duration_s).max(2.0 * t_lo);
        let len_hi = env.r_tip_m.max(env.depth_max_m).max(1e-9);
        let len_lo = (0.3e-9f64).min(len_hi / 10.0);
        let params = match kind {
            EffectKind::NonlinearStiffness => vec![EffectParam::amplitude(
                Param::linear("exponent_change", 0.0, -1.2, 3.0, 0.2),
                0.1,
                false,
            )],
            EffectKind::Adhesion => vec![
                EffectParam::amplitude(
                    Param::linear("pull_off_force_n", 0.0, 0.0, 1e-3, force_probe),
                    force_probe,
                    true,
                ),
                EffectParam::shape(
                    Param::linear("reach_m", 0.0, 0.0, 10.0 * len_hi, len_hi),
                    {
                        let mut g = vec![0.0];
                        g.extend(log_grid(len_lo, len_hi, 11));
                        g
                    },
                    false,
                ),
                // From the touch (0) or only once the contact unloads (1).
                EffectParam::shape(
                    Param::linear("on_unloading_only", 0.0, 0.0, 1.0, 1.0),
                    vec![0.0, 1.0],
                    false,
                ),
            ],
            EffectKind::SurfaceAttraction => vec![
                EffectParam::amplitude(
                    Param::linear("force_at_contact_n", 0.0, 0.0, 1e-3, force_probe),
                    force_probe,
                    true,
                ),
                EffectParam::shape(
                    Param::logarithmic("decay_length_m", len_hi / 10.0, len_lo / 3.0, 3.0 * len_hi),
                    log_grid(len_lo, len_hi, 10),
                    true,
                ),
            ],
            EffectKind::StressRelaxation => vec![
                EffectParam::amplitude(
                    Param::linear("arm1_stiffness_ratio", 0.0, 0.0, 1e3, 0.1),
                    0.1,
                    true,
                ),
                EffectParam::shape(
                    Param::logarithmic(
                        "arm1_relaxation_time_s",
                        t_lo * 10.0,
                        t_lo / 2.0,
                        5.0 * t_hi,
                    ),
                    {
                        // A further arm: a decade or more from those already fitted (two arms
                        // that far apart approximate power-law rheology).
                        let g: Vec<f64> = log_grid(t_lo, t_hi, 12)
                            .into_iter()
                            .filter(|t| {
                                env.relaxation_times_s
                                    .iter()
                                    .all(|t1| (t / t1).ln().abs() > 10f64.ln())
                            })
                            .collect();
                        if g.is_empty() {
                            return None;
                        }
                        g
                    },
                    true,
                ),
            ],
            EffectKind::HydrodynamicDrag => {
                let v = env.speed_m_per_s.max(1e-12);
                let probe = (force_probe / v).max(1e-15);
                let mut ps = vec![
                    EffectParam::amplitude(
                        Param::linear("drag_ns_per_m", 0.0, 0.0, 1.0, probe),
                        probe,
                        true,
                    ),
                    EffectParam::shape(
                        Param::linear("base_velocity_fraction", 0.0, 0.0, 1.0, 1.0),
                        vec![0.0, 0.5, 1.0],
                        false,
                    ),
                ];
                // For a dynamic recording the drag also damps the resonance: a probe of a
                // tenth of the cantilever's damping shows it.
                if let Some(f0) = env.f0_hz {
                    let c_probe = env.k_n_per_m / (2.0 * std::f64::consts::PI * f0) * 0.01;
                    ps[0].grid[0] = ps[0].grid[0].min(c_probe.max(1e-15));
                    ps[0].param.scale = ps[0].grid[0];
                }
                ps
            }
            EffectKind::BaselineTilt => {
                let probe = 3.0 * env.noise_m / env.u_span_m.max(1e-12);
                vec![EffectParam::amplitude(
                    Param::linear("tilt_m_per_m", 0.0, -1.0, 1.0, probe),
                    probe,
                    false,
                )]
            }
            EffectKind::ThermalDrift => {
                let probe = 3.0 * env.noise_m / env.duration_s.max(1e-9);
                vec![EffectParam::amplitude(
                    Param::linear("rate_m_per_s", 0.0, -1.0, 1.0, probe),
                    probe,
                    false,
                )]
            }
            EffectKind::SecondEigenmode => {
                let f0 = env.f0_hz?;
                let nyquist = 0.5 * env.fs_hz;
                let f_hi = (10.0 * f0).min(0.95 * nyquist);
                if 4.0 * f0 >= f_hi {
                    return None;
                }
                // Lines the residual shows, else a grid over where a second mode sits
                // (6.27 f₀ for a uniform beam; tips, coatings and tapering move it).
                // Each line ± one bin of the spectrum it was found in (1024 samples).
                let bin = env.fs_hz / 1024.0;
                let mut f_grid: Vec<f64> = env
                    .mode2_peaks_hz
                    .iter()
                    .copied()
                    .filter(|f| *f < f_hi && *f > 3.5 * f0)
                    .take(3)
                    .flat_map(|f| [f - bin, f, f + bin])
                    .collect();
                if f_grid.is_empty() {
                    f_grid = log_grid(4.5 * f0, (8.5 * f0).min(f_hi), 24);
                }
                f_grid.sort_by(f64::total_cmp);
                vec![
                    // Optical-lever gains of a second mode stay below one (0.3 for an ideal
                    // beam); ±3 leaves room for a strongly coupled mode, not for a mode
                    // standing in for something else.
                    EffectParam::amplitude(
                        Param::linear("force_gain", 0.0, -GAIN_MAX, GAIN_MAX, 0.05),
                        0.05,
                        false,
                    ),
                    EffectParam::amplitude(
                        Param::linear("base_gain", 0.0, -GAIN_MAX, GAIN_MAX, 0.05),
                        0.05,
                        false,
                    ),
                    EffectParam::shape(
                        Param::logarithmic("f2_hz", 6.27 * f0, 3.5 * f0, f_hi),
                        f_grid,
                        true,
                    ),
                    EffectParam::shape(
                        // A resolved resonance: below Q₂ ≈ 2 a base-driven "mode" is a
                        // velocity filter and would stand in for a drag.
                        Param::logarithmic("q2", 30.0, 2.0, 3000.0),
                        log_grid(2.5, 600.0, 6),
                        true,
                    ),
                    // The base's velocity route (a medium damping the mode's absolute
                    // velocity): with the acceleration route it sets the phase of the mode's
                    // response to the base, which no header gives.
                    EffectParam::amplitude(
                        Param::linear("base_velocity_gain", 0.0, -GAIN_MAX, GAIN_MAX, 0.05),
                        0.05,
                        false,
                    ),
                    // The tip force's static part, when the header's K (a thermal tune of
                    // the first mode) leaves the mode's static compliance out.
                    EffectParam::amplitude(
                        Param::linear("force_static_gain", 0.0, -GAIN_MAX, GAIN_MAX, 0.05),
                        0.05,
                        false,
                    ),
                ]
            }
            EffectKind::PiezoCreep => vec![
                EffectParam::amplitude(
                    Param::linear("creep_fraction", 0.0, 0.0, PIEZO_CREEP_MAX, 0.02),
                    0.02,
                    true,
                ),
                EffectParam::shape(
                    Param::logarithmic("tau_s", t_lo * 10.0, t_lo / 2.0, 5.0 * t_hi),
                    log_grid(t_lo, t_hi, 10),
                    true,
                ),
            ],
            EffectKind::PlasticDeformation => vec![EffectParam::amplitude(
                Param::linear("plastic_fraction", 0.0, 0.0, 0.9, 0.02),
                0.02,
                true,
            )],
        };
        Some(Candidate { kind, params })
    }

    /// The effect for parameter values `v` (one per [`Candidate::params`], SI).
    pub fn spec(&self, v: &[f64], env: &Env) -> EffectSpec {
        match self.kind {
            EffectKind::NonlinearStiffness => EffectSpec::NonlinearStiffness {
                exponent_change: v[0],
                reference_depth_m: env.depth_max_m.max(1e-10),
            },
            EffectKind::Adhesion => EffectSpec::Adhesion {
                force_n: v[0],
                reach_m: v[1],
                unloading_only: v[2] > 0.5,
            },
            EffectKind::SurfaceAttraction => EffectSpec::SurfaceAttraction {
                force_n: v[0],
                decay_length_m: v[1],
            },
            EffectKind::StressRelaxation => EffectSpec::StressRelaxation {
                arms: vec![(v[0], v[1])],
            },
            EffectKind::HydrodynamicDrag => EffectSpec::HydrodynamicDrag {
                drag_ns_per_m: v[0],
                base_fraction: v[1],
            },
            EffectKind::BaselineTilt => EffectSpec::BaselineTilt {
                tilt: v[0],
                u_ref_m: env.u_ref_m,
            },
            EffectKind::ThermalDrift => EffectSpec::ThermalDrift {
                rate_m_per_s: v[0],
                t_ref_s: env.t0_s,
            },
            EffectKind::SecondEigenmode => EffectSpec::SecondEigenmode {
                f_hz: v[2],
                q: v[3],
                gain: v[0],
                base_gain: v[1],
                velocity_gain: v[4],
                static_gain: v[5],
                k_n_per_m: env.k_n_per_m,
            },
            EffectKind::PiezoCreep => EffectSpec::PiezoCreep {
                fraction: v[0],
                tau_s: v[1],
            },
            EffectKind::PlasticDeformation => EffectSpec::PlasticDeformation { fraction: v[0] },
        }
    }

    /// The indices of its amplitudes and of its shape parameters, in order.
    pub fn amplitudes_and_shapes(&self) -> (Vec<usize>, Vec<usize>) {
        (0..self.params.len()).partition(|&j| !self.params[j].shape)
    }

    /// The null values: the candidate at the nominal model (amplitudes zero, shapes at their
    /// first grid point).
    pub fn null_values(&self) -> Vec<f64> {
        self.params
            .iter()
            .map(|p| if p.shape { p.grid[0] } else { p.param.value })
            .collect()
    }
}
