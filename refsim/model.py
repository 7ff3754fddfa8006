"""The reference simulator's physics, written from ``shared/spec/method.md`` (plant) and
``shared/spec/recording.md`` (the ten effects), sharing no code with ``host-sim``.

Formulation: an exponential integrator. Over each step the right-hand side is linearised at
the step's start (Jacobian by finite differences; exact for the cantilever, the discrete
element bed with its active set frozen, and every linear effect), the linear part is
integrated exactly with a matrix exponential, the input (U, dU/dt) enters as a cubic in time,
and what the linearisation leaves out (continuum contact, nonlinear effects) is added back by
one corrector pass as a quadratic in time. A discrete element entering or leaving contact is
an event: the step is cut where the apex crosses its engagement height (located on the
step's cubic Hermite path and re-integrated exactly up to it), so a Kelvin-Voigt element's
damper switches on at the right instant. Stiff contact damping (c/M ~ 1e6 1/s) is therefore
no stability issue (method.md's warning).

Sign convention (method.md): z up, D = U - Z, D < 0 when the sample pushes the tip up; a
repulsive tip-sample force is positive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

# ---------------------------------------------------------------------------------------
# Instrument and sample
# ---------------------------------------------------------------------------------------


@dataclass
class Cantilever:
    """First flexural mode: K (N/m), f0 (Hz), Q."""

    k: float
    f0: float
    q: float

    @property
    def m(self) -> float:
        return self.k / (2.0 * math.pi * self.f0) ** 2

    @property
    def c(self) -> float:
        return math.sqrt(self.k * self.m) / self.q


def cap_volume(r: float, d: float) -> float:
    """Volume between a plane and a sphere of radius r sunk d into it, inside r (m^3)."""
    if d <= 0.0:
        return 0.0
    if d <= r:
        return math.pi * d * d * (r - d / 3.0)
    return math.pi * r * r * d - 2.0 / 3.0 * math.pi * r**3


def cap_area(r: float, d: float) -> float:
    """Cross-section of that cap (m^2): d(volume)/dd."""
    if d <= 0.0:
        return 0.0
    if d <= r:
        return math.pi * (2.0 * r * d - d * d)
    return math.pi * r * r


@dataclass
class DiscreteBed:
    """The paper's bed: a square lattice of Kelvin-Voigt elements (pitch, per-element k, c),
    flat at height 0, with the tip's axis at `offset` (fractions of a pitch) in the cell.
    Only elements with r_i < R can touch (method.md (7))."""

    pitch: float
    k_el: float
    c_el: float
    offset: tuple[float, float] = (0.0, 0.0)

    def engagement(self, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per element under the tip: the apex height Z at which it starts to be
        indented (e_i = h_i - (R - sqrt(R^2 - r_i^2))), its k and its c."""
        n = int(math.ceil(radius / self.pitch)) + 2
        ix = np.arange(-n, n + 1)
        gx, gy = np.meshgrid(ix, ix)
        x = (gx.ravel() - self.offset[0]) * self.pitch
        y = (gy.ravel() - self.offset[1]) * self.pitch
        r2 = x * x + y * y
        under = r2 < radius * radius
        e = -(radius - np.sqrt(radius * radius - r2[under]))
        k = np.full(e.shape, self.k_el)
        c = np.full(e.shape, self.c_el)
        return e, k, c


@dataclass
class ContinuumBed:
    """The element bed's continuum limit: per-area spring k_a (N/m^3) and damper c_a
    (N s/m^3); the force is k_a times the indented volume plus c_a times the contact
    cross-section times the indentation rate."""

    k_a: float
    c_a: float


# ---------------------------------------------------------------------------------------
# Effects: each from recording.md's one-line description, in this simulator's own form.
# ---------------------------------------------------------------------------------------

EFFECTS = (
    "nonlinear-stiffness",
    "adhesion",
    "surface-attraction",
    "stress-relaxation",
    "hydrodynamic-drag",
    "baseline-tilt",
    "thermal-drift",
    "second-eigenmode",
    "piezo-creep",
    "plastic-deformation",
)


