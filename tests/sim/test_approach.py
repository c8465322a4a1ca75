"""The simulator's separation ground truth (sim_vehicles.approach) and how a flown mission reads it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.app.evaluation import read_approach, read_vertical
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


def test_vertical_separation_while_horizontally_within_rs(tmp_path: Path) -> None:
    """Two vehicles on layers 15 m apart cross 30 m apart horizontally (within R_s = 60 m) in step 1:
    the record gives that step their vertical separation while within R_s (the smallest, 12 m,
    when the upper one has sunk 3 m); step 0, never within R_s, has none. A 2D record (no
    `conflict_within`) keeps the four columns."""
    path = tmp_path / "approach.csv"
    rec = ApproachRecorder(path, 2, 2.0, report_within=180.0, conflict_within=60.0)
    for tick in range(1, 40):  # t = 0.1 .. 3.9 s: steps 0 and 1
        t = tick * 0.1
        x = np.array([-300.0 + 100.0 * t, 300.0 - 100.0 * t])  # they meet at t = 3 s
        y = np.array([0.0, 30.0])
        sunk = 3.0 if abs(t - 3.0) < 0.05 else 0.0
        rec.update(t, x, y, np.array([100.0, 115.0 - sunk]))
    rec.close()
    lines = path.read_text().splitlines()
    assert lines[0] == "step,i,j,distance_m,vertical_m"
    assert lines[1].endswith(",") and lines[2].endswith(",12.000"), lines
    assert read_approach(path) == {0: round(math.hypot(220.0, 30.0), 3), 1: 30.0}
    assert read_vertical(path) == {1: 12.0}
    flat = tmp_path / "flat.csv"
    rec = ApproachRecorder(flat, 2, 2.0, report_within=180.0)
    rec.update(0.1, np.array([0.0, 10.0]), np.array([0.0, 0.0]), np.array([100.0, 115.0]))
    rec.close()
    assert flat.read_text().splitlines() == ["step,i,j,distance_m", "0,0,1,10.000"]
    assert read_vertical(flat) == {}
