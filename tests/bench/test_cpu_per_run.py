"""`companion/bench/cpu_per_run.py` as docs/performance.md runs it: a script that times the checkout
on PYTHONPATH (here this one) and prints one line: its label, nine CPU times, their total."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_cpu_per_run_times_the_nine_cells_of_the_checkout_on_pythonpath(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    script = ROOT / "companion" / "bench" / "cpu_per_run.py"
    proc = subprocess.run(
        [sys.executable, str(script), "--label", "here", "--steps", "15"],
        cwd=tmp_path,  # not the checkout: the mission files come from the timed package's checkout
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    label, *cells, word, total, unit = proc.stdout.split()
    assert (label, word, unit) == ("here", "total", "s") and len(cells) == 9
    times = [float(c) for c in cells]
    assert all(t > 0 for t in times) and float(total) == pytest.approx(sum(times), abs=0.01)