@dataclass
class Effect:
    """One effect: its identifier, the amplitude the calibration scales and its shape.

    Forms (why these: each is a textbook form of the physics named, chosen to differ from
    the project's plant so that a diagnosis tuned to one form is caught):
      nonlinear-stiffness  elastic contact force times (1 + a * delta / depth_ref)
                           (strain stiffening, or softening for a < 0)
      adhesion             bonds form over the first `onset` of indentation, hold an
                           attractive force a while in contact and pull with a force falling
                           linearly to 0 over `reach` below the surface before they break
      surface-attraction   van der Waals sphere-plane form -a * (l / (gap + l))^2, -a in
                           contact
      stress-relaxation    a Maxwell arm in parallel: dF_m/dt = a * dF_el/dt - F_m / tau,
                           on the tip while the bed touches it
      hydrodynamic-drag    -a * ((1 - w) dZ/dt + w dU/dt): the lever body moves between
                           tip and base
      baseline-tilt        measured D gains a * (U - U_ref) (optical crosstalk)
      thermal-drift        measured D gains a * (t + b t^2 / T)
      second-eigenmode     a second oscillator (f2 near 6.27 f0, Q2) driven by the tip
                           force and the base velocity, added to the measured D
      piezo-creep          the real base lags: U_a = (1 - a) U + a (U_1 + U_2) / 2 with
                           first-order lags U_1, U_2 of time constants tau and 5 tau
      plastic-deformation  the surface under each element (or the apex, on a continuum)
                           sinks by a times the deepest indentation so far
    """

    kind: str
    amplitude: float
    shape: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# The simulation
# ---------------------------------------------------------------------------------------


