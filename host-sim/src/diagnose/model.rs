//! The model `diagnose` fits: the cantilever's first mode and a spherical tip on a Kelvin–Voigt
//! element bed, driven by the recorded U, plus any of the plant's effects
//! ([`crate::plant::effects`]) through the same hooks, in the same order, as the plant.
//!
//! ## The nominal model
//! `M·Z̈ = K·(U − Z) + C·(U̇ − Ż) + F_ts`, D = U − Z (`method.md` (1), (2)), with the bed in
//! its continuum limit: a sphere of radius R pressed δ = h − Z into a bed of per-area spring
//! k_a and damper c_a feels
//!
//! ```text
//! F_ts = k_a·V(δ) − c_a·A(δ)·Ż      (δ > 0; 0 otherwise)
//! ```
//!
//! with V the cap volume below the surface and A = πa² = dV/dδ the contact area
//! ([`crate::identify::signal::cap_volume`]): the sum of the paper's elements (5)–(8) for a
//! pitch small next to the contact radius. The detector adds an offset d₀. Parameters: d₀, and
//! per unit (a tap, a curve) the contact height h, k_a and c_a; for dynamic recordings also
//! the initial state, the header cantilever's calibration corrections and the input between
//! samples (below).
//!
//! ## Dynamic and quasi-static recordings
//! * **Dynamic** (the recording gives M and C, or f₀ and Q, and samples at ≥ 4 f₀): the
//!   equation of motion is integrated from sample to sample. Over each interval the contact is
//!   linearised at its start (stiffness k_a·A, damping c_a·A, the rest held) and the linear
//!   equation solved exactly ([`crate::plant::linear::Propagator`] for the homogeneous part, a
//!   polynomial particular solution for a cubic input), so the stiff contact (c/M ≈ 10⁶ s⁻¹)
//!   is no problem; where the contact's stiffness changes fast (the touch, a shallow contact
//!   moving quickly) the interval is cut into sub-steps. What U did between samples is not in
//!   a recording: a controller's DAC holds it (a staircase, updated after the reading as in
//!   the plant, or just before it), a simulator or a smooth source interpolates it; [`Input`]
//!   is chosen by the fit.
//!   A recording starts wherever the instrument was — mid-oscillation when the excitation
//!   ran before it —, so the initial state (Z's departure from static equilibrium and Ż) is
//!   fitted: the free response is linear in both. The header's f₀ and Q are calibrations, not
//!   truths: small corrections are fitted under a Gaussian prior of their stated tolerance
//!   (`search`).
//!   A force curve sampled below its lever's resonance is still integrated so when the
//!   header gives f₀ and Q and a step of U would ring on past the next sample
//!   ([`super::problem::UNSETTLED`]): a DAC's staircase at the sampling rate kicks a high-Q
//!   lever at every row, and what the reading sees of that ringing is aliased. There f₀ and Q
//!   are taken as given (a per cent of f₀ moves the sampled phase by radians) and every
//!   input convention stays a start of the first stage.
//! * **Quasi-static** (force curves: µm/s, kHz sampling, far below resonance): the cantilever
//!   is a spring, `K·(U − Z) + F_ts + F_effects = 0` at every sample, solved implicitly
//!   (backward Euler for the dampers), the effects' forces iterated to the sample's state.
//!   With a DAC updated just before the reading ([`Input::HeldFromSample`]) the lever has
//!   settled to the previous row's U when the row's D is read: D = U_i − Z(U_{i−1}) (the
//!   search does not offer it for quasi-static recordings: there it is a drag of K·Δt on
//!   the base's velocity, which the drag candidate tests).
//!
//! Units inside: nm, µs, nN (as the plant).

use crate::plant::effects::{Effect, EffectContext};
use crate::plant::linear::Propagator;
use std::f64::consts::PI;

/// What the recording says about the instrument, internal units.
#[derive(Clone, Debug, PartialEq)]
pub struct Instrument {
    /// Cantilever spring constant K (nN/nm).
    pub k: f64,
    /// Cantilever damping C (nN·µs/nm); 0 for quasi-static.
    pub c: f64,
    /// Effective mass M (internal mass units, nN·µs²/nm); `None` for quasi-static.
    pub m: Option<f64>,
    /// Tip radius R (nm).
    pub r_tip: f64,
}

impl Instrument {
    /// Whether the model integrates the cantilever's dynamics.
    pub fn dynamic(&self) -> bool {
        self.m.is_some()
    }
    /// First-mode resonance (MHz = 1/µs), when dynamic.
    pub fn f0_mhz(&self) -> Option<f64> {
        self.m.map(|m| (self.k / m).sqrt() / (2.0 * PI))
    }
}

/// One unit's contact: height h (nm), bed spring k_a (nN/nm³), bed damper c_a (nN·µs/nm³).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    pub h: f64,
    pub k_a: f64,
    pub c_a: f64,
}

/// What the base did between two recorded samples of U.
///
/// Two DAC timings are physical and a recording's rows do not say which it used: the reading
/// of D at a sample is taken *before* the DAC takes the row's U ([`Input::Held`]: the row's U
/// was held over the interval that ends at its sample, the plant's convention), or just
/// *after* it ([`Input::HeldFromSample`]: the row's U is held from its own sample to the
/// next, so the reading sees the base's step but not yet the lever's response to it). They
/// differ by one sample of delay of the whole response, i.e. a residual of about Ḋ·Δt — at
/// the tone near resonance many times the noise. Both are fitted; the data choose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Input {
    /// Held at the new sample (a DAC's staircase updated after the reading; the plant's
    /// convention).
    Held,
    /// Held from its own sample to the next (a DAC's staircase updated just before the
    /// reading).
    HeldFromSample,
    /// A straight line between the samples (a continuous source, sampled).
    Linear,
    /// A cubic through the two samples and their neighbours (Catmull–Rom: a smooth
    /// command, such as the tones of an excitation, sampled; interpolation error O(ω⁴Δt⁴)
    /// where the line's is O(ω²Δt²)).
    Cubic,
}

impl Input {
    /// Every convention, in the order they are tried.
    pub const ALL: [Input; 4] = [
        Input::Held,
        Input::HeldFromSample,
        Input::Linear,
        Input::Cubic,
    ];
    /// For reports.
    pub fn describe(self) -> &'static str {
        match self {
            Input::Held => "held (a DAC's staircase, updated after the reading)",
            Input::HeldFromSample => {
                "held from its own sample on (a DAC's staircase, updated just before the reading)"
            }
            Input::Linear => "linear (a continuous source, sampled)",
            Input::Cubic => "cubic through the neighbouring samples (a smooth command, sampled)",
        }
    }
}

/// The bed under the tip. Its per-area spring k_a and damper c_a ([`Contact`]) mean the same
/// in both: a lattice element stands for one cell of area p², so it has k_a·p² and c_a·p².
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bed {
    /// The element bed's continuum limit: `F = k_a·V(δ) − c_a·A(δ)·Ż` (a real sample, or
    /// elements much finer than the contact).
    Continuum,
    /// The paper's bed itself (`method.md` (5)–(8)): a square lattice of Kelvin–Voigt
    /// elements at pitch p (nm), the tip's axis at `offset` (fractions of a pitch) in its
    /// cell. With a few elements under the tip (the paper's 100 nm under a 300 nm tip) the
    /// force steps as each element engages, which the continuum cannot follow; pitch and
    /// offset are nuisance parameters the fit searches (`search`).
    Lattice { pitch_nm: f64, offset: [f64; 2] },
}

