"""The simulator's separation ground truth (sim_vehicles.approach) and how a flown mission reads it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.app.evaluation import read_approach
from sim_vehicles.approach import ApproachRecorder


def test_closest_approach_per_step_and_pair(tmp_path: Path) -> None:
    """Two vehicles pass each other 30 m apart in the middle of step 1; a third stays far away.
    Ticks of 0.1 s, steps of 2 s: every tick updates the step it falls in."""
    path = tmp_path / "approach.csv"
    rec = ApproachRecorder(path, 3, 2.0, report_within=180.0)
    for tick in range(1, 60):  # t = 0.1 .. 5.9 s: steps 0, 1, 2
        t = tick * 0.1
        x = np.array([-300.0 + 100.0 * t, 300.0 - 100.0 * t, 5000.0])  # they meet at t = 3 s
        y = np.array([0.0, 30.0, 0.0])
        rec.update(t, x, y)
    rec.close()
    rows = [line.split(",") for line in path.read_text().splitlines()[1:]]
    by_step: dict[int, list[tuple[int, int, float]]] = {}
    for step, i, j, d in rows:
        by_step.setdefault(int(step), []).append((int(i), int(j), float(d)))
    # step 1 holds the meeting: 30 m, pair (0, 1); the far vehicle is never reported but as nobody's closest
    assert by_step[1] == [(0, 1, 30.0)]
    # step 0 (t < 2 s): they close from 580 m to 222 m at t = 1.9 s: beyond 180 m, yet the step's closest pair
    assert by_step[0] == [(0, 1, round(math.hypot(220.0, 30.0), 3))]
    # step 2: they part again; at t = 4 s they are 200 m apart along x
    assert by_step[2][0][:2] == (0, 1) and by_step[2][0][2] == round(math.hypot(200.0, 30.0), 3)
    assert read_approach(path) == {0: by_step[0][0][2], 1: 30.0, 2: by_step[2][0][2]}
    assert read_approach(tmp_path / "missing.csv") == {}


def test_a_torn_last_line_is_ignored(tmp_path: Path) -> None:
    path = tmp_path / "approach.csv"
    path.write_text("step,i,j,distance_m\n0,0,1,80.000\n1,0,1,7")  # "7" of a "70.000" cut short
    assert read_approach(path) == {0: 80.0}
    path.write_text("step,i,j,distance_m\n0,0,1,80.000\n1,0,")
    assert read_approach(path) == {0: 80.0}