class Model:
    """The plant with its bed and at most one effect; `simulate` runs it."""

    def __init__(self, lever: Cantilever, radius: float, bed, effect: Effect | None = None):
        self.lever = lever
        self.radius = radius
        self.bed = bed
        self.effect = effect
        self.kind = effect.kind if effect is not None else None
        self.discrete = isinstance(bed, DiscreteBed)
        if self.discrete:
            self.e0, self.k_el, self.c_el = bed.engagement(radius)
            self.e = self.e0.copy()
            self.dmax = np.zeros_like(self.e0)
        else:
            # The continuum's one event: the apex reaching the (possibly sunk) surface,
            # where the contact force's curvature and damping start.
            self.e0 = np.array([0.0])
            self.e = self.e0.copy()
        self.p_cont = 0.0  # continuum plastic set (m)
        self.dmax_cont = 0.0
        self.bonded = False
        # State layout: Z, dZ/dt, then the effect's states.
        names = ["z", "v"]
        if self.kind == "second-eigenmode":
            names += ["q2", "q2d"]
        if self.kind == "stress-relaxation":
            names += ["fm"]
        if self.kind == "piezo-creep":
            names += ["l1", "l2"]
        self.names = names
        self.n = len(names)
        self.ix = {s: i for i, s in enumerate(names)}
        # Perturbation scale of each state for the finite-difference Jacobian.
        scale = {"z": 1e-9, "v": 1e-5, "q2": 1e-9, "q2d": 1e-5, "fm": 1e-12, "l1": 1e-9, "l2": 1e-9}
        self.fd = np.array([scale[s] for s in names])
        self._phi_cache: dict = {}
        self._bed_cache: dict = {}
        self._gains = None

    # ----- the contact ------------------------------------------------------------------
    def active(self, z: float) -> np.ndarray:
        """Elements indented at apex height z (method.md (7))."""
        return self.e > z

    def bed_force(self, z: float, v: float, mask) -> tuple[float, float, float]:
        """(elastic force, damping force, d(elastic)/dz) of the bed, N and N/m."""
        if self.discrete:
            key = mask.tobytes()
            sums = self._bed_cache.get(key)
            if sums is None:
                k = self.k_el[mask]
                sums = (float(np.sum(k)), float(np.sum(k * self.e[mask])),
                        float(np.sum(self.c_el[mask])))
                self._bed_cache[key] = sums
            ks, kes, cs = sums
            return kes - ks * z, -cs * v, -ks
        d = -z  # surface at 0
        r = self.radius
        b = self.bed
        if d <= self.p_cont:
            return 0.0, 0.0, 0.0
        fe = b.k_a * (cap_volume(r, d) - cap_volume(r, self.p_cont))
        a = cap_area(r, d)
        return fe, -b.c_a * a * v, -b.k_a * a

    # ----- the right-hand side ------------------------------------------------------------
    def base(self, x, u, ud):
        """The real base position and velocity (piezo creep), m and m/s."""
        if self.kind == "piezo-creep":
            a = self.effect.amplitude
            tau = self.effect.shape["tau_s"]
            l1, l2 = x[self.ix["l1"]], x[self.ix["l2"]]
            ua = (1 - a) * u + a * 0.5 * (l1 + l2)
            uad = (1 - a) * ud + a * 0.5 * ((u - l1) / tau + (u - l2) / (5 * tau))
            return ua, uad
        return u, ud

    def tip_force(self, x, mask) -> tuple[float, float]:
        """Tip-sample force (N) and its elastic part's slope (N/m)."""
        z, v = x[0], x[1]
        fe, fd, slope = self.bed_force(z, v, mask)
        kind = self.kind
        eff = self.effect
        delta = -z  # apex indentation of the flat surface at 0
        if kind == "nonlinear-stiffness" and fe != 0.0:
            ref = eff.shape["depth_ref_m"]
            g = 1.0 + eff.amplitude * max(delta, 0.0) / ref
            slope = slope * g - fe * eff.amplitude / ref * (1.0 if delta > 0 else 0.0)
            fe *= g
        f = fe + fd
        if kind == "stress-relaxation":
            # The arm acts through the contact: once the tip has left the bed no sample
            # force reaches it, and the arm relaxes on its own (its rate has no slope then).
            if mask.any():
                f += x[self.ix["fm"]]
        elif kind == "adhesion":
            a, onset, reach = eff.amplitude, eff.shape["onset_m"], eff.shape["reach_m"]
            if delta > 0.0:
                f -= a if self.bonded else a * min(1.0, delta / onset)
            elif self.bonded and delta > -reach:
                f -= a * (1.0 + delta / reach)
        elif kind == "surface-attraction":
            a, l = eff.amplitude, eff.shape["length_m"]
            gap = max(-delta, 0.0)
            f -= a * (l / (gap + l)) ** 2
        return f, slope

    def rhs(self, t, x, mask, u, ud) -> np.ndarray:
        lv = self.lever
        ua, uad = self.base(x, u, ud)
        z, v = x[0], x[1]
        fts, slope = self.tip_force(x, mask)
        dx = np.empty(self.n)
        dx[0] = v
        f_lever = lv.k * (ua - z) + lv.c * (uad - v) + fts
        if self.kind == "hydrodynamic-drag":
            w = self.effect.shape["base_weight"]
            f_lever -= self.effect.amplitude * ((1 - w) * v + w * uad)
        dx[1] = f_lever / lv.m
        if self.kind == "second-eigenmode":
            s = self.effect.shape
            w2 = 2 * math.pi * s["f2_hz"]
            i = self.ix["q2"]
            q2, q2d = x[i], x[i + 1]
            drive = w2 * w2 * s["force_gain"] * fts / lv.k + w2 * s["base_gain"] * uad
            dx[i] = q2d
            dx[i + 1] = -w2 / s["q2"] * q2d - w2 * w2 * q2 + self.effect.amplitude * drive
        if self.kind == "stress-relaxation":
            i = self.ix["fm"]
            dx[i] = self.effect.amplitude * slope * v - x[i] / self.effect.shape["tau_s"]
        if self.kind == "piezo-creep":
            tau = self.effect.shape["tau_s"]
            dx[self.ix["l1"]] = (u - x[self.ix["l1"]]) / tau
            dx[self.ix["l2"]] = (u - x[self.ix["l2"]]) / (5 * tau)
        return dx

    def input_gains(self):
        """d(rhs)/dU and d(rhs)/d(dU/dt): constant, the plant being linear in its base."""
        if self._gains is None:
            x = np.zeros(self.n)
            mask = np.zeros(len(self.e), bool)
            x[0] = 1.0  # far above any sample
            f = self.rhs(0.0, x, mask, 0.0, 0.0)
            self._gains = (self.rhs(0.0, x, mask, 1.0, 0.0) - f,
                           self.rhs(0.0, x, mask, 0.0, 1.0) - f)
        return self._gains

    def measured(self, t, x, u) -> float:
        """Noise-free measured deflection (m)."""
        ua, _ = self.base(x, u, 0.0)
        d = ua - x[0]
        eff = self.effect
        if self.kind == "second-eigenmode":
            d += x[self.ix["q2"]]
        elif self.kind == "baseline-tilt":
            d += eff.amplitude * (u - eff.shape["u_ref_m"])
        elif self.kind == "thermal-drift":
            d += eff.amplitude * (t + eff.shape["curvature"] * t * t / eff.shape["span_s"])
        return d

    def after_step(self, x):
        """History the step leaves behind (bonds, plastic set): updated between steps."""
        z = x[0]
        if self.kind == "adhesion":
            delta = -z
            if delta >= self.effect.shape["onset_m"]:
                self.bonded = True
            elif delta <= -self.effect.shape["reach_m"]:
                self.bonded = False
        if self.kind == "plastic-deformation":
            a = self.effect.amplitude
            if self.discrete:
                self.dmax = np.maximum(self.dmax, self.e0 - z)
                e = self.e0 - a * np.maximum(self.dmax, 0.0)
                if not np.array_equal(e, self.e):
                    self.e = e
                    self._bed_cache.clear()
            else:
                self.dmax_cont = max(self.dmax_cont, -z)
                self.p_cont = a * self.dmax_cont
                self.e = np.array([-self.p_cont])

    # ----- one step ---------------------------------------------------------------------
    def jacobian(self, t, x, mask, u, ud, f0):
        j = np.empty((self.n, self.n))
        for i in range(self.n):
            xp = x.copy()
            xp[i] += self.fd[i]
            j[:, i] = (self.rhs(t, xp, mask, u, ud) - f0) / self.fd[i]
        return j

    def phis(self, jac, h) -> np.ndarray:
        """[phi_1 .. phi_4](hJ) side by side (n x 4n), from one exponential of the block
        matrix [[hJ, I, 0, 0, 0], [0, 0, I, 0, 0], ..., 0] (Sidje's construction).
        Cached on J rounded to 30 bits of mantissa (the rounded J is the one used), so a
        discrete bed's few active sets cost one exponential each."""
        m, e = np.frexp(jac)
        mq = np.round(m * 2.0**30)
        key = (mq.tobytes(), e.tobytes(), float(h))
        got = self._phi_cache.get(key)
        if got is not None:
            return got
        jq = np.ldexp(mq / 2.0**30, e)
        n = self.n
        big = np.zeros((5 * n, 5 * n))
        big[:n, :n] = jq * h
        for j in range(4):
            big[j * n:(j + 1) * n, (j + 1) * n:(j + 2) * n] = np.eye(n)
        out = expm(big)[:n, n:]
        if len(self._phi_cache) > 20000:
            self._phi_cache.clear()
        self._phi_cache[key] = out
        return out

    def propagate(self, phi, coef, h) -> np.ndarray:
        """Exact y(h) of y' = J y + sum_j coef[j] s^j, y(0) = 0:
        sum_j coef[j] j! h^(j+1) phi_(j+1)(hJ)."""
        n = self.n
        y = np.zeros(n)
        fact = 1.0
        for j, cj in enumerate(coef):
            if j > 0:
                fact *= j
            y += phi[:, j * n:(j + 1) * n] @ cj * (fact * h ** (j + 1))
        return y


