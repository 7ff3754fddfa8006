"""Identify a curve that afmformats read: Recording.from_arrays on an AFMForceDistance.

    pip install afmformats
    python python/examples/from_afmformats.py [FILE]

afmformats (the reader of AFM labs' Python tools: nanite, PyJibe) gives the force (N, positive
= repulsive), the measured height (m) and the time (s). visco's recording wants U, the base
position z up (afmformats' "height (measured)" is that), and the deflection D = -F/k (m,
negative when the sample pushes the tip up). On the JPK spot3 curve this gives U bit for bit
and D to 7e-24 m of visco.read's own import, and identify's k_a equal to the last digit
(measured by hand: afmformats is not installed by `cargo xtask test`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import afmformats

import visco

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"


def main() -> int:
    path = sys.argv[1] if len(sys.argv) > 1 else str(REAL / "fmt-jpk-fd_spot3-0192.jpk-force")
    fd = afmformats.load_data(path)[0]  # an AFMForceDistance
    k = fd.metadata["spring constant"]  # N/m
    rec = visco.Recording.from_arrays(
        fd["time"],  # s
        fd["height (measured)"],  # m, z up: visco's U
        -fd["force"] / k,  # m: visco's D = -F/k
        spring_constant=k,
        tip_radius=5e-6,  # m: no vendor file stores it
        extra={"segment": fd["segment"]},  # 0 approach, 1 retract
        metadata={"segments": "0=extend,1=retract"},
        source=f"afmformats:{Path(path).name}",
    )  # sample_rate: 1 / the median time step
    report = visco.identify(rec)
    print(rec)
    print(
        f"contact at U = {report['contact']['height_m'] * 1e6:.3f} um; "
        f"k_a = {report['k_a_n_per_m3']:.4e} N/m^3, c_a = {report['c_a_ns_per_m3']:.4e} N*s/m^3; "
        f"RMS misfit {report['rms_misfit_m'] * 1e9:.3f} nm"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
