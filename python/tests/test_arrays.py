"""Recording.from_arrays, writing, simulate, the GIL and Ctrl-C."""

from __future__ import annotations

import math
import signal
import threading
import time
import warnings

import numpy as np
import pytest

import visco
from conftest import SPOT3, SR, import_options, read_csv
from test_reports import same


def spot3(real):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return visco.read(real / SPOT3, **import_options(SPOT3))


def test_from_arrays_gives_the_same_report_as_the_file(real):
    """Data that came from elsewhere (here: the arrays of an imported curve, as afmformats
    would give them) identify exactly as the recording they came from."""
    rec = spot3(real)
    m = rec.metadata
    again = visco.Recording.from_arrays(
        rec.t, rec.u, rec.d,
        mode="force-curve",
        spring_constant=m["cantilever_k_n_per_m"],
        tip_radius=m["tip_radius_m"],
        sample_rate=m["sample_rate_hz"],
        extra=rec.extras,
        metadata={"segments": m["segments"]},
        source="from-afmformats",
    )
    a = visco.identify(rec)
    b = visco.identify(again)
    # The whole report, number for number (the metadata it echoes is the same, less the
    # vendor's pass-through keys, which the report does not read).
    for key in ("k_a_n_per_m3", "c_a_ns_per_m3", "contact", "rms_misfit_m", "taps", "fit"):
        assert key in a
    same({k: a[k] for k in a if k != "fit"}, {k: b[k] for k in b if k != "fit"})
    assert b["recording"] == "from-afmformats"


def test_from_arrays_infers_the_rate():
    t = np.arange(100) / 2000.0
    rec = visco.Recording.from_arrays(
        t, -1e-6 * t, np.zeros(100), spring_constant=0.1, tip_radius=5e-6
    )
    assert rec.metadata["sample_rate_hz"] == pytest.approx(2000.0, rel=1e-12)
    assert rec.units()["d_m"] == "m"


def test_from_arrays_refuses_like_the_reader():
    """The contract's refusals, naming the source and the CSV line the row would be on."""
    t = np.array([0.0, 1e-3, 1e-3, 3e-3])
    with pytest.raises(visco.ViscoError) as e:
        visco.Recording.from_arrays(
            t, np.zeros(4), np.zeros(4), spring_constant=0.1, tip_radius=5e-6,
            sample_rate=1000.0, source="my-arrays",
        )
    assert e.value.file == "my-arrays"
    assert e.value.line is not None and e.value.line > 3
    assert "increase" in str(e.value)
    with pytest.raises(visco.ViscoError, match="tip_radius_m"):
        visco.Recording.from_arrays(
            np.arange(4) * 1e-3, np.zeros(4), np.zeros(4), spring_constant=0.1,
            tip_radius=-1.0, sample_rate=1000.0,
        )
    with pytest.raises(ValueError, match="shape"):
        visco.Recording.from_arrays(
            np.arange(4) * 1e-3, np.zeros(3), np.zeros(4), spring_constant=0.1,
            tip_radius=5e-6, sample_rate=1000.0,
        )
    with pytest.raises(visco.ViscoError, match="not a finite number"):
        visco.Recording.from_arrays(
            np.arange(4) * 1e-3, np.zeros(4), np.array([0, np.nan, 0, 0]),
            spring_constant=0.1, tip_radius=5e-6, sample_rate=1000.0,
        )


def test_write_round_trips_bit_for_bit(real, tmp_path):
    rec = spot3(real)
    path = tmp_path / "spot3.csv"
    rec.write(path)
    back = visco.read(path)
    assert list(back.columns) == list(rec.columns)
    for k in rec.columns:
        assert np.array_equal(back.columns[k], rec.columns[k], equal_nan=True), k
    assert back.metadata == rec.metadata
    # And an independent reader sees the same numbers.
    _, cols = read_csv(path)
    assert np.array_equal(np.array(cols["d_m"]), rec.d)