impl Bed {
    /// For reports.
    pub fn describe(self) -> String {
        match self {
            Bed::Continuum => "continuum limit of the element bed".to_string(),
            // The lattice is periodic: the fit's offset (bounded to −1..2 so that it can
            // cross a cell's edge) is reported inside the cell, where refsim's stress
            // relaxation s2 read "(−1.000, −1.000)".
            Bed::Lattice { pitch_nm, offset } => format!(
                "square lattice of discrete elements, pitch {pitch_nm:.1} nm, tip axis at \
                 ({:.3}, {:.3}) of a cell",
                // (+ 0.0: −1 leaves −0.)
                offset[0].rem_euclid(1.0) + 0.0,
                offset[1].rem_euclid(1.0) + 0.0
            ),
        }
    }
}

/// The bed's contact geometry under a sphere of radius R: the elastic "volume" V(δ) and the
/// "area" A(δ) = dV/dδ whose products with k_a and c_a are the bed's elastic force and
/// damping. For a lattice, the sags s_i = R − √(R² − r_i²) of the elements under the tip
/// (r_i < R), ascending, and their prefix sums: V(δ) = p²·Σ_{s_i<δ}(δ − s_i), A(δ) = p²·n(δ).
#[derive(Clone, Debug)]
pub struct BedGeometry {
    r: f64,
    cell: f64,
    sags: Vec<f64>,
    prefix: Vec<f64>,
    lattice: bool,
}

impl BedGeometry {
    pub fn new(bed: Bed, r: f64) -> Self {
        match bed {
            Bed::Continuum => BedGeometry {
                r,
                cell: 0.0,
                sags: Vec::new(),
                prefix: Vec::new(),
                lattice: false,
            },
            Bed::Lattice { pitch_nm, offset } => {
                let p = pitch_nm.max(1e-3 * r).max(1e-9);
                let n = (r / p).ceil() as i64 + 2;
                let mut sags = Vec::new();
                for i in -n..=n {
                    for j in -n..=n {
                        let x = (i as f64 - offset[0]) * p;
                        let y = (j as f64 - offset[1]) * p;
                        let r2 = x * x + y * y;
                        if r2 < r * r {
                            sags.push(r - (r * r - r2).sqrt());
                        }
                    }
                }
                sags.sort_by(f64::total_cmp);
                let mut prefix = Vec::with_capacity(sags.len() + 1);
                let mut acc = 0.0;
                prefix.push(0.0);
                for s in &sags {
                    acc += s;
                    prefix.push(acc);
                }
                BedGeometry {
                    r,
                    cell: p * p,
                    sags,
                    prefix,
                    lattice: true,
                }
            }
        }
    }
    /// Whether the bed is a lattice (its force changes slope at each element's engagement).
    #[inline]
    pub fn is_lattice(&self) -> bool {
        self.lattice
    }
    /// Elements engaged at apex depth δ (lattice); 1 or 0 for the continuum.
    #[inline]
    pub fn engaged(&self, d: f64) -> usize {
        if self.lattice {
            self.sags.partition_point(|&s| s < d)
        } else {
            usize::from(d > 0.0)
        }
    }
    /// [`Self::engaged`]`(δ)` where it is likely `hint` (the count a moment ago), which it
    /// updates: two comparisons instead of the search where the hint holds.
    #[inline]
    pub fn engaged_near(&self, d: f64, hint: &mut usize) -> usize {
        if !self.engages(d, *hint) {
            *hint = self.engaged(d);
        }
        *hint
    }
    /// Whether `n` elements are engaged at apex depth δ: [`Self::engaged`]`(δ) == n` bit for
    /// bit without its search, from the two sags that bound the count (the lattice's event
    /// search asks it of one count ~40 times per event).
    #[inline]
    pub fn engages(&self, d: f64, n: usize) -> bool {
        if self.lattice {
            let below = n
                .checked_sub(1)
                .is_none_or(|i| self.sags.get(i).is_some_and(|&s| s < d));
            below && self.sags.get(n).is_none_or(|&s| !(s < d))
        } else {
            usize::from(d > 0.0) == n
        }
    }
    /// (V(δ), A(δ), elements engaged) with one search of the lattice: [`Self::volume`],
    /// [`Self::area`] and [`Self::engaged`] bit for bit, for the per-sample force (three
    /// binary searches per call were a tenth of a simulation).
    #[inline]
    pub fn at(&self, d: f64) -> (f64, f64, usize) {
        let n = self.engaged(d);
        let (vol, a) = self.at_count(d, n);
        (vol, a, n)
    }
    /// (V(δ), A(δ)) where `n` = [`Self::engaged`]`(δ)` is known (the one place of the
    /// lattice's sums; [`Self::at`] searches for `n` first).
    #[inline]
    pub fn at_count(&self, d: f64, n: usize) -> (f64, f64) {
        debug_assert!(self.engages(d, n));
        if self.lattice {
            let below = self.prefix.get(n).copied().unwrap_or(f64::NAN);
            (self.cell * (n as f64 * d - below), self.cell * n as f64)
        } else {
            (cap_volume(self.r, d), contact_area(self.r, d))
        }
    }
    /// V(δ) (nm³).
    #[inline]
    pub fn volume(&self, d: f64) -> f64 {
        self.at(d).0
    }
    /// A(δ) = dV/dδ (nm²).
    #[inline]
    pub fn area(&self, d: f64) -> f64 {
        if self.lattice {
            self.cell * self.engaged(d) as f64
        } else {
            contact_area(self.r, d)
        }
    }
}

/// The nominal parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Nominal {
    /// Detector offset d₀ (nm).
    pub offset: f64,
    /// Input between samples (dynamic only).
    pub input: Input,
    /// Initial state (dynamic only): Z's departure from the static equilibrium with the first
    /// U (nm) and Ż (nm/µs) at the first sample. A recording starts wherever the instrument
    /// was — mid-oscillation when the excitation ran before it — and the free response is
    /// linear in these two.
    pub z0: f64,
    pub v0: f64,
    /// Calibration corrections of the header's cantilever (dynamic only): f₀ × `f0_scale`
    /// (K kept, M adjusted) and Q × `q_scale`; 1 = the header's values.
    pub f0_scale: f64,
    pub q_scale: f64,
    /// The bed's form (one for the whole recording).
    pub bed: Bed,
    /// Per unit.
    pub contacts: Vec<Contact>,
}

impl Nominal {
    /// At rest in static equilibrium, the header's cantilever, the input held.
    pub fn new(offset: f64, contacts: Vec<Contact>) -> Self {
        Nominal {
            offset,
            input: Input::Held,
            z0: 0.0,
            v0: 0.0,
            f0_scale: 1.0,
            q_scale: 1.0,
            bed: Bed::Continuum,
            contacts,
        }
    }
    /// The instrument with the calibration corrections applied: M/f0_scale², C so that
    /// Q·q_scale holds with the new M.
    pub fn instrument(&self, inst: &Instrument) -> Instrument {
        match inst.m {
            Some(m) if self.f0_scale != 1.0 || self.q_scale != 1.0 => {
                let fs = self.f0_scale.max(1e-6);
                let qs = self.q_scale.max(1e-6);
                Instrument {
                    m: Some(m / (fs * fs)),
                    c: inst.c / (fs * qs),
                    ..inst.clone()
                }
            }
            _ => inst.clone(),
        }
    }
}

/// The recording in internal units, with each sample's unit.
#[derive(Clone, Debug)]
pub struct Data {
    pub t: Vec<f64>,
    pub u: Vec<f64>,
    pub d: Vec<f64>,
    /// Unit (tap, curve) of each sample, 0-based, non-decreasing.
    pub unit: Vec<usize>,
    /// Number of units.
    pub units: usize,
}

