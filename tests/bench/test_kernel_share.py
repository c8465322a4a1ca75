"""`python -m companion.bench.kernel_share`: every kernel call from Python timed in a real run. The
counts are checked against what the agent's step must call (one RHC ranking and one candidate
search per UAV and step), and the split against the wall time; the figures are printed, never
asserted."""

from __future__ import annotations

import subprocess
import sys

from tests.cli import ROOT


def test_kernel_share_counts_each_uavs_calls_and_splits_the_wall_time() -> None:
    steps = 40
    proc = subprocess.run(
        [sys.executable, "-m", "companion.bench.kernel_share", "--scenario", "1", "--runs", "2",
         "--steps", str(steps)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    head, columns, *rows = proc.stdout.splitlines()
    assert columns.split() == ["kernel", "calls", "seconds", "us/call"]
    words = head.replace("(", " ").replace(")", " ").replace(",", " ").split()
    wall, kernels, glue = float(words[1]), float(words[5]), float(words[11])
    assert 0 < kernels < wall and abs(kernels + glue - wall) <= 0.002
    table = {name: (int(calls), float(seconds)) for name, calls, seconds, _ in map(str.split, rows)}
    assert table["rank_grid_candidates"][0] == 2 * 4 * steps  # 2 runs x 4 UAVs x steps, grid mode
    assert table["first_allowed_from"][0] == 2 * 4 * steps
    assert table["_ground_truth"][0] == 2 * steps  # the engine's scoring, once a step
    assert sum(seconds for _, seconds in table.values()) <= kernels + 0.002