@pytest.mark.parametrize("setup", ["curve-colloid", "tap-air"])
def test_simulate_effect_by_name(setup):
    clean = visco.simulate(setup, [], seed=3)
    sim = visco.simulate(setup, ["adhesion"], magnitude=6.0, seed=3)
    rec = sim.recording
    assert rec.mode == ("dive" if visco.SETUPS[setup][0] else "force-curve")
    assert len(rec) == len(sim.truth_d_m) == len(sim.clean_d_m)
    # The same instrument, protocol and noise draw: only the effect differs.
    assert np.array_equal(sim.clean_d_m, clean.clean_d_m)
    assert np.array_equal(rec.u, clean.recording.u)
    # Calibrated to 6x the noise RMS (the suite's secant stops within 3 % in log).
    (e,) = sim.effects
    assert e["effect"] == "adhesion"
    assert abs(math.log(e["peak_over_noise"] / 6.0)) < 0.05
    peak = np.max(np.abs(sim.truth_d_m - sim.clean_d_m))
    assert peak / sim.noise_m == pytest.approx(e["peak_over_noise"], rel=1e-9)
    # A pull-off force in newtons: a fraction of the contact force (nN at most).
    assert e["parameters"]["pull_off_force_n"] < 1e-8
    assert e["parameters"]["pull_off_force_n"] > 0
    # The noise: D in metres, thermal noise + ADC of the order of 0.01-1 nm.
    assert 1e-12 < sim.noise_m < 1e-9
    # noise_m is the RMS of the recording's noise, measured on the run without effects (the
    # same draw: with an effect a rupture may move by a few samples, which is physics).
    assert sim.noise_m == clean.noise_m
    resid = clean.recording.d - clean.truth_d_m
    assert np.sqrt(np.mean(resid**2)) == pytest.approx(clean.noise_m, rel=1e-9)


def test_simulate_refuses():
    with pytest.raises(ValueError, match="not an effect"):
        visco.simulate("curve-soft", ["magic"])
    with pytest.raises(ValueError, match="is not one of"):
        visco.simulate("curve-unknown")
    with pytest.raises(ValueError, match="needs a tap"):
        visco.simulate("curve-gel", ["second-eigenmode"])


def test_simulated_noise_free_is_the_truth():
    sim = visco.simulate("curve-soft", ["stress-relaxation"], seed=1, noise=False)
    assert np.array_equal(sim.recording.d, sim.truth_d_m)


def test_diagnose_releases_the_gil_and_reports_progress(real):
    """While a diagnosis runs on another thread, this one keeps running Python."""
    rec = spot3(real)
    steps = []
    out = {}

    def work():
        out["r"] = visco.diagnose(rec, effects=["adhesion"], max_effects=1, progress=steps.append)

    th = threading.Thread(target=work)
    th.start()
    spins = 0
    while th.is_alive():
        spins += 1
    th.join()
    assert "r" in out
    assert steps and steps[0] in ("nominal fit", "misfit dominates the residual: robust (Huber) fitting")
    # With the GIL held for the call this loop would hardly run at all.
    assert spins > 10_000, spins


def test_progress_callback_exception_stops_diagnose(real):
    rec = visco.read(real / SR, **import_options(SR))
    seen = []

    def progress(step):
        seen.append(step)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        visco.diagnose(rec, progress=progress)
    assert len(seen) == 1


def test_ctrl_c_interrupts_diagnose(real):
    """SIGINT during a diagnosis raises KeyboardInterrupt at its next step."""
    import _thread

    rec = visco.read(real / SR, **import_options(SR))
    steps = []
    timers = []
    # Interrupt once the search has started (the first progress line), from another thread,
    # as a terminal's Ctrl-C arrives.
    def progress(step):
        steps.append(step)
        if len(steps) == 1:
            t = threading.Timer(0.05, _thread.interrupt_main)
            t.start()
            timers.append(t)
        elif timers:
            # On a loaded machine the timer's thread may not have run yet (a CI run once
            # finished the diagnosis first): wait for it, so the interrupt is pending here.
            timers[0].join()

    # Python turns SIGINT into KeyboardInterrupt only if its parent did not ignore SIGINT (a
    # background job's does), and `interrupt_main` does nothing where it is ignored.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            visco.diagnose(rec, progress=progress)
    finally:
        signal.signal(signal.SIGINT, previous)
    # It stopped before the end of the search (a full run takes 20+ steps).
    assert len(steps) < 20, steps
