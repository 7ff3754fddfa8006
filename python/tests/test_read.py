"""visco.read against `visco import`: every real file, every curve, bit for bit; units."""

from __future__ import annotations

import math

import numpy as np
import pytest

import visco
from conftest import ALL, MAP, SPOT3, cli_flags, import_options, read_csv, run_cli


def import_with_cli(real, name, tmp_path):
    """{curve: (meta, columns)} as the command writes them."""
    out = tmp_path / ("curve-{curve}.csv" if name == MAP else "curve-0.csv")
    run_cli("import", str(real / name), "--out", str(out), *cli_flags(import_options(name)))
    return {
        int(p.stem.split("-")[1]): read_csv(p) for p in sorted(tmp_path.glob("curve-*.csv"))
    }


@pytest.mark.parametrize("name", ALL)
def test_read_matches_cli_import_bit_for_bit(real, name, tmp_path):
    expected = import_with_cli(real, name, tmp_path)
    with _no_check():
        got = visco.read_all(real / name, **import_options(name))
    assert sorted(got) == sorted(expected)
    for curve, (meta, cols) in expected.items():
        rec = got[curve]
        assert list(rec.columns) == list(cols)
        for col, values in cols.items():
            a = rec.columns[col]
            b = np.array(values, dtype=float)
            # Bit for bit: the same f64s, NaN where NaN.
            assert a.shape == b.shape, col
            assert np.array_equal(a.astype(float), b, equal_nan=True), col
        for key, text in meta.items():
            value = rec.metadata[key]
            if isinstance(value, float):
                assert value == float(text), key
            else:
                assert str(value) == text, key
        assert set(rec.metadata) == set(meta)


class _no_check:
    """Vendor warnings are expected on some files; they go through `warnings`."""

    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore")

    def __exit__(self, *a):
        self._w.__exit__(*a)


@pytest.mark.parametrize("name", ALL)
def test_arrays_are_in_si_units(real, name):
    """The columns are in the units their names say: time in seconds at the declared rate,
    positions and deflections in metres (an AFM's are nm to um, not nm-sized numbers), and
    the vendor's force in newtons equal to -k*D (its sign: positive = repulsive)."""
    with _no_check():
        recs = visco.read_all(real / name, **import_options(name))
    for rec in recs.values():
        units = rec.units()
        assert units["t_s"] == "s" and units["u_m"] == "m" and units["d_m"] == "m"
        assert np.all(np.diff(rec.t) > 0)
        # Within each segment the step is 1/rate, at the segment's rate where the vendor
        # gives one (a JPK hold may be sampled slower), else the recording's.
        rates = rec.metadata.get("segment_rates_hz")
        seg = rec.columns.get("segment", np.zeros(len(rec)))
        for i, s in enumerate(np.unique(seg)):
            fs = float(rates.split(",")[i]) if rates else rec.metadata["sample_rate_hz"]
            t = rec.t[seg == s]
            if len(t) > 2:
                assert abs(np.median(np.diff(t)) * fs - 1.0) < 0.01, (s, fs)
        # Travel of a force curve: 100 nm to 100 um; deflection below 10 um.
        assert 1e-7 < np.ptp(rec.u) < 1e-4, np.ptp(rec.u)
        assert 1e-10 < np.ptp(rec.d) < 1e-5, np.ptp(rec.d)
        if "force_vendor_n" in rec.columns:
            assert units["force_vendor_n"] == "N"
            k = rec.metadata["cantilever_k_n_per_m"]
            f = rec.columns["force_vendor_n"]
            ok = np.isfinite(f)
            # Least-squares slope of F against D: -k, to the rounding of the file's scaling.
            slope = np.polyfit(rec.d[ok], f[ok], 1)[0]
            assert math.isclose(slope, -k, rel_tol=1e-6), (slope, k)


def test_map_needs_a_curve(real):
    with pytest.raises(visco.ViscoError) as e:
        visco.read(real / MAP, tip_radius=5e-6)
    assert e.value.file == str(real / MAP)
    assert "the map holds 4 curves" in e.value.reason
    rec = visco.read(real / MAP, tip_radius=5e-6, curve=2)
    assert rec.curve == 2


def test_missing_tip_radius_is_the_cli_error(real, tmp_path):
    """Same text as the command's `error: ...` line."""
    path = real / SPOT3
    with pytest.raises(visco.ViscoError) as e, _no_check():
        visco.read(path)
    r = run_cli("import", str(path), "--out", str(tmp_path / "x.csv"), ok=False)
    assert r.returncode == 1
    assert f"error: {e.value}" in r.stderr.splitlines()
    assert e.value.file == str(path)
    assert e.value.reason == "the file holds no tip radius"
    assert "--tip-radius" in e.value.fix
    assert isinstance(e.value, ValueError)


def test_malformed_recording_names_file_and_line(tmp_path):
    """A broken recording CSV: the command's file, line and reason."""
    path = tmp_path / "broken.csv"
    path.write_text(
        "# visco-recording: 1\n# mode: force-curve\n# sample_rate_hz: 1000\n"
        "# cantilever_k_n_per_m: 0.1\n# tip_radius_m: 5e-6\n"
        "t_s,u_m,d_m\n0,1e-6,0\n0.001,0.9e-6,zero\n"
    )
    with pytest.raises(visco.ViscoError) as e:
        visco.read(path)
    assert e.value.file == str(path)
    assert e.value.line == 8
    assert "zero" in e.value.reason
    r = run_cli("identify", str(path), "--json", str(tmp_path / "r.json"), ok=False)
    assert f"error: {e.value}" in r.stderr.splitlines()


def test_missing_file(tmp_path):
    with pytest.raises(visco.ViscoError) as e:
        visco.read(tmp_path / "nothing.jpk-force", tip_radius=5e-6)
    assert e.value.file == str(tmp_path / "nothing.jpk-force")
