"""`companion/bench/run_digest.py` as docs/performance.md runs it: the same checkout gives the
same hash of its seeded runs, and a change to any run (here another seed) gives another."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _digest(tmp_path: Path, *extra: str) -> list[str]:
    proc = subprocess.run(
        [sys.executable, str(ROOT / "companion" / "bench" / "run_digest.py"), "--steps", "8", *extra],
        cwd=tmp_path,  # the mission files come from the hashed package's checkout
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.splitlines()


def test_the_digest_is_reproducible_and_changes_with_the_runs(tmp_path: Path) -> None:
    first, again, other = _digest(tmp_path), _digest(tmp_path), _digest(tmp_path, "--seed", "2")
    assert len(first) == 4 * 3 * 3 + 1 and first[-1].startswith("all ")
    assert first == again
    assert first[-1] != other[-1]
    assert sum(a != b for a, b in zip(first, other, strict=True)) >= 30  # nearly every run differs


def test_an_imperfect_sensor_adds_its_runs_to_the_digest(tmp_path: Path) -> None:
    """`--sensor PD,PF` keeps the scenarios' lines and adds three missions x three algorithms."""
    plain, imperfect = _digest(tmp_path), _digest(tmp_path, "--sensor", "0.8,0.02")
    assert imperfect[:-1][: len(plain) - 1] == plain[:-1]
    added = imperfect[len(plain) - 1 : -1]
    assert len(added) == 3 * 3 and all("_pd0.8_pf0.02 " in line for line in added), added
    assert imperfect[-1] != plain[-1]
    bad = subprocess.run(
        [sys.executable, str(ROOT / "companion" / "bench" / "run_digest.py"), "--sensor", "0.8"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert bad.returncode == 2 and "expected PD,PF" in bad.stderr, bad.stderr
