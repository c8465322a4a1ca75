"""The suite's scheduling holds: `make test` runs `pytest -n 2 --dist loadgroup`, and the tests of one
`xdist_group` (tests/conftest.py: the real-time autopilot flights, the real-time swarms) must run
one after another on one worker. pytest-xdist groups by rewriting node ids, which pytest 9.2
ignores: the groups were then silently spread over both workers. This runs a small suite the same
way and reads which worker ran each test."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

GROUPED = """
import os
from pathlib import Path

import pytest


@pytest.mark.xdist_group("solo")
@pytest.mark.parametrize("i", range(6))
def test_grouped(i):
    Path(os.environ["RECORD"], f"{__name__}-{i}").write_text(os.environ["PYTEST_XDIST_WORKER"])
"""


def test_an_xdist_group_runs_on_one_worker(tmp_path: Path) -> None:
    suite, record = tmp_path / "suite", tmp_path / "record"
    suite.mkdir()
    record.mkdir()
    for name in ("test_a.py", "test_b.py"):
        (suite / name).write_text(GROUPED)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p", "no:cacheprovider",
         "--rootdir", str(suite), str(suite)],
        cwd=suite, env={**os.environ, "RECORD": str(record)}, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    workers = {p.name: p.read_text() for p in record.iterdir()}
    assert len(workers) == 12, workers
    assert len(set(workers.values())) == 1, f"one group, several workers: {workers}"
