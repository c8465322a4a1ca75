"""The companion's run logs: a CSV row per step flown, per plan-versus-flight error, per target change."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TextIO

from companion.core.agent import Agent, Command
from companion.node.target_watch import TargetEvent
from companion.node.tracking import PlanError

LOG_COLUMNS = [
    "step",
    "time",
    "x",
    "y",
    "heading",
    "task",
    "mean_eta",
    "found",
    "candidates",
    "steered",
    "turn",
    "cmd_x",
    "cmd_y",
    "peers",
    "up",
    "closing",
]
PLAN_COLUMNS = [
    "step",
    "planned_x",
    "planned_y",
    "planned_heading",
    "x",
    "y",
    "heading",
    "error_m",
    "error_deg",
]
TARGET_COLUMNS = ["step", "event", "cell", "x", "y", "lat", "lon", "posterior"]


class CsvLog:
    """A CSV log flushed after every row: new with its header row, or continued after a restart."""

    def __init__(self, path: Path, columns: list[str], append: bool) -> None:
        """Open `path`; with `append`, go on after its last row (ending a line a kill cut short)."""
        if append and path.exists() and path.stat().st_size > 0:
            with path.open("rb") as f:
                f.seek(-1, 2)
                torn = f.read(1) != b"\n"
            self._file: TextIO = path.open("a", newline="")
            if torn:
                self._file.write("\n")
            self._writer = csv.writer(self._file)
        else:
            self._file = path.open("w", newline="")
            self._writer = csv.writer(self._file)
            self._writer.writerow(columns)

    def write(self, row: list[object]) -> None:
        """Append one row, on disk at once."""
        self._writer.writerow(row)
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class RunLogs:
    """One UAV's step log (`uav<N>.csv`), plan-versus-flight log (`uav<N>_plan.csv`) and target log.

    The target log (`uav<N>_targets.csv`) has a row per new candidate, confirmation and retraction."""

    def __init__(self, out: Path, uav: int, append: bool) -> None:
        """Open the logs in `out` (`append`: a restarted companion goes on with its logs)."""
        out.mkdir(parents=True, exist_ok=True)
        self._steps = CsvLog(out / f"uav{uav}.csv", LOG_COLUMNS, append)
        self._plan = CsvLog(out / f"uav{uav}_plan.csv", PLAN_COLUMNS, append)
        self._targets = CsvLog(out / f"uav{uav}_targets.csv", TARGET_COLUMNS, append)

    def step(
        self,
        k: int,
        dt: float,
        pose: tuple[float, float, float],
        command: Command,
        agent: Agent,
        steered: bool,
        up: float,
        closing: bool,
    ) -> None:
        """Write step k's row of the step log.

        The row holds step k (of `dt` seconds), the pose it was planned from, the command, what the
        agent knows, whether the vehicle flies it, its height and the phase.
        """
        x, y, heading = pose
        self._steps.write(
            [
                k,
                f"{k * dt:.3f}",
                f"{x:.4f}",
                f"{y:.4f}",
                f"{heading:.9f}",
                command.task,
                f"{float(agent.eta.mean()):.6f}",
                len(agent.found),
                len(agent.candidates),
                int(steered),
                f"{command.turn:.6f}",
                f"{command.waypoint[0]:.3f}",
                f"{command.waypoint[1]:.3f}",
                len(agent.peers),
                f"{up:.2f}",
                int(closing),
            ]
        )

    def plan(self, e: PlanError) -> None:
        """One row of the plan log: where the plan put the vehicle and where it was."""
        self._plan.write(
            [
                e.step,
                *(f"{v:.3f}" for v in e.planned[:2]),
                f"{e.planned[2]:.6f}",
                *(f"{v:.3f}" for v in e.flown[:2]),
                f"{e.flown[2]:.6f}",
                f"{e.position_m:.3f}",
                f"{e.heading_deg:.3f}",
            ]
        )

    def targets(self, events: list[TargetEvent]) -> None:
        """The target log's rows of one step's events (`TargetWatch.step`)."""
        for e in events:
            where = (f"{e.x:.3f}", f"{e.y:.3f}", f"{e.lat:.7f}", f"{e.lon:.7f}")
            self._targets.write([e.step, e.event, e.cell, *where, f"{e.posterior:.6f}"])

    def close(self) -> None:
        self._steps.close()
        self._plan.close()
        self._targets.close()