impl Data {
    pub fn len(&self) -> usize {
        self.t.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
}

/// Per-sample states of a simulation, for locating and figures.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    /// Tip height Z (nm), in the bed's frame.
    pub z: Vec<f64>,
    /// Apex depth δ = h − Z (nm); negative above the surface.
    pub depth: Vec<f64>,
    /// Sample force on the tip (nN).
    pub force: Vec<f64>,
    /// Effective base position after the effects' piezo hooks (nm).
    pub u_eff: Vec<f64>,
    /// Tip velocity Ż (nm/µs).
    pub v: Vec<f64>,
    /// What the effects saw at each sample's reading: [`reading_with`] replays an added
    /// effect on them.
    pub contexts: Vec<EffectContext>,
}

/// Volume of the cap below the bed's surface (nm³) at apex depth δ (see
/// [`crate::identify::signal::cap_volume`]).
#[inline]
pub fn cap_volume(r: f64, d: f64) -> f64 {
    if d <= 0.0 {
        0.0
    } else if d <= r {
        PI * d * d * (r - d / 3.0)
    } else {
        PI * r * r * (d - r / 3.0)
    }
}

/// Contact area πa² (nm²) at apex depth δ: dV/dδ.
#[inline]
pub fn contact_area(r: f64, d: f64) -> f64 {
    if d <= 0.0 {
        0.0
    } else if d <= r {
        PI * d * (2.0 * r - d)
    } else {
        PI * r * r
    }
}

/// Largest sub-steps per interval.
const SUBSTEPS_MAX: usize = 64;
/// Largest number of engagement events handled within one interval on a lattice (the rest of
/// the interval, if more, is one linearised piece).
const LATTICE_EVENTS_MAX: usize = 64;

/// The cubic Hermite path between (z0, v0) and (z1, v1) over `tau`, at the fraction q.
#[inline]
fn hermite(z0: f64, v0: f64, z1: f64, v1: f64, tau: f64, q: f64) -> f64 {
    let q2 = q * q;
    let q3 = q2 * q;
    (2.0 * q3 - 3.0 * q2 + 1.0) * z0
        + (q3 - 2.0 * q2 + q) * tau * v0
        + (-2.0 * q3 + 3.0 * q2) * z1
        + (q3 - q2) * tau * v1
}

/// Runs the model over `data`: the simulated detector reading per sample (nm), and the states
/// when `trace` is given. `effects` are fresh (their state starts at the first sample).
pub fn simulate(
    inst: &Instrument,
    nom: &Nominal,
    effects: &mut [Box<dyn Effect>],
    data: &Data,
    trace: Option<&mut Trace>,
) -> Vec<f64> {
    let mut out = simulate_before_offset(inst, nom, effects, data, trace);
    for d in &mut out {
        *d += nom.offset;
    }
    out
}

/// [`simulate`] without the detector offset d₀: nothing else reads d₀, so a reading at any
/// offset is this plus it, bit for bit (a fit's offset column needs no simulation).
pub fn simulate_before_offset(
    inst: &Instrument,
    nom: &Nominal,
    effects: &mut [Box<dyn Effect>],
    data: &Data,
    mut trace: Option<&mut Trace>,
) -> Vec<f64> {
    let n = data.len();
    let mut out = Vec::with_capacity(n);
    if n == 0 {
        return out;
    }
    if let Some(tr) = trace.as_deref_mut() {
        *tr = Trace::default();
        tr.z.reserve(n);
        tr.depth.reserve(n);
        tr.force.reserve(n);
        tr.u_eff.reserve(n);
        tr.v.reserve(n);
        tr.contexts.reserve(n);
    }
    let (k_lin, c_lin) = effects.iter().fold((0.0, 0.0), |(k, c), e| {
        let (ek, ec) = e.linear_terms();
        (k + ek, c + ec)
    });
    let inst = &nom.instrument(inst);
    let r = inst.r_tip;
    let geo = &BedGeometry::new(nom.bed, r);
    let contact_of = |i: usize| nom.contacts[data.unit[i].min(nom.contacts.len() - 1)];
    // Start from static equilibrium with the first U (effects' held forces excluded, as the
    // plant's settle), displaced by the fitted initial state.
    let c0 = contact_of(0);
    let mut z = static_equilibrium(inst.k + k_lin, inst.k * data.u[0], c0, geo);
    let mut v = 0.0;
    if inst.dynamic() {
        z += nom.z0;
        v = nom.v0;
    }
    let mut cache = PropagatorCache::default();
    // The lattice's count at the last context: the next one's is mostly the same.
    let mut hint = 0;
    // The effective base (after the effects' piezo hooks) of the previous two rows: the
    // `HeldFromSample` convention holds the previous row's over the interval, after the step
    // from the one before it.
    let mut u_eff_prev = data.u[0];
    let mut u_eff_prev2 = data.u[0];
    // Without effects (every simulation of the nominal fit) nothing reads the contexts
    // unless the states are traced: they are not built (two force evaluations per sample).
    let bare = effects.is_empty();
    for i in 0..n {
        let ct = contact_of(i);
        let dt = interval_before(data, i);
        let u_cmd = data.u[i];
        if i > 0 {
            let ctx0 = (!bare).then(|| context(ct, geo, data.t[i - 1], dt, z, v, u_cmd, &mut hint));
            let mut u_eff = u_cmd;
            let mut f_eff = 0.0;
            if let Some(ctx0) = &ctx0 {
                for e in effects.iter() {
                    u_eff = e.piezo_z_nm(ctx0, u_eff);
                }
            }
            match inst.m {
                Some(m) => {
                    if let Some(ctx0) = &ctx0 {
                        for e in effects.iter() {
                            f_eff += e.tip_force_nn(ctx0);
                        }
                    }
                    let sys = Dyn {
                        m,
                        k: inst.k + k_lin,
                        k_base: inst.k,
                        c: inst.c + c_lin,
                        c_base: inst.c,
                        r,
                        geo,
                        ct,
                    };
                    let poly = input_polynomial(nom.input, data, i, u_eff_prev2, u_eff_prev, u_eff);
                    (z, v) = sys.interval(z, v, &poly, f_eff, dt, &mut cache);
                }
                None => {
                    // The lever settles to the base that acted over the interval.
                    let u_acting = if nom.input == Input::HeldFromSample {
                        u_eff_prev
                    } else {
                        u_eff
                    };
                    (z, v) = quasi_static_step(
                        inst,
                        geo,
                        ct,
                        effects,
                        ctx0.as_ref(),
                        u_acting,
                        z,
                        dt,
                        k_lin,
                        c_lin,
                    );
                }
            }
            u_eff_prev2 = u_eff_prev;
            u_eff_prev = u_eff;
        }
        // Measure: the base at the reading is the row's in every convention (with
        // `HeldFromSample` it has just stepped there).
        let mut d = u_eff_prev - z;
        if !bare || trace.is_some() {
            let ctx = context(ct, geo, data.t[i], dt, z, v, u_cmd, &mut hint);
            for e in effects.iter() {
                d = e.measured_deflection_nm(&ctx, d);
            }
            for e in effects.iter_mut() {
                e.end_of_step(&ctx);
            }
            if let Some(tr) = trace.as_deref_mut() {
                tr.z.push(z);
                tr.depth.push(ct.h - z);
                tr.force.push(ctx.contact_force_nn);
                tr.u_eff.push(u_eff_prev);
                tr.v.push(v);
                tr.contexts.push(ctx);
            }
        }
        out.push(d);
    }
    out
}

/// The reading of the model that [`simulate`] gave `base` (with its states `trace`) once
/// `effect` is added last, for an effect that acts only on the reading
/// ([`crate::plant::effects::EffectKind::reading_only`]): the states are those of the model
/// without it, so the effect's hooks replay on them — what a full simulation computes, at the
/// cost of the effect's own arithmetic (a second mode's shape grid is ~150 such readings).
pub fn reading_with(
    nom: &Nominal,
    effect: &mut dyn Effect,
    data: &Data,
    trace: &Trace,
    base: &[f64],
) -> Vec<f64> {
    // The simulation's own contexts: what a full simulation's effects would see.
    trace
        .contexts
        .iter()
        .zip(base)
        .take(data.len())
        .map(|(ctx, &b)| {
            let d = effect.measured_deflection_nm(ctx, b - nom.offset);
            effect.end_of_step(ctx);
            d + nom.offset
        })
        .collect()
}

