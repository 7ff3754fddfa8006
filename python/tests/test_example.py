"""The example script runs end to end and saves its figure."""

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "diagnose_real.py"


def test_example_diagnoses_and_plots(tmp_path):
    png = tmp_path / "fig.png"
    r = subprocess.run(
        [sys.executable, str(EXAMPLE), "--out", str(png)], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    # The NT-MDT gel curve was recorded for its adhesion: the diagnosis names it.
    assert "adhesion" in r.stdout, r.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 20_000
