"""Diagnose a real force curve from Python and plot recorded vs extended model.

    python python/examples/diagnose_real.py [FILE [--spring-constant K ...]] [--out PNG]

Reads a vendor file from ../shared/data/real/ (default: the NT-MDT force curve on a gel,
recorded for its adhesion; its file lacks the spring constant, the sensitivity and the rate,
which are given as a user would: 0.1 N/m, 50 nm/nA, 1 kHz), diagnoses it (which physics the
nominal Kelvin-Voigt model left out), prints the findings and saves a figure of the recorded deflection against the nominal and the extended
model, with the residuals before and after. No display needed (matplotlib's Agg backend).

Arrays read by other tools (afmformats, ...) go through visco.Recording.from_arrays: see
from_afmformats.py beside this file.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import visco  # noqa: E402

HERE = Path(__file__).resolve().parent
REAL = HERE.parents[1].parent / "shared" / "data" / "real"
DEFAULT = REAL / "fmt-ntmdt-txt-fd_2015_01_17_gel4-0,1_mQ_adh_6B_Curve_DFL_Height_51.txt"
# What the default file lacks (as host-sim's diagnose_real supplies it).
DEFAULT_VALUES = dict(spring_constant=0.1, sensitivity=5e-8, sample_rate=1000.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file", nargs="?", default=str(DEFAULT))
    ap.add_argument("--out", default=str(HERE / "diagnose_real.png"))
    ap.add_argument("--tip-radius", type=float, default=5e-6, help="m (no vendor stores it)")
    ap.add_argument("--spring-constant", type=float, help="N/m, if the file lacks it")
    ap.add_argument("--sensitivity", type=float, help="m per raw unit, if the file lacks it")
    ap.add_argument("--sample-rate", type=float, help="Hz, if the file lacks it")
    args = ap.parse_args(argv)

    values = dict(DEFAULT_VALUES) if Path(args.file) == DEFAULT else {}
    for key in ("spring_constant", "sensitivity", "sample_rate"):
        if getattr(args, key) is not None:
            values[key] = getattr(args, key)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # vendor oddities, reported by visco import too
        rec = visco.read(args.file, tip_radius=args.tip_radius, **values)
    print(rec)
    report = visco.diagnose(rec, progress=lambda s: print("  diagnose:", s, file=sys.stderr))
    print(
        f"held-out RMS misfit: nominal {report['rms_before_m'] * 1e9:.3f} nm, "
        f"extended {report['rms_after_m'] * 1e9:.3f} nm"
    )
    for i, found in enumerate(report["left_out"], 1):
        print(f"  {i}. {found['effect']}: {found['explanation']}")

    s = report.series
    t = s["t_s"]
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(9, 6))
    top.plot(t, s["d_recorded_m"] * 1e9, lw=0.8, label="recorded")
    top.plot(t, s["d_nominal_m"] * 1e9, "--", lw=1, label="nominal model")
    names = ", ".join(f["effect"] for f in report["left_out"]) or "nothing found"
    top.plot(t, s["d_extended_m"] * 1e9, "--", lw=1, label=f"extended ({names})")
    top.set_ylabel("deflection D (nm)")
    top.legend(fontsize=8)
    top.set_title(Path(args.file).name, fontsize=9)
    bottom.plot(t, s["residual_before_m"] * 1e9, lw=0.6, label="recorded - nominal")
    bottom.plot(t, s["residual_after_m"] * 1e9, lw=0.6, label="recorded - extended")
    bottom.set_ylabel("residual (nm)")
    bottom.set_xlabel("t (s)")
    bottom.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