/// The interval (µs) that ends at sample `i`; the first sample's is taken as the next one's.
#[inline]
fn interval_before(data: &Data, i: usize) -> f64 {
    match i {
        0 if data.len() > 1 => data.t[1] - data.t[0],
        0 => 1.0,
        _ => data.t[i] - data.t[i - 1],
    }
}

/// What the effects see at time `t` with the tip at (Z, Ż) and the commanded U; `hint` is
/// the lattice's count at the caller's last context ([`BedGeometry::engaged_near`]).
#[allow(clippy::too_many_arguments)]
#[inline]
fn context(
    ct: Contact,
    geo: &BedGeometry,
    t: f64,
    dt: f64,
    z: f64,
    v: f64,
    u_cmd: f64,
    hint: &mut usize,
) -> EffectContext {
    let d = ct.h - z;
    // No element is engaged at δ ≤ 0 (every sag is ≥ 0), nor for the continuum: as `force`
    // and `engaged` would say.
    let (vol, area, engaged) = if d > 0.0 {
        let n = geo.engaged_near(d, hint);
        let (vol, area) = geo.at_count(d, n);
        (vol, area, n)
    } else {
        (0.0, 0.0, 0)
    };
    let (fe, fd) = if d > 0.0 {
        (ct.k_a * vol, -ct.c_a * area * v)
    } else {
        (0.0, 0.0)
    };
    EffectContext {
        time_us: t,
        dt_us: dt,
        z_nm: z,
        z_dot_nm_per_us: v,
        u_nm: u_cmd,
        x_nm: 0.0,
        y_nm: 0.0,
        contact_force_nn: fe + fd,
        elastic_force_nn: fe,
        depth_nm: d,
        active_elements: engaged,
    }
}

/// The bed's (elastic, damping) force on the tip at (Z, Ż).
#[inline]
fn force(ct: Contact, geo: &BedGeometry, z: f64, v: f64) -> (f64, f64) {
    let d = ct.h - z;
    if d > 0.0 {
        (ct.k_a * geo.volume(d), -ct.c_a * geo.area(d) * v)
    } else {
        (0.0, 0.0)
    }
}

