//! Each effect found, said in words with its numbers: what acts, how strongly, where.

use super::candidates::Env;
use super::locate::{Phase, Span};
use crate::plant::effects::EffectKind;

/// `v` in the first of `units` (scale, symbol) whose scale it reaches, else the last.
fn scaled(v: f64, units: &[(f64, &str)]) -> String {
    let (scale, symbol) = units
        .iter()
        .find(|(s, _)| v.abs() >= *s)
        .unwrap_or(&units[units.len() - 1]);
    format!("{:.3} {symbol}", v / scale)
}

/// A force with a unit that suits it.
pub fn force(f_n: f64) -> String {
    scaled(f_n, &[(1e-6, "µN"), (1e-9, "nN"), (1e-12, "pN")])
}

/// A length with a unit that suits it.
pub fn length(x_m: f64) -> String {
    scaled(x_m, &[(1e-6, "µm"), (1e-9, "nm"), (1e-12, "pm")])
}

/// A time with a unit that suits it.
pub fn time(t_s: f64) -> String {
    scaled(t_s, &[(1.0, "s"), (1e-3, "ms"), (1e-6, "µs")])
}

/// A frequency with a unit that suits it.
pub fn frequency(f_hz: f64) -> String {
    scaled(f_hz, &[(1e6, "MHz"), (1e3, "kHz"), (1.0, "Hz")])
}

/// Where, in a few words: the phases of the spans and the first one's time.
fn where_words(spans: &[Span]) -> String {
    if spans.is_empty() {
        return String::new();
    }
    let mut phases: Vec<Phase> = Vec::new();
    for s in spans {
        if !phases.contains(&s.phase) {
            phases.push(s.phase);
        }
    }
    let names: Vec<&str> = phases.iter().map(|p| p.as_str()).collect();
    format!(
        "; the misfit it explains sits in the {} (from t = {:.6} s)",
        names.join(", "),
        spans[0].t_start_s
    )
}

/// The sentence for effect `kind` with parameter values `v` (as in
/// [`super::candidates::Candidate::params`], SI); `peak_m` is its largest contribution to D.
pub fn explain(kind: EffectKind, v: &[f64], env: &Env, spans: &[Span], peak_m: f64) -> String {
    let w = where_words(spans);
    let size = format!("it changes D by up to {}", length(peak_m));
    match kind {
        EffectKind::NonlinearStiffness => {
            let q = v[0];
            let p = 2.0 + q;
            let law = if (p - 1.5).abs() < 0.2 {
                " — close to Hertz's δ^1.5 for a continuum"
            } else if q > 0.0 {
                " — stiffening with depth"
            } else {
                " — softer growth than the bed"
            };
            format!(
                "the contact force does not grow with depth as the element bed predicts: \
                 shallow, it grows as δ^{p:.2} where the bed gives δ^2{law} (the force at \
                 {} deep is unchanged, {:.0} % different at half that depth; nonlinear \
                 stiffness); {size}{w}",
                length(env.depth_max_m),
                (0.5f64.powf(q) - 1.0) * 100.0
            )
        }
        EffectKind::Adhesion => format!(
            "an attractive force of {} acts {} until the tip is {} out of the sample on \
             retract, then lets go (adhesion; pull-off jump of up to {} in D); {size}{w}",
            force(v[0]),
            if v[2] > 0.5 {
                "once the contact unloads (bonds or tethers resisting separation)"
            } else {
                "from the first touch"
            },
            length(v[1]),
            length(v[0] / env.k_n_per_m),
        ),
        EffectKind::SurfaceAttraction => format!(
            "an attractive force pulls the tip before it touches: {} at contact, decaying \
             over {} of separation ({} at {} above the surface; surface attraction, e.g. an \
             electrostatic double layer or van der Waals forces); {size}{w}",
            force(v[0]),
            length(v[1]),
            force(v[0] * (-2.0f64).exp()),
            length(2.0 * v[1]),
        ),
        EffectKind::StressRelaxation => format!(
            "the force relaxes at constant depth with time constant τ = {}, which a \
             Kelvin–Voigt element cannot do: a Maxwell arm {:.3}× as stiff as the bed \
             (standard linear solid), so a sudden indentation first meets {:.1} % more force, \
             of which {:.1} % of the total decays (stress relaxation); {size}{w}",
            time(v[1]),
            v[0],
            v[0] * 100.0,
            v[0] / (1.0 + v[0]) * 100.0,
        ),
        EffectKind::HydrodynamicDrag => {
            let f_at = v[0] * env.speed_m_per_s;
            format!(
                "a velocity-proportional drag of {:.3e} N·s/m acts on the cantilever in and \
                 out of contact ({:.0} % on the base's velocity, the rest on the tip's): at \
                 {} per s it is {}, and approach and retract baselines part by {} \
                 (hydrodynamic drag of the liquid); {size}{w}",
                v[0],
                v[1] * 100.0,
                length(env.speed_m_per_s),
                force(f_at),
                length(2.0 * f_at / env.k_n_per_m),
            )
        }
        EffectKind::BaselineTilt => format!(
            "the out-of-contact deflection changes linearly with the piezo position: {} of D \
             per µm of U, {} over the {} the piezo travels (baseline tilt: interference or a \
             tilting mount); {size}{w}",
            length(v[0] * 1e-6),
            length(v[0] * env.u_span_m),
            length(env.u_span_m),
        ),
        EffectKind::ThermalDrift => format!(
            "the deflection offset drifts by {} per s, {} over the {} recording (thermal \
             drift of the lever or the detector); {size}{w}",
            length(v[0]),
            length(v[0] * env.duration_s),
            time(env.duration_s),
        ),
        EffectKind::SecondEigenmode => format!(
            "the cantilever's second flexural mode rings at {} ({:.2} × f0), Q2 = {:.0}, \
             decaying over {}: rung by the base's motion (gain {:.3} on its acceleration, \
             {:.3} on its velocity) and by the tip force (gain {:.3} on its changes, {:.3} \
             on the force itself) (second eigenmode); {size}{w}",
            frequency(v[2]),
            env.f0_hz.map_or(f64::NAN, |f0| v[2] / f0),
            v[3],
            time(v[3] / (std::f64::consts::PI * v[2])),
            v[1],
            v[4],
            v[0],
            v[5],
        ),
        EffectKind::PiezoCreep => format!(
            "the piezo creeps: {:.2} % of every move arrives late, with time constant {}, so \
             the base keeps moving after the command stops (piezo creep); {size}{w}",
            v[0] * 100.0,
            time(v[1]),
        ),
        EffectKind::PlasticDeformation => format!(
            "the sample does not come back: {:.2} % of the deepest indentation stays, so the \
             surface sank by {} and unloading leaves the contact earlier than loading \
             entered it (plastic deformation); {size}{w}",
            v[0] * 100.0,
            length(v[0] / (1.0 - v[0]).max(0.05) * env.depth_max_m),
        ),
    }
}