def cubic_coefficients(values: np.ndarray, h: float) -> list[np.ndarray]:
    """Coefficients c0..c3 of the cubic through values at s = 0, h/3, 2h/3, h."""
    s = np.array([0.0, h / 3, 2 * h / 3, h])
    v = np.vander(s, 4, increasing=True)
    c = np.linalg.solve(v, values)
    return [c[j] for j in range(4)]


def hermite(z0, v0, z1, v1, h, s):
    """Cubic Hermite path between two states (z, dz/dt) at s in [0, h]."""
    t = s / h
    h00 = 2 * t**3 - 3 * t**2 + 1
    h10 = t**3 - 2 * t**2 + t
    h01 = -2 * t**3 + 3 * t**2
    h11 = t**3 - t**2
    return h00 * z0 + h10 * h * v0 + h01 * z1 + h11 * h * v1


@dataclass
class Drive:
    """The command U(t), m, with its derivative, and how it reaches the piezo: a smooth
    command (`dac_lsb` None) or a DAC staircase updated at `dac_period` and quantised to
    `dac_lsb`."""

    u: object  # callable t -> U
    ud: object  # callable t -> dU/dt
    dac_period: float | None = None
    dac_lsb: float | None = None

    def dac_value(self, t: float) -> float:
        k = math.floor(t / self.dac_period + 1e-9)
        v = self.u(k * self.dac_period)
        if self.dac_lsb:
            v = round(v / self.dac_lsb) * self.dac_lsb
        return v