/// Z where `k·Z = f + k_a·V(h − Z)` (the static balance with the base force f = K·U).
fn static_equilibrium(k: f64, f: f64, ct: Contact, geo: &BedGeometry) -> f64 {
    let free = f / k;
    if free >= ct.h || ct.k_a <= 0.0 {
        return free;
    }
    // g(z) = f + k_a·V(h − z) − k·z decreases in z; root in [free, h).
    let g = |z: f64| f + ct.k_a * geo.volume(ct.h - z) - k * z;
    let (mut lo, mut hi) = (free, ct.h);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 * (1.0 + hi.abs()) {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// `x.ceil() as usize` as the sub-step count uses it (`n ≤ 1`, `n.min(SUBSTEPS_MAX)`): the
/// same up to SUBSTEPS_MAX + 1, NaN → 0 as the cast. `ceil` is a libm call on the default
/// x86-64 target, ~1 % of a continuum's simulation.
#[inline]
fn ceil_count(x: f64) -> usize {
    if !(x > 0.0) {
        return 0; // NaN and x ≤ 0, as the saturating cast
    }
    let x = x.min((SUBSTEPS_MAX + 1) as f64);
    let t = x as usize;
    if (t as f64) < x {
        t + 1
    } else {
        t
    }
}

/// The dynamic system of one interval.
struct Dyn<'a> {
    m: f64,
    /// Cantilever stiffness with the effects' linear terms (on Z).
    k: f64,
    /// Cantilever stiffness on U.
    k_base: f64,
    c: f64,
    c_base: f64,
    r: f64,
    geo: &'a BedGeometry,
    ct: Contact,
}

/// The base over one sample interval: `u(s) = Σ c_j·s^j`, s ∈ [0, 1] from the previous
/// sample to this one, and the velocity jump at its start (nm/µs·(nN·µs/nm)/mass: the held
/// input's step through the base damping, C·Δu/M, applied as an impulse).
#[derive(Clone, Copy, Debug)]
struct InputPoly {
    c: [f64; 4],
    /// The step of U at the interval's start (nm), for the impulse C·Δu/M.
    jump: f64,
    /// Held over the interval: `c[1..]` are +0 by construction, not by chance.
    held: bool,
}

/// The base's path between samples i − 1 and i under `input`; `u0`, `u1` are the effective
/// base (after the effects' piezo hooks) at both ends, `u_before` the one at sample i − 2.
/// The cubic follows the commanded U's neighbours, the effects' change of the base riding on
/// it linearly.
#[inline]
fn input_polynomial(
    input: Input,
    data: &Data,
    i: usize,
    u_before: f64,
    u0: f64,
    u1: f64,
) -> InputPoly {
    match input {
        Input::Held => InputPoly {
            c: [u1, 0.0, 0.0, 0.0],
            jump: u1 - u0,
            held: true,
        },
        // The step to u0 happened at sample i − 1, just before its reading: its impulse acts
        // from there (at the first sample it is part of the fitted initial state).
        Input::HeldFromSample => InputPoly {
            c: [u0, 0.0, 0.0, 0.0],
            jump: if i >= 2 { u0 - u_before } else { 0.0 },
            held: true,
        },
        Input::Linear => InputPoly {
            c: [u0, u1 - u0, 0.0, 0.0],
            jump: 0.0,
            held: false,
        },
        Input::Cubic => {
            let n = data.len();
            let (a, b) = (data.u[i - 1], data.u[i]);
            // Catmull–Rom tangents (per interval), one-sided at the ends.
            let m0 = if i >= 2 {
                0.5 * (b - data.u[i - 2])
            } else {
                b - a
            };
            let m1 = if i + 1 < n {
                0.5 * (data.u[i + 1] - a)
            } else {
                b - a
            };
            let c2 = 3.0 * (b - a) - 2.0 * m0 - m1;
            let c3 = 2.0 * (a - b) + m0 + m1;
            // The effects' share: (u0 − a) → (u1 − b), linearly.
            let (e0, e1) = (u0 - a, u1 - b);
            InputPoly {
                c: [a + e0, m0 + (e1 - e0), c2, c3],
                jump: 0.0,
                held: false,
            }
        }
    }
}

impl InputPoly {
    /// The polynomial re-expanded about s0 in local time τ = (s − s0)·dt: (b0, b1, b2, b3).
    #[inline]
    fn local(&self, s0: f64, inv_dt: f64) -> [f64; 4] {
        let [c0, c1, c2, c3] = self.c;
        let p = c0 + s0 * (c1 + s0 * (c2 + s0 * c3));
        let d1 = c1 + s0 * (2.0 * c2 + 3.0 * s0 * c3);
        let d2 = c2 + 3.0 * s0 * c3;
        // One division per distinct Δt (the caller's): the three of d1/Δt, d2/Δt², c3/Δt³
        // were a fair share of a piece.
        let r = inv_dt;
        let r2 = r * r;
        [p, d1 * r, d2 * r2, c3 * (r2 * r)]
    }
}

/// Propagators by key (c, k, τ) at one M: in free flight every interval has the same one,
/// and on a lattice one per number of engaged elements, while `Propagator::new` (an exp and
/// a sin/cos pair) is most of a step's cost. A few entries, the least recently used
/// replaced: an engagement event's pieces (one-off τ) would otherwise evict the full
/// interval's propagator of the count before and after it. Exact keys, so the result is the uncached one.
/// Beside them, what else one simulation reuses from piece to piece: 1/Δt and the lattice's
/// last count.
#[derive(Default)]
struct PropagatorCache {
    entries: [CacheEntry; PROPAGATOR_CACHE],
    clock: u64,
    /// The entry of the last hit, tried first: consecutive samples mostly share a key.
    last: usize,
    /// M and 1/M of the last miss (one simulation has one M).
    mass: (f64, f64),
    /// The last interval Δt (its bits) and 1/Δt: a recording's intervals are mostly one.
    interval: Option<(u64, f64)>,
    /// The lattice's count at the last piece's start: the next one's is mostly the same.
    engaged: usize,
}

/// One key (c, k, τ) of [`PropagatorCache`], its propagator, 1/k (the particular solution's
/// four divisions by k made products) and when it was last used.
#[derive(Clone, Copy, Default)]
struct CacheEntry {
    c: f64,
    k: f64,
    tau: f64,
    prop: Propagator,
    inv_k: f64,
    used: u64,
}

/// Entries of [`PropagatorCache`]: the counts a tap's depth visits within a few samples.
const PROPAGATOR_CACHE: usize = 8;

impl PropagatorCache {
    /// 1/Δt, divided again only where the interval changes (bit for bit the same).
    #[inline]
    fn inv_interval(&mut self, dt: f64) -> f64 {
        match self.interval {
            Some((bits, r)) if bits == dt.to_bits() => r,
            _ => {
                let r = dt.recip();
                self.interval = Some((dt.to_bits(), r));
                r
            }
        }
    }

    /// The propagator of (c, k, τ) at mass `m` and 1/k, not looked up: a continuum's
    /// contact stiffness is new at every piece, and the search of the entries and the
    /// replacement of one cost a tenth of such a simulation for nothing.
    #[inline]
    fn compute(&mut self, m: f64, c: f64, k: f64, tau: f64) -> (Propagator, f64) {
        if self.mass.0 != m {
            self.mass = (m, m.recip());
        }
        let im = self.mass.1;
        (
            Propagator::from_rates(k * im, -0.5 * c * im, tau),
            k.recip(),
        )
    }

    /// The propagator of (c, k, τ) at mass `m` and 1/k. The last entry used is the usual
    /// one (free flight, a lattice between engagements), tried inline; a hit there leaves
    /// the stamps alone.
    #[inline(always)]
    fn get(&mut self, m: f64, c: f64, k: f64, tau: f64) -> (Propagator, f64) {
        // τ = 0 marks an empty entry (a piece of zero length is recomputed, as before).
        let e = &self.entries[self.last];
        if e.tau != 0.0 && e.tau == tau && e.c == c && e.k == k {
            return (e.prop, e.inv_k);
        }
        self.get_other(m, c, k, tau)
    }

    /// [`PropagatorCache::get`] past the last entry: the others searched, the least
    /// recently used replaced on a miss. An entry is stamped when it stops being the last,
    /// so the smallest stamp is still the least recently used.
    #[inline(never)]
    fn get_other(&mut self, m: f64, c: f64, k: f64, tau: f64) -> (Propagator, f64) {
        self.clock += 1;
        self.entries[self.last].used = self.clock;
        let is = |e: &CacheEntry| e.tau != 0.0 && (e.c, e.k, e.tau) == (c, k, tau);
        let i = match self.entries.iter().position(is) {
            Some(i) => i,
            None => {
                let i = (0..PROPAGATOR_CACHE)
                    .min_by_key(|&i| self.entries[i].used)
                    .unwrap_or(0);
                let (prop, inv_k) = self.compute(m, c, k, tau);
                self.entries[i] = CacheEntry {
                    c,
                    k,
                    tau,
                    prop,
                    inv_k,
                    used: 0,
                };
                i
            }
        };
        self.last = i;
        self.clock += 1;
        let e = &mut self.entries[i];
        e.used = self.clock;
        (e.prop, e.inv_k)
    }
}

impl Dyn<'_> {
    /// Advances (z, v) over one sample interval of length `dt` with the base following
    /// `poly`, an extra held force `f_eff`.
    #[inline]
    fn interval(
        &self,
        z: f64,
        v: f64,
        poly: &InputPoly,
        f_eff: f64,
        dt: f64,
        cache: &mut PropagatorCache,
    ) -> (f64, f64) {
        // A held input jumps at the start: an impulse C·Δu/M through the base damping.
        // (No division where there is no step: every smooth convention, most held samples;
        // the same bits but for the sign of a zero velocity.)
        let v = if poly.jump != 0.0 {
            v + self.c_base * poly.jump / self.m
        } else {
            v
        };
        if self.geo.is_lattice() {
            return self.interval_lattice(z, v, poly, f_eff, dt, cache);
        }
        // Trial step; cut into sub-steps where the contact stiffness changes fast.
        let (z1, v1) = self.piece(z, v, poly, 0.0, 1.0, f_eff, dt, None, cache);
        let d0 = self.ct.h - z;
        let d1 = self.ct.h - z1;
        if !(d0 > 0.0 || d1 > 0.0) || self.ct.k_a <= 0.0 {
            return (z1, v1);
        }
        let shallow = d0.min(d1) < self.r;
        if !shallow {
            return (z1, v1);
        }
        // Relative change of the contact area over the step: A ∝ δ while shallow.
        let scale = d0.max(d1).max(1e-3);
        let n = ceil_count((z1 - z).abs() / (0.02 * scale));
        if n <= 1 {
            return (z1, v1);
        }
        let n = n.min(SUBSTEPS_MAX);
        let (mut zz, mut vv) = (z, v);
        for j in 0..n {
            let (s0, s1) = (j as f64 / n as f64, (j + 1) as f64 / n as f64);
            (zz, vv) = self.piece(zz, vv, poly, s0, s1, f_eff, dt, None, cache);
        }
        (zz, vv)
    }

    /// [`Dyn::interval`] on a lattice: between engagements the bed is linear, so each piece
    /// is exact; an element entering or leaving contact is an event, located (on the exact
    /// solution, by bisection) and stepped to, so its damper switches where it should. A
    /// crossing is looked for on the cubic Hermite path through the piece's ends at eight
    /// points (a brief dip past one element and back inside an eighth of a sample is missed:
    /// its impulse is c_el·Ż·τ over that sliver).
    #[allow(clippy::too_many_arguments)]
    fn interval_lattice(
        &self,
        z: f64,
        v: f64,
        poly: &InputPoly,
        f_eff: f64,
        dt: f64,
        cache: &mut PropagatorCache,
    ) -> (f64, f64) {
        let h = self.ct.h;
        let (mut zz, mut vv, mut s) = (z, v, 0.0);
        for _ in 0..LATTICE_EVENTS_MAX {
            // The count at the piece's start: its force's and the event search's.
            let n0 = self.geo.engaged_near(h - zz, &mut cache.engaged);
            let (z1, v1) = self.piece(zz, vv, poly, s, 1.0, f_eff, dt, Some(n0), cache);
            if self.ct.k_a <= 0.0 && self.ct.c_a <= 0.0 {
                return (z1, v1);
            }
            let tau = (1.0 - s) * dt;
            // The Hermite path stays within the ends' range widened by 4/27·τ·(|Ż₀| + |Ż₁|)
            // (its value weights h₀₀ + h₀₁ = 1 are in [0, 1], its slope weights at most 4/27
            // in size), plus a margin for rounding: where the count is the same at both edges
            // none of the eight points below can differ from n0 (the count is monotone in
            // the depth), so the search is skipped; most samples are such, free or pressed.
            let swing = 4.0 / 27.0 * tau * (vv.abs() + v1.abs());
            let margin = 1e-12 * (zz.abs() + z1.abs() + swing) + 1e-300;
            let (z_lo, z_hi) = (zz.min(z1) - swing - margin, zz.max(z1) + swing + margin);
            if self.geo.engages(h - z_hi, n0) && self.geo.engages(h - z_lo, n0) {
                return (z1, v1);
            }
            let mut hit = None;
            for j in 1..=8 {
                let q = j as f64 / 8.0;
                let zq = hermite(zz, vv, z1, v1, tau, q);
                if !self.geo.engages(h - zq, n0) {
                    hit = Some(q);
                    break;
                }
            }
            let Some(q) = hit else {
                return (z1, v1);
            };
            // The crossing located on the Hermite path (its error h⁴·|Z⁗|/384, as the plant's
            // event search), then the exact solution advanced to it: one propagator per
            // event. If the exact path has not crossed yet, the next piece finds it again a
            // sliver later.
            let (mut lo, mut hi) = (q - 0.125, q);
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if self.geo.engages(h - hermite(zz, vv, z1, v1, tau, mid), n0) {
                    lo = mid;
                } else {
                    hi = mid;
                }
                if (hi - lo) * tau < 1e-9 {
                    break;
                }
            }
            let s_new = s + (1.0 - s) * hi;
            (zz, vv) = self.piece(zz, vv, poly, s, s_new, f_eff, dt, Some(n0), cache);
            s = s_new;
            if s >= 1.0 - 1e-12 {
                return (zz, vv);
            }
        }
        self.piece(zz, vv, poly, s, 1.0, f_eff, dt, None, cache)
    }

    /// Exact solution over the fraction `[s0, s1]` of the interval with the contact linearised
    /// at its start and the base a cubic in time: a polynomial particular solution, the
    /// homogeneous deviation propagated exactly. `engaged`: the lattice's count at the start
    /// where the caller has it (its search saved).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn piece(
        &self,
        z: f64,
        v: f64,
        poly: &InputPoly,
        s0: f64,
        s1: f64,
        f_eff: f64,
        dt: f64,
        engaged: Option<usize>,
        cache: &mut PropagatorCache,
    ) -> (f64, f64) {
        let tau = (s1 - s0) * dt;
        let d = self.ct.h - z;
        let (kt, ct, f_hold) = if d > 0.0 {
            let (vol, a) = match engaged {
                Some(n) => self.geo.at_count(d, n),
                None => {
                    let (vol, a, _) = self.geo.at(d);
                    (vol, a)
                }
            };
            let kt = self.ct.k_a * a;
            let cc = self.ct.c_a * a;
            // F ≈ f_hold − kt·Z − cc·Ż around the start (exact on a lattice until the next
            // engagement).
            let f0 = self.ct.k_a * vol - cc * v;
            (kt, cc, f0 + kt * z + cc * v)
        } else {
            (0.0, 0.0, 0.0)
        };
        let (k, c, m) = (self.k + kt, self.c + ct, self.m);
        let (kb, cb) = (self.k_base, self.c_base);
        // Cached: in free flight, and on a lattice between engagements, every interval has
        // the same one.
        let (prop, ik) = if kt != 0.0 && !self.geo.is_lattice() {
            cache.compute(m, c, k, tau)
        } else {
            cache.get(m, c, k, tau)
        };
        let inv_dt = cache.inv_interval(dt);
        if poly.held
            && kb > 0.0
            && k > 0.0
            && ik < f64::INFINITY
            && c >= 0.0
            && m >= 0.0
            && tau >= 0.0
            && inv_dt < f64::INFINITY
        {
            // A held base: the general path below with c₁ = c₂ = c₃ = +0, each of its
            // operations taken with its IEEE signed zeros, under these signs (and a finite
            // 1/Δt, or b₁ would be 0·∞). Its b₁..b₃,
            // a₁..a₃ and p₁..p₃ are all +0; b₀ = c₀ + 0 (−0 becomes +0); the sum
            // K·b₀ + C·(±0) is K·b₀, never −0 for K > 0 and b₀ ≠ −0; p₀ = a₀/k; subtracting
            // a +0 changes nothing; the particular solution's τ-polynomials are p₀ + 0 and
            // +0. So the same bits, without the cubic's arithmetic.
            let b0 = poly.c[0] + 0.0;
            let a0 = kb * b0 + f_hold + f_eff;
            let p0 = a0 * ik;
            let (e1, ed1) = prop.apply(z - p0, v, 0.0);
            return (e1 + (p0 + 0.0), ed1 + 0.0);
        }
        // Force K·u + C·u̇ + held terms as a cubic in local time: a0 + a1·τ + a2·τ² + a3·τ³.
        let [b0, b1, b2, b3] = poly.local(s0, inv_dt);
        let a0 = kb * b0 + cb * b1 + f_hold + f_eff;
        let a1 = kb * b1 + 2.0 * cb * b2;
        let a2 = kb * b2 + 3.0 * cb * b3;
        let a3 = kb * b3;
        // Particular solution p0 + p1·τ + p2·τ² + p3·τ³ of M·z̈ + c·ż + k·z = a(τ).
        let p3 = a3 * ik;
        let p2 = (a2 - 3.0 * c * p3) * ik;
        let p1 = (a1 - 2.0 * c * p2 - 6.0 * m * p3) * ik;
        let p0 = (a0 - c * p1 - 2.0 * m * p2) * ik;
        let (e1, ed1) = prop.apply(z - p0, v - p1, 0.0);
        let zp = p0 + tau * (p1 + tau * (p2 + tau * p3));
        let vp = p1 + tau * (2.0 * p2 + 3.0 * tau * p3);
        (e1 + zp, ed1 + vp)
    }
}

