"""`python -m refsim quieter`: the truth's noise-free D plus noise of the asked size."""

import json
import os

import numpy as np

from refsim.__main__ import main


def test_quieter_keeps_the_physics_and_scales_the_noise(tmp_path):
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    n, sigma = 4000, 1e-10
    t = np.arange(n) * 1e-6
    d_true = 5e-9 * np.sin(2 * np.pi * 1e3 * t)
    rng = np.random.default_rng(1)
    d = d_true + rng.normal(0.0, sigma, n)
    with open(src / "adhesion_s1.csv", "w") as f:
        f.write("# visco-recording: 1\n# mode: dive\nt_s,u_m,d_m\n")
        f.writelines(f"{float(a)!r},0.0,{float(b)!r}\n" for a, b in zip(t, d))
    with open(src / "adhesion_s1.truth.csv", "w") as f:
        f.write("t_s,d_true_m,d_clean_m\n")
        f.writelines(f"{float(a)!r},{float(b)!r},{float(b)!r}\n" for a, b in zip(t, d_true))
    with open(src / "adhesion_s1.truth.json", "w") as f:
        json.dump({"class": "adhesion", "noise_rms_m": sigma,
                   "peak_difference_over_noise": 5.0}, f)
    assert main(["quieter", "--from", str(src), "--out", str(out), "--factor", "0.1"]) == 0
    got = np.loadtxt(out / "adhesion_s1.csv", delimiter=",", comments="#", skiprows=3)
    # The header and the other columns untouched; the new noise within 4 sigma of its RMS's
    # sampling spread (RMS of n normals: relative sd 1/sqrt(2n) = 1.1 %).
    assert open(out / "adhesion_s1.csv").read().startswith("# visco-recording: 1\n# mode: dive\n")
    assert np.array_equal(got[:, 0], t)
    rms = np.sqrt(np.mean((got[:, 2] - d_true) ** 2))
    assert abs(rms / (0.1 * sigma) - 1.0) < 4.0 / np.sqrt(2 * n), rms
    truth = json.load(open(out / "adhesion_s1.truth.json"))
    assert truth["noise_rms_m"] == 0.1 * sigma
    assert abs(truth["peak_difference_over_noise"] - 50.0) < 1e-9
    assert os.path.exists(out / "adhesion_s1.truth.csv")
    # A factor outside (0, 1] is refused.
    assert main(["quieter", "--from", str(src), "--out", str(out), "--factor", "2"]) == 2
