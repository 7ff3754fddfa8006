"""The reference simulator against closed forms, before it is trusted as an oracle.

Tolerances: the integrator is exact for linear dynamics (matrix exponential), so the free
ring-down and the static bend are held to ~1e-6 of their amplitude (rounding of the cached
Jacobian, 2^-30); the force law to the paper's own reading of its Fig. 9.
"""

import math

import numpy as np

from refsim.model import (Cantilever, ContinuumBed, DiscreteBed, Drive, Model, cap_volume,
                          simulate, steady_state)
from refsim.scenario import draw_setup, run

PAPER = Cantilever(0.18, 20e3, 100.0)


def test_free_ring_down_decays_and_rings_as_the_damped_oscillator():
    # Tip released 50 nm from rest, far above the sample: Z(t) = A e^{-zeta w0 t}
    # (cos wd t + zeta w0 / wd sin wd t).
    m = Model(PAPER, 300e-9, DiscreteBed(100e-9, 3e-3, 6e-7, (0.3, 0.2)))
    u = 1e-6
    x0 = np.array([u + 50e-9, 0.0])
    ts = np.arange(1, 801) * 2e-6
    d = simulate(m, Drive(lambda t: u, lambda t: 0.0), 0.0, ts, 2e-6, x0)
    w0 = 2 * math.pi * PAPER.f0
    z = 1 / (2 * PAPER.q)
    wd = w0 * math.sqrt(1 - z * z)
    want = 50e-9 * np.exp(-z * w0 * ts) * (np.cos(wd * ts) + z * w0 / wd * np.sin(wd * ts))
    assert np.max(np.abs(-d - want)) < 50e-9 * 1e-6


def test_steady_state_of_a_tone_is_the_transfer_function():
    # Started in the periodic steady state, the free lever's deflection stays a sinusoid of
    # amplitude |1 - (K + iwC)/(K - Mw^2 + iwC)| a from the first sample (no ring-up).
    m = Model(PAPER, 300e-9, ContinuumBed(3e11, 6e7))
    a, f = 2e-9, 0.9 * PAPER.f0
    w = 2 * math.pi * f
    g = 1 - (PAPER.k + 1j * w * PAPER.c) / (PAPER.k - PAPER.m * w * w + 1j * w * PAPER.c)
    x0 = steady_state(m, 0.0, 1e-6, [(a, f, 0.0)])
    ts = np.arange(1, 401) * 1e-6
    d = simulate(m, Drive(lambda t: 1e-6 + a * math.sin(w * t),
                          lambda t: a * w * math.cos(w * t)), 0.0, ts, 1e-6, x0)
    want = np.imag(g * a * np.exp(1j * w * ts))
    assert np.max(np.abs(d - want)) < abs(g) * a * 1e-4


def test_static_bend_under_the_bed_force():
    # Base held below the surface: at rest K (U - Z) + sum_{e_i > Z} k_i (e_i - Z) = 0,
    # D = U - Z = -F/K. Solved in closed form over the active set, then simulated.
    bed = DiscreteBed(100e-9, 4e-3, 6e-7, (0.25, 0.5))
    m = Model(PAPER, 300e-9, bed)
    e, k, _ = bed.engagement(300e-9)
    u = -200e-9
    z = u
    for _ in range(50):  # fixed point over the active set
        act = e > z
        z = (PAPER.k * u + np.sum(k[act] * e[act])) / (PAPER.k + np.sum(k[act]))
    d_want = u - z
    x0 = np.array([z + 5e-9, 0.0])
    ts = np.array([5e-3])
    d = simulate(m, Drive(lambda t: u, lambda t: 0.0), 0.0, ts, 2e-6, x0)
    assert abs(d[0] - d_want) < 1e-4 * abs(d_want), (d[0], d_want)
    assert d_want < 0  # the sample pushes the tip up


def test_fig9_force_law_of_the_paper_bed():
    # The paper's bed (100 nm pitch, R = 300 nm, k_i = 5e-3 N/m, its k_max) indented
    # quasi-statically: Fig. 9 reads F ~ 1.6e-3 delta^1.72 (nN, nm), ~15 nN at 200 nm.
    # Averaged over the lattice's offset under the tip; the force from the simulated D.
    depths = np.linspace(20e-9, 200e-9, 10)
    forces = np.zeros_like(depths)
    offsets = [(0.0, 0.0), (0.5, 0.5), (0.5, 0.0), (0.25, 0.75)]
    for off in offsets:
        bed = DiscreteBed(100e-9, 5e-3, 6e-7, off)
        m = Model(PAPER, 300e-9, bed)
        # Quasi-static: the base ramps down at 20 um/s with the lever at rest; the force is
        # -K D when the apex passes each depth.
        v = 20e-6
        t_end = 400e-9 / v  # past 200 nm of depth plus the bend F/K
        u = lambda t: 50e-9 - v * t  # noqa: E731
        ts = np.linspace(0, t_end, 400)[1:]
        d = simulate(m, Drive(u, lambda t: -v), 0.0, ts, 20e-6, np.array([50e-9, -v]))
        z = np.array([u(t) for t in ts]) - d
        f = -PAPER.k * d
        assert -z[-1] > depths[-1]
        forces += np.interp(depths, -z, f) / len(offsets)
    slope, icpt = np.polyfit(np.log(depths * 1e9), np.log(forces * 1e9), 1)
    assert abs(slope - 1.72) < 0.12, slope
    f200 = forces[-1] * 1e9
    assert 12.0 < f200 < 18.0, f200
    # And the continuum limit of the same bed gives the same law within the lattice's
    # granularity (k_a = k_i / pitch^2).
    cont = 5e-3 / (100e-9) ** 2 * cap_volume(300e-9, 200e-9) * 1e9
    assert abs(cont - f200) < 0.25 * f200, (cont, f200)



def test_a_stiff_continuum_met_in_long_steps_settles_at_the_static_balance():
    # The recording that once came out NaN from its 107th sample (clean seed 2 of the full
    # set: K 0.053 N/m, f0 41 kHz, R 720 nm on a continuum, a DAC staircase at 1 kHz, 80 us
    # steps, three of the lever's periods): at the touch the contact's stiffness and damping
    # grow by far more within a step than its start's linearisation holds, the corrector's
    # fixed point ran away, and the run grew 10^90 per sample. The step is now halved until
    # the corrector settles. Closed form at the hold's end (the bed's Kelvin-Voigt time
    # c_a/k_a is 0.2 ms, the hold far longer): K (U - Z) + k_a V(-Z) = 0, D = U - Z.
    rng = np.random.default_rng([2, 0, 0x5EF])
    tap = bool(rng.uniform() < 0.5)
    setup = draw_setup(rng, tap, False)
    assert not tap and isinstance(setup.bed, ContinuumBed), "the draw changed: not the case"
    ts, um, d = run(setup, None)
    assert np.all(np.isfinite(d))
    k = np.searchsorted(ts, setup.times()[2]) - 1  # the hold's last sample
    u_end, lever, r, k_a = um[k], setup.lever, setup.radius, setup.bed.k_a
    lo, hi = u_end, 0.0  # the tip sits between the base and the surface
    for _ in range(200):
        z = 0.5 * (lo + hi)
        if lever.k * (u_end - z) + k_a * cap_volume(r, -z) > 0:  # the bed pushes harder
            lo = z
        else:
            hi = z
    d_want = u_end - 0.5 * (lo + hi)
    assert d_want < -10e-9  # pressed: the bed pushes the tip up by more than 10 nm
    assert abs(d[k] - d_want) < 1e-3 * abs(d_want), (d[k], d_want)