/// One quasi-static sample: Z where `K·(U − Z) − k_lin·Z + F_ts + F_eff = 0` with the dampers
/// by backward Euler; the effects' forces are evaluated at the solution (twice iterated).
/// `ctx0` is the context at the interval's start, given when there are effects.
#[allow(clippy::too_many_arguments)]
fn quasi_static_step(
    inst: &Instrument,
    geo: &BedGeometry,
    ct: Contact,
    effects: &[Box<dyn Effect>],
    ctx0: Option<&EffectContext>,
    u: f64,
    z_prev: f64,
    dt: f64,
    k_lin: f64,
    c_lin: f64,
) -> (f64, f64) {
    let mut f_eff = 0.0;
    if let Some(ctx0) = ctx0 {
        for e in effects {
            f_eff += e.tip_force_nn(ctx0);
        }
    }
    let mut z = solve_quasi_static(inst.k, k_lin, c_lin, ct, geo, u, z_prev, dt, f_eff);
    if let Some(ctx0) = ctx0 {
        for _ in 0..2 {
            let v = (z - z_prev) / dt;
            let (fe, fd) = force(ct, geo, z, v);
            let ctx = EffectContext {
                z_nm: z,
                z_dot_nm_per_us: v,
                contact_force_nn: fe + fd,
                elastic_force_nn: fe,
                depth_nm: ct.h - z,
                active_elements: geo.engaged(ct.h - z),
                ..*ctx0
            };
            let f_new: f64 = effects.iter().map(|e| e.tip_force_nn(&ctx)).sum();
            if (f_new - f_eff).abs() <= 1e-12 * (1.0 + f_eff.abs()) {
                break;
            }
            f_eff = f_new;
            z = solve_quasi_static(inst.k, k_lin, c_lin, ct, geo, u, z_prev, dt, f_eff);
        }
    }
    (z, (z - z_prev) / dt)
}

