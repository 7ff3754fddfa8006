"""python -m refsim generate --out DIR --seeds N [--classes clean,adhesion,...]
python -m refsim quieter --from DIR --out DIR2 --factor 0.1 [--stems a_s1,b_s2]

Writes DIR/<class>_s<seed>.csv (a recording as shared/spec/recording.md defines it) and,
beside it, the truth that `visco diagnose` never reads: <stem>.truth.json (class, amplitude,
shape, the reached |dD|/noise, the setup) and <stem>.truth.csv (t_s, the noise-free D with
the effect, the noise-free D without it). `visco concealed --recordings DIR` reads the truth
only to score.

`quieter` rewrites recordings of DIR with their noise-free D (from the truth) plus white
Gaussian noise of `factor` times their noise RMS, no ADC grid: the same physics with 1/factor²
times the information per sample. A miss that a quieter recording turns into a right name
was limited by the information in the recording; one that stays wrong is the method's.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import zlib
from concurrent.futures import ProcessPoolExecutor

from .model import EFFECTS, DiscreteBed
from .scenario import scenario

CLASSES = ("clean",) + EFFECTS


def fmt(v: float) -> str:
    return repr(float(v))


def write(out: str, cls: str, seed: int, sc: dict) -> str:
    stem = f"{cls}_s{seed}"
    s = sc["setup"]
    lv = s.lever
    lines = [
        "# visco-recording: 1",
        f"# mode: {'dive' if s.tap else 'force-curve'}",
        f"# sample_rate_hz: {fmt(s.rate_hz)}",
        f"# cantilever_k_n_per_m: {fmt(lv.k)}",
    ]
    if s.tap:
        lines += [f"# cantilever_c_ns_per_m: {fmt(lv.c)}", f"# cantilever_m_kg: {fmt(lv.m)}"]
    else:
        # Force curves, as commercial files give them: resonance and Q.
        lines += [f"# cantilever_f0_hz: {fmt(lv.f0)}", f"# cantilever_q: {fmt(lv.q)}"]
    lines += [
        f"# tip_radius_m: {fmt(s.radius)}",
        "# source: refsim (independent reference simulator, issue 13)",
        "t_s,u_m,d_m",
    ]
    rows = [f"{t:.9e},{float(u)!r},{float(d)!r}" for t, u, d in zip(sc["t_s"], sc["u_m"], sc["d_m"])]
    tmp = os.path.join(out, f".{stem}.csv.tmp")
    with open(tmp, "w") as f:
        f.write("\n".join(lines + rows) + "\n")
    eff = sc["effect"]
    truth = {
        "class": cls,
        "seed": seed,
        "amplitude": None if eff is None else eff.amplitude,
        "shape": None if eff is None else eff.shape,
        "peak_difference_over_noise": sc["ratio"],
        "target_ratio": sc["target_ratio"],
        "noise_rms_m": sc["noise_rms_m"],
        "setup": s.describe(),
        "interference": None if sc["interference"] is None else sc["interference"].describe(),
        "definitions": {
            "peak_difference_over_noise": "largest |D with - D without the effect| on "
            "noise-free runs over the recording's noise RMS (noise + ADC)",
        },
    }
    with open(os.path.join(out, f"{stem}.truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    with open(os.path.join(out, f"{stem}.truth.csv"), "w") as f:
        f.write("t_s,d_true_m,d_clean_m\n")
        f.writelines(f"{t:.9e},{float(a)!r},{float(b)!r}\n"
                     for t, a, b in zip(sc["t_s"], sc["truth_d_m"], sc["clean_d_m"]))
    os.replace(tmp, os.path.join(out, f"{stem}.csv"))
    return stem


def job(args):
    out, cls, seed, discrete_only, interference = args
    t = time.time()
    sc = scenario(None if cls == "clean" else cls, seed, discrete_only=discrete_only,
                  interference=interference)
    stem = write(out, cls, seed, sc)
    s = sc["setup"]
    return (f"{stem}: {'tap' if s.tap else 'curve'}, "
            f"{'discrete' if isinstance(s.bed, DiscreteBed) else 'continuum'} bed, "
            f"{'DAC' if s.dac else 'smooth'} U, {len(sc['t_s'])} samples, "
            f"{sc['ratio']:.1f}x noise, {time.time() - t:.0f} s")


def quieter(src: str, out: str, stem: str, factor: float) -> str:
    """Rewrite recording `stem` of `src` into `out` with factor x its noise (see the docs)."""
    import numpy as np

    with open(os.path.join(src, f"{stem}.truth.json")) as f:
        truth = json.load(f)
    with open(os.path.join(src, f"{stem}.csv")) as f:
        lines = f.read().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    cols = lines[len(head)].split(",")
    rows = [ln.split(",") for ln in lines[len(head) + 1:] if ln]
    with open(os.path.join(src, f"{stem}.truth.csv")) as f:
        d_true = [float(ln.split(",")[1]) for ln in f.read().splitlines()[1:] if ln]
    if len(d_true) != len(rows):
        raise ValueError(f"{src}/{stem}.truth.csv: {len(d_true)} rows, the recording has {len(rows)}")
    sigma = factor * truth["noise_rms_m"]
    rng = np.random.default_rng(zlib.crc32(stem.encode()))
    noise = rng.normal(0.0, sigma, len(rows))
    di = cols.index("d_m")
    for r, d, e in zip(rows, d_true, noise):
        r[di] = repr(float(d + e))
    tmp = os.path.join(out, f".{stem}.csv.tmp")
    with open(tmp, "w") as f:
        f.write("\n".join(head + [",".join(cols)] + [",".join(r) for r in rows]) + "\n")
    truth["noise_rms_m"] = sigma
    truth["peak_difference_over_noise"] = truth["peak_difference_over_noise"] / factor
    truth["quieter"] = {"factor": factor, "from": os.path.abspath(src),
                        "note": "noise-free D plus white Gaussian noise, no ADC grid"}
    with open(os.path.join(out, f"{stem}.truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    shutil.copyfile(os.path.join(src, f"{stem}.truth.csv"), os.path.join(out, f"{stem}.truth.csv"))
    os.replace(tmp, os.path.join(out, f"{stem}.csv"))
    return stem


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m refsim")
    sub = p.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate", help="write recordings and their truth sidecars")
    g.add_argument("--out", required=True)
    g.add_argument("--seeds", type=int, default=5, help="recordings per class")
    g.add_argument("--first-seed", type=int, default=0)
    g.add_argument("--classes", default=",".join(CLASSES),
                   help="comma-separated: clean and effect identifiers")
    g.add_argument("--jobs", type=int, default=1)
    g.add_argument("--discrete-only", action="store_true",
                   help="the paper's discrete bed on every recording (fast: no continuum "
                   "curves, each ~100 s per run in Python here); the CI subset uses it")
    g.add_argument("--interference", action="store_true",
                   help="force curves only, from 1.5-3 um away, with an optical-interference "
                   "wave in the lever's height on the detector (2-10x the noise, period "
                   "0.25-0.45 um); the truth's D is without it")
    q = sub.add_parser("quieter", help="rewrite recordings with a fraction of their noise "
                       "(noise-free D from the truth plus fresh noise)")
    q.add_argument("--from", dest="src", required=True, help="a directory `generate` wrote")
    q.add_argument("--out", required=True)
    q.add_argument("--factor", type=float, default=0.1, help="the new noise RMS over the old")
    q.add_argument("--stems", default="", help="comma-separated stems (default: every one)")
    a = p.parse_args(argv)
    if a.cmd == "quieter":
        if not 0.0 < a.factor <= 1.0:
            print("error: --factor must be in (0, 1]", file=sys.stderr)
            return 2
        stems = [x.strip() for x in a.stems.split(",") if x.strip()] or sorted(
            f[:-len(".truth.json")] for f in os.listdir(a.src) if f.endswith(".truth.json"))
        os.makedirs(a.out, exist_ok=True)
        for i, stem in enumerate(stems):
            try:
                quieter(a.src, a.out, stem, a.factor)
            except (OSError, ValueError, KeyError) as e:
                print(f"error: {stem}: {e}", file=sys.stderr)
                return 1
            print(f"[{i + 1}/{len(stems)}] {stem}: noise x{a.factor}", flush=True)
        return 0
    classes = [c.strip() for c in a.classes.split(",") if c.strip()]
    for c in classes:
        if c not in CLASSES:
            print(f"error: --classes: `{c}` is not one of {', '.join(CLASSES)}", file=sys.stderr)
            return 2
    if a.interference and "second-eigenmode" in classes:
        print("error: --interference makes force curves, which do not resolve the second "
              "eigenmode: leave second-eigenmode out of --classes", file=sys.stderr)
        return 2
    if a.seeds < 1:
        print("error: --seeds must be at least 1", file=sys.stderr)
        return 2
    os.makedirs(a.out, exist_ok=True)
    jobs = [(a.out, c, s, a.discrete_only, a.interference) for s in range(a.first_seed, a.first_seed + a.seeds) for c in classes]
    done = 0
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        for line in ex.map(job, jobs):
            done += 1
            print(f"[{done}/{len(jobs)}] {line}", flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    sys.exit(main())
