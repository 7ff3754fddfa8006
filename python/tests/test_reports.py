"""visco.identify and visco.diagnose against the command's JSON: identical numbers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import visco
from conftest import ALL, MAP, NTMDT, SPOT3, WORKSHOP, cli_flags, import_options, read_csv, read_json, run_cli

# Keys that hold output file names (which differ between the two runs by construction).
PATH_KEYS = {"recording", "files", "series_csv", "figure_png", "figures"}


def same(a, b, where="report"):
    """Equal trees, numbers exactly (both sides are the same JSON text, parsed)."""
    if isinstance(a, dict):
        assert isinstance(b, dict), where
        ka = set(a) - PATH_KEYS
        kb = set(b) - PATH_KEYS
        assert ka == kb, (where, ka ^ kb)
        for k in ka:
            same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{where}[{i}]")
    elif isinstance(a, str) and a.endswith((".csv", ".png", ".json", ".gsf")):
        pass
    else:
        assert a == b or (a != a and b != b), (where, a, b)


def imported(real, name, tmp_path, curve=None):
    """The command's import of `name` (one curve) and the same in Python."""
    out = tmp_path / "rec.csv"
    extra = ["--curve", str(curve)] if curve is not None else []
    run_cli("import", str(real / name), "--out", str(out), *extra, *cli_flags(import_options(name)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = visco.read(real / name, curve=curve, **import_options(name))
    return out, rec


@pytest.mark.parametrize("name", ALL)
def test_identify_matches_cli(real, name, tmp_path):
    curve = 1 if name == MAP else None
    csv, rec = imported(real, name, tmp_path, curve)
    json_path = tmp_path / "cli.json"
    run_cli("identify", str(csv), "--json", str(json_path))
    expected = read_json(json_path)
    got = visco.identify(rec)
    same(got.to_dict(), expected)
    assert got["recording"] == str(real / name)
    # The fit per sample, as the command's <stem>_fit.csv.
    _, cols = read_csv(tmp_path / "cli_fit.csv")
    assert list(got.series) == list(cols)
    for k, v in cols.items():
        assert np.array_equal(got.series[k], np.array(v, dtype=float), equal_nan=True), k
    # Units: the residual is recorded - simulated, in metres like D.
    s = got.series
    assert np.allclose(s["residual_m"], s["d_recorded_m"] - s["d_simulated_m"], rtol=0, atol=1e-18)
    assert np.array_equal(s["d_recorded_m"], rec.d)
    assert np.array_equal(s["t_s"], rec.t)


def test_identify_of_a_path_is_the_cli(real, tmp_path):
    csv, _ = imported(real, SPOT3, tmp_path)
    run_cli("identify", str(csv), "--json", str(tmp_path / "cli.json"))
    got = visco.identify(csv)
    same(got.to_dict(), read_json(tmp_path / "cli.json"))
    assert got["recording"] == str(csv)


def test_identify_keeps_outputs_in_out_dir(real, tmp_path):
    _, rec = imported(real, SPOT3, tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    got = visco.identify(rec, out_dir=out)
    names = sorted(p.name for p in out.iterdir())
    assert any(n.endswith("_fit.png") for n in names), names
    assert any(n.endswith(".json") for n in names), names
    assert got["fit"]["series_csv"].startswith(str(out))


# Diagnosis is the long call (thousands of simulations): the JPK force-distance curve and
# the two text formats take seconds each; the stress relaxation (SR, ~4 min) and the creep
# (CC, ~1 min) recordings are left to host-sim's diagnose_real.
@pytest.mark.parametrize("name", [SPOT3, WORKSHOP, NTMDT])
def test_diagnose_matches_cli(real, name, tmp_path):
    csv, rec = imported(real, name, tmp_path)
    json_path = tmp_path / "cli.json"
    run_cli("diagnose", str(csv), "--json", str(json_path), "--no-figures", "--quiet")
    expected = read_json(json_path)
    got = visco.diagnose(rec)
    same(got.to_dict(), expected)
    assert got["recording"] == str(real / name)
    _, cols = read_csv(tmp_path / "cli_series.csv")
    assert list(got.series) == list(cols)
    for k, v in cols.items():
        if k == "phase":
            assert list(got.series[k]) == v
        else:
            assert np.array_equal(got.series[k], np.array(v, dtype=float), equal_nan=True), k
    # The extended model fits the held-out half no worse than the nominal one (m, held out).
    s = got.series
    held = s["held_out"] == 1
    rms = lambda r: float(np.sqrt(np.mean(r[held] ** 2)))
    assert rms(s["residual_before_m"]) == pytest.approx(got["rms_before_m"], rel=1e-12)
    assert rms(s["residual_after_m"]) == pytest.approx(got["rms_after_m"], rel=1e-12)


def test_diagnose_options_match_cli(real, tmp_path):
    """alpha and effects reach the search as the command's flags do."""
    csv, rec = imported(real, NTMDT, tmp_path)
    json_path = tmp_path / "cli.json"
    run_cli(
        "diagnose", str(csv), "--json", str(json_path), "--no-figures", "--quiet",
        "--alpha", "0.05", "--effects", "adhesion,thermal-drift", "--max-effects", "1",
    )
    got = visco.diagnose(rec, alpha=0.05, effects=["adhesion", "thermal-drift"], max_effects=1)
    same(got.to_dict(), read_json(json_path))
    assert got["selection"]["family_alpha"] == 0.05
    tried = {c["effect"] for st in got["selection"]["stages"] for c in st["candidates"]}
    assert tried == {"adhesion", "thermal-drift"}
    assert len(got["left_out"]) <= 1


def test_diagnose_refuses_unknown_effect(real, tmp_path):
    _, rec = imported(real, SPOT3, tmp_path)
    with pytest.raises(ValueError, match="not an effect"):
        visco.diagnose(rec, effects=["gravity"])
    with pytest.raises(ValueError, match="alpha"):
        visco.diagnose(rec, alpha=1.5)