def steady_state(model: Model, t0: float, u_dc: float, tones) -> np.ndarray:
    """State at t0 of the free, linearised plant after the command u_dc + sum of tones
    (a_k, f_k, phase_k) has run forever: the excitation runs long before the recording."""
    n = model.n
    x = np.zeros(n)
    x[0] = u_dc
    for s in ("l1", "l2"):
        if s in model.ix:
            x[model.ix[s]] = u_dc
    mask = model.active(x[0])
    for _ in range(3):  # Newton on f(x) = 0 for the constant command
        f = model.rhs(0.0, x, mask, u_dc, 0.0)
        j = model.jacobian(0.0, x, mask, u_dc, 0.0, f)
        x = x - np.linalg.solve(j, f)
    f = model.rhs(0.0, x, mask, u_dc, 0.0)
    j = model.jacobian(0.0, x, mask, u_dc, 0.0, f)
    du = 1e-9
    bu = (model.rhs(0.0, x, mask, u_dc + du, 0.0) - f) / du
    bud = (model.rhs(0.0, x, mask, u_dc, du) - f) / du
    out = x.copy()
    for a, fr, ph in tones:
        w = 2 * math.pi * fr
        # U = a sin(w t + ph) = Im(a e^{i(w t + ph)})
        xc = np.linalg.solve(1j * w * np.eye(n) - j, (bu + 1j * w * bud) * a)
        out += np.imag(xc * np.exp(1j * (w * t0 + ph)))
    return out


def simulate(model: Model, drive: Drive, t_start: float, t_samples: np.ndarray, h_max: float,
             x0: np.ndarray) -> np.ndarray:
    """Runs from t_start (state x0) and returns the noise-free measured D at t_samples (m).

    Steps never straddle a sample instant or a DAC update; a DAC update changes U in a jump,
    whose dU/dt impulse kicks the states exactly (x += (df/d(dU/dt)) * jump)."""
    x = x0.copy()
    t = t_start
    out = np.empty(len(t_samples))
    mask = model.active(x[0])
    staircase = drive.dac_period is not None
    u_held = drive.dac_value(t) if staircase else None
    next_dac = (math.floor(t / drive.dac_period + 1e-9) + 1) * drive.dac_period if staircase else math.inf
    k = 0
    while k < len(t_samples):
        target = min(t_samples[k], next_dac)
        if target - t <= 1e-15:
            if staircase and abs(t - next_dac) <= 1e-12:
                new = drive.dac_value(next_dac + 1e-12)
                jump = new - u_held
                if jump != 0.0:
                    f0 = model.rhs(t, x, mask, u_held, 0.0)
                    b = (model.rhs(t, x, mask, u_held, 1.0) - f0)
                    # An impulse in dU/dt of area `jump` (the base's velocity term) ...
                    x = x + b * jump
                u_held = new
                next_dac += drive.dac_period
            if k < len(t_samples) and abs(t - t_samples[k]) <= 1e-12:
                u_now = u_held if staircase else drive.u(t)
                out[k] = model.measured(t, x, u_now)
                k += 1
            continue
        h = min(h_max, target - t)
        if target - (t + h) < 1e-3 * h_max:
            h = target - t
        x, t, mask = step(model, drive, x, t, h, mask, u_held)
    return out


_NODES = np.array([0.0, 1 / 3, 2 / 3, 1.0])
# The continuum corrector's last change of Z allowed in a step (m): a thousandth of the
# smallest noise the scenarios draw (0.05 nm).
_CORRECTOR_TOL_M = 5e-14
_EVENT_SAMPLES = np.linspace(0.0, 1.0, 17)[1:]


def _inputs(drive, t, u_held):
    if u_held is not None:
        return u_held, 0.0
    return drive.u(t), drive.ud(t)


