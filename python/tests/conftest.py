"""Shared fixtures: the real recordings, the `visco` command to compare with, and an
independent reader of the command's CSV outputs (Python's csv module, no visco code)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
from pathlib import Path
from typing import Dict, List, Tuple

import pytest

ROOT = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ.get("VISCO_SHARED", ROOT.parent / "shared"))
REAL = SHARED / "data" / "real"

SPOT3 = "fmt-jpk-fd_spot3-0192.jpk-force"
SR = "fmt-jpk-sr_cell1-0008.jpk-force"
CC = "fmt-jpk-cc_pr14-polymergel-2021.06.30.jpk-force"
MAP = "fmt-jpk-fd_map2x2_extracted.jpk-force-map"
WORKSHOP = "fmt-afm-workshop-fd_single_2021-10-22_14.16.csv"
NTMDT = "fmt-ntmdt-txt-fd_2015_01_17_gel4-0,1_mQ_adh_6B_Curve_DFL_Height_51.txt"
ALL = [SPOT3, SR, CC, MAP, WORKSHOP, NTMDT]


def import_options(name: str) -> Dict[str, float]:
    """What the files lack, supplied as a user would (as host-sim's identify_real): tip
    radius 5 um; AFM Workshop and NT-MDT 0.1 N/m at 1 kHz; NT-MDT 50 nm/nA."""
    o = {"tip_radius": 5e-6}
    if name in (WORKSHOP, NTMDT):
        o.update(spring_constant=0.1, sample_rate=1000.0)
    if name == NTMDT:
        o["sensitivity"] = 5e-8
    return o


def cli_flags(opts: Dict[str, float]) -> List[str]:
    flags = []
    for k, v in opts.items():
        flags += ["--" + k.replace("_", "-"), repr(v)]
    return flags


def cli_path() -> Path:
    """The `visco` command: $VISCO_CLI, else the build `cargo xtask test` makes."""
    p = Path(os.environ.get("VISCO_CLI", ROOT / "target" / "pyext" / "visco"))
    if not p.is_file():
        raise RuntimeError(
            f"the visco command is not at {p}: build it with "
            "`cargo build --profile pyext -p visco --bin visco` or set VISCO_CLI"
        )
    return p


def run_cli(*args: str, ok: bool = True) -> subprocess.CompletedProcess:
    r = subprocess.run([str(cli_path()), *args], capture_output=True, text=True)
    if ok and r.returncode != 0:
        raise AssertionError(f"visco {' '.join(args)} failed: {r.stderr}")
    return r


def read_csv(path: Path) -> Tuple[Dict[str, str], Dict[str, list]]:
    """`# key: value` lines and columns of a CSV the command wrote, with Python's csv module;
    numeric cells as float (Python's float() rounds correctly, as Rust's parse does)."""
    meta: Dict[str, str] = {}
    with open(path, newline="") as f:
        lines = f.read().splitlines()
    body = []
    for line in lines:
        if line.startswith("#"):
            if ":" in line:
                k, v = line[1:].split(":", 1)
                meta[k.strip()] = v.strip()
        else:
            body.append(line)
    rows = list(csv.reader(body))
    names = rows[0]
    cols: Dict[str, list] = {n: [] for n in names}
    for row in rows[1:]:
        for n, cell in zip(names, row):
            try:
                cols[n].append(float(cell))
            except ValueError:
                cols[n].append(cell)
    return meta, cols


def read_json(path: Path):
    with open(path) as f:
        return json.load(f)


@pytest.fixture(scope="session")
def cli() -> Path:
    return cli_path()


@pytest.fixture(scope="session")
def real() -> Path:
    if not REAL.is_dir():
        raise RuntimeError(f"the real recordings are not at {REAL} (set VISCO_SHARED)")
    return REAL
