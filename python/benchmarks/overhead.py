"""Per-call overhead of the Python layer: visco.identify / visco.diagnose against the Rust
functions they wrap, called through the bare binding (visco._native, no Python-side work).

    python python/benchmarks/overhead.py [--repeat N]

For identify, the bare call is `visco::identify::identify(path, opts)` on the recording CSV
(the command's own work: read, identify, write the report, series and figure); the Python
call on a Recording also writes the recording to a temporary CSV, parses the JSON and reads
the series into numpy (both write to the same kind of temporary directory). For diagnose, the
bare call runs `visco::diagnose::report::analyse` on the arrays; the Python call adds the
contract check (the recording written once) and json.loads. Prints the median
wall time of each and the ratio. Timings are noisy on a shared machine: read the ratio, not
the absolute numbers.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from pathlib import Path

import visco
from visco import _native

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"
FILE = REAL / "fmt-jpk-fd_spot3-0192.jpk-force"


def median_time(f, repeat: int) -> float:
    f()  # warm up (page cache, first-call imports)
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = visco.read(FILE, tip_radius=5e-6)
    # The bare call writes its outputs where visco.identify would (RAM when there is room).
    with visco._tempdir(len(rec), len(rec.columns)) as tmp:
        csv = os.path.join(tmp, "spot3.csv")
        rec.write(csv)
        out = os.path.join(tmp, "bare")
        os.mkdir(out)

        def bare_identify():
            _native.identify_file(csv, os.path.join(out, "spot3.json"), out)

        def py_identify():
            visco.identify(rec)

        cols = rec._native_columns()

        def bare_diagnose():
            _native.diagnose(rec.metadata, cols, "spot3", 0.01, 1, ["adhesion"], None)

        def py_diagnose():
            visco.diagnose(rec, effects=["adhesion"], max_effects=1)

        rows = [
            ("identify", median_time(bare_identify, args.repeat), median_time(py_identify, args.repeat)),
            ("diagnose", median_time(bare_diagnose, max(3, args.repeat // 5)), median_time(py_diagnose, max(3, args.repeat // 5))),
        ]
    print(f"recording: {FILE.name}, {len(rec)} samples")
    print(f"{'call':10} {'Rust (bare binding)':>20} {'visco.<call>':>14} {'ratio':>7}")
    for name, bare, py in rows:
        print(f"{name:10} {bare * 1e3:17.1f} ms {py * 1e3:11.1f} ms {py / bare:7.3f}")


if __name__ == "__main__":
    main()
