"""Following the companions' CSV logs while they grow, and scoring them (companion.app.evaluation)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest

from companion.app.evaluation import CompanionLogs, evaluate, failed_criteria
from companion.core.feasibility import load_mission
from companion.core.world import build_world

ROOT = Path(__file__).resolve().parents[2]

COLUMNS = ["step", "x", "y", "heading", "task", "mean_eta"]


def line(*values: object) -> bytes:
    """One row as the companion's csv.writer writes it (\\r\\n terminated)."""
    buf = io.StringIO()
    csv.writer(buf).writerow(values)
    return buf.getvalue().encode()


def append(path: Path, data: bytes) -> None:
    with path.open("ab") as f:
        f.write(data)


def test_rows_are_read_once_as_the_log_grows(tmp_path: Path) -> None:
    logs = CompanionLogs(tmp_path, 2)
    assert logs.poll() == {0: [], 1: []}  # no files yet
    log0 = tmp_path / "uav0.csv"
    append(log0, line(*COLUMNS) + line(0, 10.0, 20.0, 0.5, -1, 1.0))
    new = logs.poll()
    assert [r["step"] for r in new[0]] == [0] and new[1] == []
    assert logs.logs[0][0]["x"] == 10.0
    assert logs.poll() == {0: [], 1: []}  # nothing new, nothing reread
    append(log0, line(1, 11.0, 21.0, 0.5, 3, 0.9) + line(2, 12.0, 22.0, 0.5, 3, 0.8))
    assert [r["step"] for r in logs.poll()[0]] == [1, 2]
    assert sorted(logs.logs[0]) == [0, 1, 2] and logs.logs[0][2]["task"] == 3


def test_a_line_is_taken_only_once_it_is_complete(tmp_path: Path) -> None:
    log = tmp_path / "uav0.csv"
    logs = CompanionLogs(tmp_path, 1)
    row = line(7, 123.4567, 20.0, 0.5, -1, 0.75)
    header = line(*COLUMNS)
    append(log, header[:5])  # even the header arrives in pieces
    assert logs.poll() == {0: []}
    append(log, header[5:] + row[:9])  # "7,123.45": a number cut short must not be read as 123.45
    assert logs.poll() == {0: []}
    append(log, row[9:])
    (got,) = logs.poll()[0]
    assert got["step"] == 7 and got["x"] == 123.4567


def test_a_line_cut_short_by_a_kill_is_never_read(tmp_path: Path) -> None:
    log = tmp_path / "uav0.csv"
    append(log, line(*COLUMNS) + line(0, 1.0, 2.0, 0.0, -1, 1.0) + line(1, 3.0, 4.0, 0.0, -1, 0.9)[:6])
    logs = CompanionLogs(tmp_path, 1)
    logs.poll()
    assert sorted(logs.logs[0]) == [0]


def test_damaged_lines_are_skipped_and_the_rest_is_read(tmp_path: Path) -> None:
    log = tmp_path / "uav0.csv"
    append(log, line(*COLUMNS) + b"garbage,\xff\xfe\r\n" + line(3, 1.0, 2.0, 0.0, -1, 0.5) + b"1,2\r\n")
    logs = CompanionLogs(tmp_path, 1)
    assert [r["step"] for r in logs.poll()[0]] == [3]


def test_a_uav_missing_a_step_keeps_its_latest_pose(tmp_path: Path) -> None:
    """Companions that start at different steps and skip some (a busy machine, a real autopilot
    taking off) are scored at their latest logged pose, never at the origin."""
    mission = load_mission(ROOT / "mission_files" / "scenario1_px4.toml")
    world = build_world(mission, mission.seed, 0)
    starts = [(v.x, v.y) for v in mission.vehicles]  # 400 m apart in a row
    first = {0: 10, 1: 8, 2: 12, 3: 12}
    logs = {
        i: {
            k: {"x": x, "y": y + 10.0 * k, "heading": 1.57, "task": -1.0, "mean_eta": 1.0}
            for k in range(first[i], 20)
            if not (i == 1 and k in (12, 13))  # uav 1 skips the first scored step and the next
        }
        for i, (x, y) in enumerate(starts)
    }
    result = evaluate(world, logs, np.zeros(0, dtype=np.int64), 1.0, mission.seed)
    assert result.steps == 8
    assert result.trajectory[0, 1, 1] == pytest.approx(starts[1][1] + 110.0)  # its step 11
    assert result.min_distance.min() == pytest.approx(400.0, abs=1.0), result.min_distance
    assert result.lambda2.min() > 0, result.lambda2


def test_separation_is_judged_on_the_flown_tracks_where_they_were_recorded() -> None:
    """With one clock per vehicle (PX4 SITL instances) the poses logged at step k were not taken at
    one moment: the pass criterion reads the flown tracks' record (approach.csv) where there is one,
    else the logged poses."""
    mission = load_mission(ROOT / "mission_files" / "scenario1_px4.toml")
    world = build_world(mission, mission.seed, 0)
    starts = [(v.x, v.y) for v in mission.vehicles]
    logs = {
        i: {k: {"x": x + (370.0 if i == 0 and k == 11 else 0.0), "y": y, "heading": 0.0, "task": -1.0,
                "mean_eta": 1.0} for k in range(10, 14)}
        for i, (x, y) in enumerate(starts)
    }  # fmt: skip
    none = np.zeros(0, dtype=np.int64)
    logged = evaluate(world, logs, none, 1.0, mission.seed)
    assert logged.min_distance.min() == pytest.approx(30.0)  # uav 0 logged 30 m from uav 1 at step 11
    assert any("closest approach 30.0 m" in f for f in failed_criteria(world, logged))
    flown = evaluate(world, logs, none, 1.0, mission.seed, {k: 250.0 for k in range(10, 14)})
    assert not any("closest approach" in f for f in failed_criteria(world, flown))
    close = evaluate(world, logs, none, 1.0, mission.seed, {10: 250.0, 11: 45.0, 12: 250.0, 13: 250.0})
    assert any("closest approach 45.0 m" in f for f in failed_criteria(world, close))


def test_the_pass_criterion_judges_a_recorded_flight_in_three_dimensions(tmp_path: Path) -> None:
    """With a separation record, a pair within R_s horizontally fails the mission only when it was
    also closer vertically than the layers' floor (docs/algorithm.md, "Separation in three
    dimensions"); a record without altitudes is judged in 2D."""
    mission = load_mission(ROOT / "mission_files" / "scenario1_px4.toml")
    world = build_world(mission, mission.seed, 0)
    starts = [(v.x, v.y) for v in mission.vehicles]
    logs = {
        i: {k: {"x": x, "y": y, "heading": 0.0, "task": -1.0, "mean_eta": 1.0} for k in range(10, 14)}
        for i, (x, y) in enumerate(starts)
    }
    floor = mission.vertical_floor
    record = tmp_path / "approach.csv"
    far = {k: 250.0 for k in range(10, 14)}
    result = evaluate(world, logs, np.zeros(0, dtype=np.int64), 1.0, mission.seed, far)

    def lost(text: str) -> bool:
        record.write_text(text)
        return any("separation lost" in f for f in failed_criteria(world, result, record))

    head = "step,i,j,distance_m,vertical_m\n"
    assert not lost(head + f"11,2,3,1.8,{floor + 5.2}\n")  # layers apart: separated
    assert lost(head + f"11,2,3,1.8,{floor - 0.5}\n")  # too close vertically as well
    assert not lost(head + "11,2,3,75.0,\n")  # never within R_s: no vertical figure
    assert lost("step,i,j,distance_m\n11,2,3,45.0\n")  # no altitudes: 2D
