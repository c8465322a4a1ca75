"""Scoring a flown run under imperfect sensing: only the companions' confirmations of true targets count."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np

from companion.app.evaluation import TargetRow, evaluate, failed_criteria, read_target_logs
from companion.app.target_report import target_summary
from companion.contracts.mission import Mission, PassCriteria
from companion.core.feasibility import load_mission
from companion.core.world import build_world

ROOT = Path(__file__).resolve().parents[2]
TARGETS = np.array([100, 200, 300], dtype=np.int64)


def _mission(perfect: bool) -> Mission:
    m = load_mission(ROOT / "mission_files" / "scenario1_px4.toml")
    sensor = m.sensor if perfect else msgspec.structs.replace(m.sensor, pd=0.9, pf=0.05)
    criteria = PassCriteria(min_targets_found=3, max_false_confirmations=0)
    return msgspec.structs.replace(m, sensor=sensor, pass_criteria=criteria)


def _logs(m: Mission) -> dict[int, dict[int, dict[str, float]]]:
    """Steps 10-19 (uav 1 from step 8); uav 0 flies out its steps 18 and 19 after the mission's end."""
    return {
        i: {
            k: {"x": v.x, "y": v.y, "heading": 1.57, "task": -1.0, "mean_eta": 1.0,
                "closing": float(i == 0 and k >= 18)}
            for k in range(8 if i == 1 else 10, 20)
        }
        for i, v in enumerate(m.vehicles)
    }  # fmt: skip


def _row(uav: int, step: int, event: str, cell: int) -> TargetRow:
    return TargetRow(uav, step, event, cell, -35.0, 149.0, 0.95)


TARGET_LOG = sorted(
    [
        _row(1, 9, "confirmed", 100),  # before the whole swarm was up: at step 0
        _row(0, 12, "candidate", 200),  # undecided: not found
        _row(2, 13, "confirmed", 555),  # no target there: a false confirmation
        _row(3, 14, "confirmed", 100),  # confirmed before
        _row(0, 15, "retracted", 555),
        _row(0, 18, "confirmed", 300),  # while closing: not scored
        _row(2, 19, "confirmed", 200),
    ],
    key=lambda r: (r.step, r.uav),
)


def test_a_target_is_found_when_a_companion_confirms_it_and_a_false_alarm_never() -> None:
    m = _mission(perfect=False)
    world = build_world(m, m.seed, 0)
    result = evaluate(world, _logs(m), TARGETS, 1.0, m.seed, target_log=TARGET_LOG)
    assert result.steps == 10 and result.sensing is not None
    assert result.confirm_steps.tolist() == [0, 9, -1]
    assert result.sensing.false_cells.tolist() == [555] and result.sensing.false_steps.tolist() == [3]
    assert failed_criteria(world, result) == ["targets found 2 < 3", "false confirmations 1 > 0"]
    summary = target_summary(result, TARGET_LOG, perfect=False)
    assert (summary.confirmed_true, summary.false_confirmations, summary.never_confirmed) == (2, 1, [300])
    assert [(c.cell, c.step, c.uav, c.true, c.scored) for c in summary.confirmed] == [
        (100, 9, 1, True, True), (555, 13, 2, False, True), (300, 18, 0, True, False),
        (200, 19, 2, True, True),
    ]  # fmt: skip
    assert (summary.candidate_cells, summary.candidates_raised, summary.retractions) == ([200], 1, 1)


def test_a_perfect_sensor_scores_as_before() -> None:
    """With the paper's camera a target is found when it is in view; no cell is falsely confirmed."""
    m = _mission(perfect=True)
    world = build_world(m, m.seed, 0)
    before = evaluate(world, _logs(m), TARGETS, 1.0, m.seed)
    after = evaluate(world, _logs(m), TARGETS, 1.0, m.seed, target_log=TARGET_LOG)
    assert after.sensing is None and after.false_confirmations == 0
    assert after.confirm_steps.tolist() == after.target_steps.tolist() == before.target_steps.tolist()
    assert failed_criteria(world, after) == failed_criteria(world, before)


def test_the_target_logs_are_read_in_step_order_without_damaged_rows(tmp_path: Path) -> None:
    head = "step,event,cell,x,y,lat,lon,posterior\n"
    damaged, torn = "x,candidate,8,0,0,0,0,0.5\n", "5,candidate,9,1.0,2.0,-35"  # a kill cut it short
    good = "4,confirmed,7,1.0,2.0,-35.1,149.2,0.990000\n"
    (tmp_path / "uav0_targets.csv").write_text(head + good + damaged + torn)
    (tmp_path / "uav2_targets.csv").write_text(head + "3,candidate,11,0.0,0.0,-35.0,149.0,0.100000\n")
    assert read_target_logs(tmp_path, 3) == [
        TargetRow(2, 3, "candidate", 11, -35.0, 149.0, 0.1),
        TargetRow(0, 4, "confirmed", 7, -35.1, 149.2, 0.99),
    ]