/// The root of `g(z) = K·(u − z) − k_lin·z − c_lin·(z − z₀)/dt + k_a·V(h − z)
/// − c_a·A(h − z)·(z − z₀)/dt + f = 0`, strictly decreasing in z.
#[allow(clippy::too_many_arguments)]
fn solve_quasi_static(
    k: f64,
    k_lin: f64,
    c_lin: f64,
    ct: Contact,
    geo: &BedGeometry,
    u: f64,
    z0: f64,
    dt: f64,
    f: f64,
) -> f64 {
    let cd = c_lin / dt;
    let g = |z: f64| -> (f64, f64) {
        let d = ct.h - z;
        let (fe, a) = if d > 0.0 {
            (ct.k_a * geo.volume(d), geo.area(d))
        } else {
            (0.0, 0.0)
        };
        let cb = ct.c_a * a / dt;
        let val = k * (u - z) - k_lin * z - cd * (z - z0) + fe - cb * (z - z0) + f;
        // Slope: the area's own change with z is left out (it only steers Newton).
        let slope = -(k + k_lin + cd + ct.k_a * a + cb);
        (val, slope)
    };
    // Free solution first: valid when it stays above the surface.
    let z_free = (k * u + cd * z0 + f) / (k + k_lin + cd);
    if z_free >= ct.h || ct.k_a <= 0.0 && ct.c_a <= 0.0 {
        return z_free;
    }
    // Bracket: g(h) ≥ 0 side is below... g decreases in z; g(z_free) ≥ 0 when the bed pushes.
    let mut lo = z_free.min(ct.h);
    let mut hi = ct.h.max(z_free);
    // Ensure g(lo) ≥ 0 ≥ g(hi).
    let mut step = (hi - lo).abs().max(1.0);
    while g(lo).0 < 0.0 {
        lo -= step;
        step *= 2.0;
        if step > 1e12 {
            break;
        }
    }
    let mut step = 1.0;
    while g(hi).0 > 0.0 {
        hi += step;
        step *= 2.0;
        if step > 1e12 {
            break;
        }
    }
    let mut x = z0.clamp(lo, hi);
    for _ in 0..100 {
        let (gx, s) = g(x);
        if gx > 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let mut next = x - gx / s;
        if !(next > lo && next < hi) {
            next = 0.5 * (lo + hi);
        }
        if (next - x).abs() <= 1e-13 * (1.0 + x.abs()) || hi - lo <= 1e-13 * (1.0 + x.abs()) {
            return next;
        }
        x = next;
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lattice's offset is reported inside its cell, whatever side of a cell's edge the fit
    /// left it on (the lattice is periodic), and never as −0.
    #[test]
    fn a_lattice_offset_is_described_inside_its_cell() {
        let d = Bed::Lattice {
            pitch_nm: 60.0,
            offset: [-1.0, 1.25],
        }
        .describe();
        assert!(d.ends_with("tip axis at (0.000, 0.250) of a cell"), "{d}");
    }

    /// A lattice's contact area p²·n(δ) against the continuum's πa²: the cells of the
    /// engaged elements cover the disk of radius a − p/√2 and lie inside the one of radius
    /// a + p/√2, so |p²·n − πa²| ≤ π(√2·a·p + p²/2); V is the integral of A over δ, so its
    /// error is at most δ times that bound at δ. And V's slope is A between engagements.
    #[test]
    fn a_fine_lattice_converges_to_the_continuum_within_its_cell_bound() {
        let r = 300.0;
        for (pitch, offset) in [(15.0, [0.3, 0.7]), (100.0, [0.0, 0.0]), (60.0, [0.5, 0.25])] {
            let geo = BedGeometry::new(
                Bed::Lattice {
                    pitch_nm: pitch,
                    offset,
                },
                r,
            );
            for d in [20.0, 75.0, 150.0, 280.0] {
                let a = (2.0 * r * d - d * d).sqrt();
                let bound = PI * (2f64.sqrt() * a * pitch + pitch * pitch / 2.0);
                let da = (geo.area(d) - contact_area(r, d)).abs();
                assert!(
                    da <= bound,
                    "pitch {pitch} δ {d}: area off by {da} > {bound}"
                );
                let dv = (geo.volume(d) - cap_volume(r, d)).abs();
                assert!(dv <= d * bound, "pitch {pitch} δ {d}: volume off by {dv}");
                // Slope: between engagements V is linear with slope A.
                let eps = 1e-6;
                if geo.engaged(d) == geo.engaged(d + eps) {
                    let slope = (geo.volume(d + eps) - geo.volume(d)) / eps;
                    assert!((slope - geo.area(d)).abs() <= 1e-6 * geo.area(d).max(1.0));
                }
            }
        }
    }

    /// `engages(δ, n)` is `engaged(δ) == n` for every count, and `at_count` is `at` bit for
    /// bit, at depths on, between and beyond the sags (ties included), on lattices and the
    /// continuum.
    #[test]
    fn engages_is_the_engaged_count_compared() {
        let beds = [
            Bed::Continuum,
            Bed::Lattice {
                pitch_nm: 100.0,
                offset: [0.0, 0.0],
            },
            Bed::Lattice {
                pitch_nm: 15.0,
                offset: [0.37, 0.61],
            },
        ];
        for bed in beds {
            let geo = BedGeometry::new(bed, 300.0);
            let mut depths: Vec<f64> = vec![-1.0, 0.0, 1e-300, 1e9, f64::NAN];
            for &s in &geo.sags {
                depths.extend([s, s.next_down(), s.next_up(), s + 0.5]);
            }
            let top = geo.sags.len() + 2;
            for &d in &depths {
                let (vol, a, n) = geo.at(d);
                let (vol_n, a_n) = geo.at_count(d, n);
                assert_eq!(
                    (vol_n.to_bits(), a_n.to_bits()),
                    (vol.to_bits(), a.to_bits())
                );
                for n in 0..top {
                    assert_eq!(
                        geo.engages(d, n),
                        geo.engaged(d) == n,
                        "{bed:?} d {d} n {n}"
                    );
                }
            }
        }
    }

    /// On a lattice the tip at rest on k elements pressed δ deep balances K·(U − Z) against
    /// k_el·Σ(δ − s_i): the static equilibrium found by bisection meets it to 10⁻⁹ nN.
    #[test]
    fn the_static_balance_on_a_lattice_is_the_elements_sum() {
        let r = 300.0;
        let geo = BedGeometry::new(
            Bed::Lattice {
                pitch_nm: 100.0,
                offset: [0.2, 0.6],
            },
            r,
        );
        let ct = Contact {
            h: 0.0,
            k_a: 3e-7,
            c_a: 6e-5,
        };
        let k = 0.18;
        let u = -150.0;
        let z = static_equilibrium(k, k * u, ct, &geo);
        let d = ct.h - z;
        let by_hand: f64 = geo
            .sags
            .iter()
            .filter(|&&s| s < d)
            .map(|s| ct.k_a * 1e4 * (d - s))
            .sum();
        assert!(d > 0.0 && geo.engaged(d) > 0);
        assert!(
            (k * (z - u) - by_hand).abs() < 1e-9,
            "{} vs {by_hand}",
            k * (z - u)
        );
    }

    /// The propagator cache returns the uncached propagator from 1/M bit for bit, through
    /// hits, misses and evictions (more keys than entries, revisited out of order), and
    /// `Propagator::new` to rounding; τ = 0 is never a hit.
    #[test]
    fn the_propagator_cache_returns_the_uncached_propagator() {
        let m = 11.8;
        let im = 1.0 / m;
        let uncached = |c: f64, k: f64, tau: f64| {
            let p = Propagator::from_rates(k * im, -0.5 * c * im, tau);
            // Against the divisions of `new`: a few roundings apart.
            let q = Propagator::new(m, c, k, tau);
            for (a, b) in p.phi.iter().flatten().zip(q.phi.iter().flatten()) {
                assert!((a - b).abs() <= 1e-14 * (1.0 + b.abs()), "{a} vs {b}");
            }
            (p, k.recip())
        };
        let mut cache = PropagatorCache::default();
        let keys: Vec<(f64, f64, f64)> = (0..PROPAGATOR_CACHE + 5)
            .map(|i| {
                (
                    0.01 + 0.3 * i as f64,
                    0.18 + 0.05 * i as f64,
                    2.0 - 0.1 * i as f64,
                )
            })
            .collect();
        let order = [
            0usize, 1, 0, 2, 3, 4, 5, 6, 7, 8, 0, 9, 1, 12, 11, 10, 0, 3, 3, 12,
        ];
        for &i in &order {
            let (c, k, tau) = keys[i];
            assert_eq!(cache.get(m, c, k, tau), uncached(c, k, tau), "key {i}");
        }
        let zero = cache.get(m, 0.5, 0.2, 0.0);
        assert_eq!(zero, uncached(0.5, 0.2, 0.0));
        // An entry never filled is all zeros with τ = 0: a zero key must not read it.
        let mut fresh = PropagatorCache::default();
        assert_eq!(fresh.get(m, 0.0, 1e-3, 0.0), uncached(0.0, 1e-3, 0.0));
        // Computed without the entries (a continuum's contact pieces), between lookups.
        for &i in &order {
            let (c, k, tau) = keys[i];
            let k2 = k * 1.37;
            assert_eq!(
                cache.compute(m, c, k2, tau),
                uncached(c, k2, tau),
                "key {i}"
            );
            assert_eq!(cache.get(m, c, k, tau), uncached(c, k, tau), "key {i}");
        }
    }

    /// A held base's short path through the exact step gives the general path's bits,
    /// signed zeros and all: on both beds, in and out of contact, for zero and negative-zero
    /// states and inputs, Δt down to 0 and subnormal, and for negative stiffness or damping
    /// (where the short path must not be taken).
    #[test]
    fn a_held_base_steps_bit_for_bit_as_the_general_cubic() {
        let mut rng = crate::plant::rng::Xoshiro256pp::new(11);
        let mut u = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_open01();
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        let beds = [
            Bed::Continuum,
            Bed::Lattice {
                pitch_nm: 100.0,
                offset: [0.25, 0.5],
            },
        ];
        let zeros = [0.0, -0.0];
        let mut checked = 0;
        for bed in beds {
            let geo = BedGeometry::new(bed, 300.0);
            for case in 0..4000 {
                let pick = |i: usize, x: f64| if case % 7 == i { zeros[case % 2] } else { x };
                let sys = Dyn {
                    m: 11.8,
                    k: if case % 11 == 0 { -0.3 } else { u(0.05, 0.5) },
                    k_base: u(0.05, 0.5),
                    c: if case % 13 == 0 { -0.01 } else { u(0.0, 0.2) },
                    c_base: u(0.0, 0.2),
                    r: 300.0,
                    geo: &geo,
                    ct: Contact {
                        h: u(-50.0, 50.0),
                        k_a: pick(5, u(0.0, 1e-3)),
                        c_a: u(0.0, 1e-3),
                    },
                };
                let z = pick(1, u(-100.0, 100.0));
                let v = pick(2, u(-5.0, 5.0));
                let f_eff = pick(3, u(-1.0, 1.0));
                let c0 = pick(4, u(-200.0, 200.0));
                let s0 = if case % 3 == 0 { 0.0 } else { u(0.0, 0.9) };
                let s1 = if case % 5 == 0 { s0 } else { u(s0, 1.0) };
                let dt = [1.0, 0.5, 2e-3, 1e-310, 0.0][case % 5];
                let held = InputPoly {
                    c: [c0, 0.0, 0.0, 0.0],
                    jump: 0.0,
                    held: true,
                };
                let general = InputPoly {
                    held: false,
                    ..held
                };
                let engaged = geo.is_lattice().then(|| geo.engaged(sys.ct.h - z));
                let (mut c1, mut c2) = (PropagatorCache::default(), PropagatorCache::default());
                let a = sys.piece(z, v, &held, s0, s1, f_eff, dt, engaged, &mut c1);
                let b = sys.piece(z, v, &general, s0, s1, f_eff, dt, engaged, &mut c2);
                assert!(
                    same(a.0, b.0) && same(a.1, b.1),
                    "case {case} on {bed:?}: {a:?} against {b:?}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 8000);
    }

    /// The sub-step count is `ceil` as the interval uses it: exact to SUBSTEPS_MAX + 1, and
    /// past it, at the ends and on NaN, the same after `min(SUBSTEPS_MAX)` and `≤ 1`.
    #[test]
    fn the_sub_step_count_is_the_ceiling_where_it_is_read() {
        let used = |n: usize| (n <= 1, n.min(SUBSTEPS_MAX));
        let mut xs = vec![
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -0.0,
            0.0,
            -3.5,
            f64::MIN_POSITIVE,
            1e-300,
            1e300,
            (SUBSTEPS_MAX + 1) as f64,
            (SUBSTEPS_MAX + 1) as f64 + 1e-9,
        ];
        for i in 0..=4 * SUBSTEPS_MAX {
            let x = i as f64 * 0.25;
            xs.extend([x, x.next_up(), x.next_down()]);
        }
        for x in xs {
            assert_eq!(used(ceil_count(x)), used(x.ceil() as usize), "x = {x:e}");
        }
        for i in 0..=SUBSTEPS_MAX {
            let x = i as f64 + 0.5;
            assert_eq!(ceil_count(x), x.ceil() as usize, "x = {x}");
        }
    }

    /// The lattice's event search is skipped only where it could find nothing: wherever the
    /// bound's two edges have the same engaged count, so have the eight Hermite points the
    /// search looks at, over pieces of every kind (free, pressed, crossing, turning).
    #[test]
    fn the_lattice_search_is_skipped_only_where_the_hermite_points_agree() {
        let r = 300.0;
        let geo = BedGeometry::new(
            Bed::Lattice {
                pitch_nm: 100.0,
                offset: [0.25, 0.0],
            },
            r,
        );
        let h = 0.0;
        let mut rng = crate::plant::rng::Xoshiro256pp::new(7);
        let (mut skipped, mut searched) = (0, 0);
        for _ in 0..20_000 {
            // Depths from −50 to 250 nm, velocities up to 40 nm per sample, τ up to 2 µs.
            let z0 = -250.0 + 300.0 * rng.next_open01();
            let z1 = z0 + 40.0 * (2.0 * rng.next_open01() - 1.0);
            let tau = 0.05 + 2.0 * rng.next_open01();
            let v0 = 20.0 * (2.0 * rng.next_open01() - 1.0) / tau;
            let v1 = 20.0 * (2.0 * rng.next_open01() - 1.0) / tau;
            let n0 = geo.engaged(h - z0);
            let swing = 4.0 / 27.0 * tau * (v0.abs() + v1.abs());
            let margin = 1e-12 * (z0.abs() + z1.abs() + swing) + 1e-300;
            let (z_lo, z_hi) = (z0.min(z1) - swing - margin, z0.max(z1) + swing + margin);
            if geo.engaged(h - z_hi) == n0 && geo.engaged(h - z_lo) == n0 {
                skipped += 1;
                for j in 1..=8 {
                    let zq = hermite(z0, v0, z1, v1, tau, j as f64 / 8.0);
                    assert_eq!(
                        geo.engaged(h - zq),
                        n0,
                        "{z0} {v0} {z1} {v1} {tau} at {j}/8"
                    );
                }
            } else {
                searched += 1;
            }
        }
        // Both branches are exercised.
        assert!(
            skipped > 1000 && searched > 1000,
            "{skipped} skipped, {searched} searched"
        );
    }
}
