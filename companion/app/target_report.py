"""A flown run's targets: the candidates and the confirmations the companions logged, against the truth.

`uavsearch run` writes `targets_confirmed.json` from the companions' target logs
(`uav{i}_targets.csv`) and the run's score (`evaluation.evaluate`): each cell some companion
confirmed during the scored steps (first confirmation: step, UAV, where, whether `truth.json` puts
a target there), the targets never confirmed, the cells raised as candidates, and the retractions.
"""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import numpy as np

from companion.app.evaluation import TargetRow
from companion.batch.engine import RunResult


class ConfirmedCell(msgspec.Struct, frozen=True):
    """A cell some companion confirmed: its first confirmation, and whether it holds a target."""

    cell: int
    step: int  # the companion's step (its log's), not the scored run's
    uav: int
    lat: float
    lon: float
    posterior: float
    true: bool
    scored: bool  # counted in the run's score: confirmed in a scored step (not while closing)


class TargetSummary(msgspec.Struct, frozen=True):
    """targets_confirmed.json: what the swarm confirmed and left undecided, checked against the truth."""

    perfect_sensor: bool
    targets: int
    confirmed_true: int  # targets some companion confirmed in a scored step: the run's targets found
    false_confirmations: int  # cells holding no target that some companion confirmed in a scored step
    never_confirmed: list[int]  # target cells
    confirmed: list[ConfirmedCell]  # every cell some companion confirmed, scored or not
    candidate_cells: list[int]  # cells some companion held as a candidate at some step
    candidates_raised: int
    retractions: int


def target_summary(result: RunResult, target_log: list[TargetRow], perfect: bool) -> TargetSummary:
    """The run's targets from the companions' target logs (`read_target_logs`) and its score."""
    truth = set(result.target_cells.tolist())
    first: dict[int, TargetRow] = {}
    for row in target_log:
        if row.event == "confirmed":
            first.setdefault(row.cell, row)
    confirm_steps = result.confirm_steps
    steps = zip(result.target_cells.tolist(), confirm_steps.tolist(), strict=True)
    never = sorted(c for c, s in steps if s < 0)
    scored = set(result.target_cells.tolist()) - set(never)
    if result.sensing is not None:
        scored.update(result.sensing.false_cells.tolist())
    confirmed = [
        ConfirmedCell(r.cell, r.step, r.uav, r.lat, r.lon, r.posterior, r.cell in truth, r.cell in scored)
        for r in sorted(first.values(), key=lambda r: (r.step, r.cell))
    ]
    return TargetSummary(
        perfect_sensor=perfect,
        targets=len(truth),
        confirmed_true=int(np.count_nonzero(confirm_steps >= 0)),
        false_confirmations=result.false_confirmations,
        never_confirmed=never,
        confirmed=confirmed,
        candidate_cells=sorted({r.cell for r in target_log if r.event == "candidate"}),
        candidates_raised=sum(r.event == "candidate" for r in target_log),
        retractions=sum(r.event == "retracted" for r in target_log),
    )


def write_target_summary(out: Path, summary: TargetSummary) -> None:
    """targets_confirmed.json in `out`."""
    text = json.dumps(msgspec.to_builtins(summary), indent=2)
    (out / "targets_confirmed.json").write_text(text + "\n")


def target_line(summary: TargetSummary) -> str:
    """The printed line of an imperfect sensor's run: confirmations, true and false, and candidates."""
    false = [c.cell for c in summary.confirmed if c.scored and not c.true]
    return (
        f"targets confirmed {summary.confirmed_true}/{summary.targets}, false confirmations "
        f"{summary.false_confirmations}{f' (cells {false})' if false else ''}, "
        f"{len(summary.candidate_cells)} cells raised as candidates, {summary.retractions} retractions"
    )