def step(model: Model, drive: Drive, x, t, h, mask, u_held):
    """One step of at most h; shorter if a discrete element enters or leaves contact."""
    u0, ud0 = _inputs(drive, t, u_held)
    f0 = model.rhs(t, x, mask, u0, ud0)
    jac = model.jacobian(t, x, mask, u0, ud0, f0)

    def run(hh):
        phi = model.phis(jac, hh)
        if u_held is not None:
            coef = [f0]
        else:
            # f is linear in (U, dU/dt) with constant gains: only the command's cubic is
            # needed.
            ss = _NODES * hh
            us = np.array([drive.u(t + s) for s in ss]) - u0
            uds = np.array([drive.ud(t + s) for s in ss]) - ud0
            cu = np.linalg.solve(np.vander(ss, 4, increasing=True), np.stack([us, uds], 1))
            bu, bud = model.input_gains()
            coef = [f0 + bu * cu[0, 0] + bud * cu[0, 1]] + [
                bu * cu[j, 0] + bud * cu[j, 1] for j in range(1, 4)
            ]
        y = model.propagate(phi, coef, hh)
        x1 = x + y
        # Corrector: what the linearisation misses. It vanishes at s = 0 with its slope
        # (J is the Jacobian there), so a quadratic through its value at h, or on the
        # continuum (curved all along the contact) a quadratic + cubic through its values
        # at h/2 and h, iterated twice.
        resid = model.rhs(t + hh, x1, mask, u0, ud0) - f0 - jac @ y
        if np.max(np.abs(resid)) == 0.0:
            return x1
        base = list(coef) + [np.zeros(model.n)] * (4 - len(coef))
        if model.discrete:
            coef = list(base)
            coef[2] = coef[2] + resid / (hh * hh)
            return x + model.propagate(phi, coef, hh)
        phi_half = model.phis(jac, hh / 2)
        coef = list(base)
        y_prev = None
        for _ in range(2):
            yh = model.propagate(phi_half, coef, hh / 2)
            rh = model.rhs(t + hh / 2, x + yh, mask, u0, ud0) - f0 - jac @ yh
            # N(s) = a s^2 + b s^3 through (h/2, rh) and (h, resid).
            m = np.array([[(hh / 2) ** 2, (hh / 2) ** 3], [hh**2, hh**3]])
            ab = np.linalg.solve(m, np.stack([rh, resid]))
            coef = list(base)
            coef[2] = coef[2] + ab[0]
            coef[3] = coef[3] + ab[1]
            y_prev, y = y, model.propagate(phi, coef, hh)
            resid = model.rhs(t + hh, x + y, mask, u0, ud0) - f0 - jac @ y
        # The corrector is a fixed point: where the contact's stiffness or damping changes
        # by far more over the step than the linearisation at its start holds (a stiff bed
        # met within a long quasi-static step), it does not settle, and the step is halved.
        if y_prev is not None and not (abs(y[0] - y_prev[0]) <= _CORRECTOR_TOL_M):
            return None
        return x + y

    def settle(hh, x1):
        """(x1, hh) if x1 = run(hh) settled, else the first halving of hh that does (a step
        of hh/2**40 is below any recording's need)."""
        for _ in range(40):
            if x1 is not None and np.all(np.isfinite(x1)):
                return x1, hh
            hh = 0.5 * hh
            x1 = run(hh)
        raise FloatingPointError(f"refsim: the step at t = {t:.9g} s does not settle")

    x1, h = settle(h, run(h))
    if True:
        ss = _EVENT_SAMPLES * h
        zs = hermite(x[0], x[1], x1[0], x1[1], h, ss)
        changed = list(np.any((zs[:, None] < model.e[None, :]) != mask[None, :], axis=1))
        if any(changed):
            j = changed.index(True)
            lo, hi = (ss[j - 1] if j > 0 else 0.0), ss[j]
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                if np.array_equal(model.active(hermite(x[0], x[1], x1[0], x1[1], h, mid)), mask):
                    lo = mid
                else:
                    hi = mid
            # Past the crossing on the path: the new active set (the bracket's far side).
            new_mask = model.active(hermite(x[0], x[1], x1[0], x1[1], h, hi))
            if hi < h * (1 - 1e-9):
                x1, h = settle(hi, run(hi))
                if h < hi:
                    # Short of the crossing, in the present active set; the next step
                    # finds the event again.
                    model.after_step(x1)
                    return x1, t + h, mask
            model.after_step(x1)
            return x1, t + h, new_mask
    model.after_step(x1)
    new_mask = model.active(x1[0])
    return x1, t + h, new_mask
