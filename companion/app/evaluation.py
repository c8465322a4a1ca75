"""Scoring a distributed run from what the companions logged and the simulator's truth record.

The companions log, per step, their pose, task and mean uncertainty (`uav{i}.csv`), and the cells
their maps confirmed (`uav{i}_targets.csv`); the simulator (or the stand-alone camera) writes the
ground-truth targets (`truth.json`). From these the evaluator rebuilds a `RunResult`, so a flown
mission is summarised, plotted and compared exactly like a batch-engine run. `flight_report` adds
what only a real flight has: the companions' plan-versus-flight errors (`uav{i}_plan.csv`) and how
the poses kept to the fence.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import NamedTuple

import msgspec
import numpy as np

from companion.batch.engine import RunResult, Scorer
from companion.contracts.mission import Mission
from companion.core.search_area import region_hull
from companion.core.world import World
from companion.node.fence import fence_margin, fence_polygon
from companion.node.tracking import Percentiles, percentiles


class UavTracking(msgspec.Struct, frozen=True):
    """One UAV's plan versus flight in tracking.json: its measured steps and error percentiles."""

    steps: int
    position_m: Percentiles
    heading_deg: Percentiles


class FlightReport(msgspec.Struct, frozen=True):
    """tracking.json: plan versus flight, the fence, and the vertical separation within R_s.

    Plan versus flight over the swarm and each UAV, how the logged poses kept to the fence, and the
    steps with a pair within R_s horizontally with their closest vertical separation."""

    steps: int
    position_m: Percentiles
    heading_deg: Percentiles
    per_uav: dict[int, UavTracking]
    fence_margin_m: float
    outside_fence: int
    max_beyond_region_m: float
    steps_within_rs: int
    closest_vertical_within_rs_m: float | None


class CompanionLogs:
    """The companions' uav{i}.csv logs, {uav: {step: row}}, followed as they grow.

    The companions' uav{i}.csv logs, {uav: {step: row}}, followed as they grow: `poll` parses
    only the complete lines written since the previous call, so a long mission is not reread
    every time and a line a kill cut short is never taken for a shorter number."""

    def __init__(self, out: Path, n_uavs: int) -> None:
        self.paths = [out / f"uav{i}.csv" for i in range(n_uavs)]
        self.logs: dict[int, dict[int, dict[str, float]]] = {i: {} for i in range(n_uavs)}
        self._read = [0] * n_uavs  # bytes consumed per file
        self._columns: list[list[str]] = [[] for _ in range(n_uavs)]

    def poll(self) -> dict[int, list[dict[str, float]]]:
        """Read what each log gained (missing files are empty logs); returns the new rows."""
        new: dict[int, list[dict[str, float]]] = {i: [] for i in self.logs}
        for i, path in enumerate(self.paths):
            try:
                with path.open("rb") as f:
                    f.seek(self._read[i])
                    data = f.read()
            except FileNotFoundError:
                continue
            end = data.rfind(b"\n") + 1
            self._read[i] += end
            for fields in csv.reader(data[:end].decode(errors="replace").splitlines()):
                if not self._columns[i]:
                    self._columns[i] = fields
                    continue
                try:
                    row = {k: float(v) for k, v in zip(self._columns[i], fields, strict=True)}
                    step = int(row["step"])
                except (KeyError, ValueError):  # a damaged line
                    continue
                self.logs[i][step] = row
                new[i].append(row)
        return new


class TargetRow(NamedTuple):
    """One row of a companion's target log (`uav{i}_targets.csv`): a candidate, confirmation or retraction."""

    uav: int
    step: int
    event: str
    cell: int
    lat: float
    lon: float
    posterior: float


def read_target_logs(out: Path, n_uavs: int) -> list[TargetRow]:
    """The companions' target logs in `out`, by step then UAV (missing logs and damaged rows: none)."""
    rows = []
    for i in range(n_uavs):
        path = out / f"uav{i}_targets.csv"
        if not path.exists():
            continue
        lines = path.read_text(encoding="utf-8", errors="replace").split("\n")[:-1]  # a line cut short: out
        for r in csv.DictReader(lines):
            try:
                rows.append(
                    TargetRow(
                        i, int(r["step"]), r["event"], int(r["cell"]), float(r["lat"]), float(r["lon"]),
                        float(r["posterior"]),
                    )
                )  # fmt: skip
            except (KeyError, TypeError, ValueError):
                continue
    return sorted(rows, key=lambda r: (r.step, r.uav, r.cell))


def truth_cells(path: Path) -> np.ndarray:
    """Target cells from the simulator's evaluation record."""
    data = json.loads(path.read_text())
    return np.array(sorted(int(t["cell"]) for t in data["targets"]), dtype=np.int64)


def read_approach(path: Path) -> dict[int, float]:
    """The separation record's closest approach per step (horizontal metres; empty: no record).

    The separation record (`sim_vehicles.approach`): each step's closest approach of any pair of
    vehicles, horizontal metres, from the simulator at its physics rate or from the stand-alone
    camera's position streams (SITL, external vehicles). Empty when there is no record."""
    if not path.exists():
        return {}
    lines = path.read_text(encoding="utf-8", errors="replace").split("\n")[:-1]  # a last line cut short: out
    out: dict[int, float] = {}
    for row in csv.DictReader(lines):
        try:
            step, d = int(row["step"]), float(row["distance_m"])
        except (KeyError, TypeError, ValueError):
            continue
        out[step] = min(out.get(step, math.inf), d)
    return out


def read_vertical(path: Path) -> dict[int, float]:
    """Per step with a pair horizontally within R_s, the smallest vertical separation of such a pair.

    The separation record's third dimension: for each step in which some pair of vehicles came
    horizontally within R_s, the smallest vertical separation (m) of such a pair while it was (its
    `vertical_m`). Steps without such a pair, and records written without altitudes, are absent.
    Two aircraft are separated in 3D when R_s apart horizontally or `vertical_separation` apart
    vertically: a step here below that lost 3D separation."""
    if not path.exists():
        return {}
    lines = path.read_text(encoding="utf-8", errors="replace").split("\n")[:-1]
    out: dict[int, float] = {}
    for row in csv.DictReader(lines):
        try:
            step, v = int(row["step"]), float(row["vertical_m"])
        except (KeyError, TypeError, ValueError):  # no altitudes, not within R_s, a line cut short
            continue
        out[step] = min(out.get(step, math.inf), v)
    return out


def losses_3d(path: Path, mission: Mission) -> int:
    """The steps of the separation record at `path` that lost separation in three dimensions.

    Steps of the separation record at `path` in which two aircraft lost separation in three
    dimensions: horizontally within R_s and vertically closer than `Mission.vertical_floor` (a
    record without altitudes counts every step within R_s)."""
    vertical = read_vertical(path)
    r_s, floor = mission.comms.safety, mission.vertical_floor
    return sum(d <= r_s and vertical.get(k, 0.0) < floor for k, d in read_approach(path).items())


def mission_rows(logs: dict[int, dict[int, dict[str, float]]]) -> dict[int, dict[int, dict[str, float]]]:
    """The logs without the steps a companion flew after the mission's end.

    The logs without the steps a companion flew after the mission's end (`closing`: it flies
    out its trajectory in force before the hand-over); those are not part of the search."""
    return {i: {k: r for k, r in rows.items() if not r.get("closing")} for i, rows in logs.items()}


def logged_span(logs: dict[int, dict[int, dict[str, float]]]) -> range:
    """The steps to score, from the first the whole swarm logged to the last any UAV logged.

    The steps to score: from the first step every UAV has logged (the mission starts when the
    whole swarm is up) to the last step any UAV logged."""
    started = [min(rows) for rows in logs.values() if rows]
    if len(started) < len(logs):
        return range(0)
    return range(max(started), max(max(rows) for rows in logs.values()) + 1)


def evaluate(
    world: World,
    logs: dict[int, dict[int, dict[str, float]]],
    targets: np.ndarray,
    seconds: float,
    seed: int,
    approach: dict[int, float] | None = None,
    target_log: list[TargetRow] | None = None,
) -> RunResult:
    """A RunResult of the flown mission, scored as a batch-engine run is.

    A RunResult of the flown mission: eq. 30, targets found, coverage, lambda_2, min distance, and
    the closest approach between sampling moments: the separation record where there is one
    (`read_approach`), else the logged poses' distance at the sampling moments. With an imperfect
    sensor, `RunResult.sensing` holds the cells the companions confirmed (`target_log`, the first
    confirmation of each cell in a scored step; a confirmation before step 0 counts at step 0):
    the targets' confirmation steps and the false confirmations.

    Step 0 of the result is the first step every companion logged. A UAV with no row for a step (a
    companion that skipped it, a killed one whose log stops) keeps its latest logged pose for the
    link metrics, and its mean uncertainty; the vehicle itself keeps flying under its autopilot (the
    physics-rate record sees it).
    """
    m = world.mission
    n = m.n_uavs
    closing = {i: {k for k, r in rows.items() if r.get("closing")} for i, rows in logs.items()}
    logs = mission_rows(logs)
    span = logged_span(logs)
    steps = len(span)
    traj = np.zeros((steps, n, 3))
    tasks = np.full((steps, n), -1, dtype=np.int64)
    unc = np.zeros(steps)
    last = {i: rows[max(k for k in rows if k <= span.start)] for i, rows in logs.items() if steps}
    for k, step in enumerate(span):
        etas = []
        for i in range(n):
            row = logs[i].get(step) or last.get(i)
            if row is None:
                continue
            last[i] = row
            traj[k, i] = (row["x"], row["y"], row["heading"])
            tasks[k, i] = int(row["task"])
            etas.append(row["mean_eta"])
        unc[k] = float(np.mean(etas)) if etas else 1.0
    scorer = Scorer(world, targets, steps)
    for k, step in enumerate(span):
        scorer.record(k, traj[k, :, :2], unc[k])
        scorer.approach[k] = approach.get(step, math.inf) if approach else scorer.mind[k]
    for t in target_log or ():  # by step: the scorer keeps each cell's first confirmation
        if t.event == "confirmed" and t.step < span.stop and t.step not in closing.get(t.uav, ()):
            scorer.confirm(max(t.step - span.start, 0), (t.cell,))
    return scorer.result(0, seed, seconds, trajectory=traj, tasks=tasks)


def failed_criteria(world: World, result: RunResult, record: Path | None = None) -> list[str]:
    """The mission file's pass criteria that the run did not meet (empty: passed).

    Separation is judged in three dimensions over everything the separation record at `record`
    holds, start-up and hand-over included (`losses_3d`: a pair within R_s horizontally and closer
    vertically than `Mission.vertical_floor`); without a record, on the logged poses in 2D. A chord
    into the keep-out (`RunResult.keepout_entries`) always fails. A target counts as found once some
    UAV confirmed it (`RunResult.confirm_steps`: with a perfect sensor, once it was in view); a
    confirmed cell holding no target never counts, and fails past `max_false_confirmations`."""
    m, c = world.mission, world.mission.pass_criteria
    failures = []
    found = int(np.count_nonzero(result.confirm_steps >= 0))
    if found < min(c.min_targets_found, len(result.target_cells)):
        failures.append(f"targets found {found} < {c.min_targets_found}")
    false = result.false_confirmations
    if c.max_false_confirmations is not None and false > c.max_false_confirmations:
        failures.append(f"false confirmations {false} > {c.max_false_confirmations}")
    if c.require_connected and result.steps and result.lambda2.min() <= 0:
        failures.append(f"network disconnected (min lambda_2 = {result.lambda2.min():.4f})")
    if c.require_safe_distance and record is not None and record.exists():
        if lost := losses_3d(record, m):
            failures.append(
                f"separation lost at {lost} steps: within R_s = {m.comms.safety:g} m horizontally and "
                f"closer than {m.vertical_floor:g} m vertically"
            )
    elif c.require_safe_distance and result.steps and (closest := result.approach.min()) <= m.comms.safety:
        failures.append(f"closest approach {closest:.1f} m <= R_s = {m.comms.safety} m")
    if result.keepout_entries:
        failures.append(
            f"{result.keepout_entries} chords between sampling points entered a no-fly zone inflated by "
            f"safety.margin = {m.safety.margin:g} m or left the region's margin"
        )
    if result.steps == 0:
        failures.append("no step was flown")
    return failures


def _plan_rows(path: Path) -> list[dict[str, float]]:
    if not path.exists():
        return []
    with path.open(newline="") as f:
        rows = []
        for row in csv.DictReader(f):
            try:
                rows.append({k: float(v) for k, v in row.items()})
            except (TypeError, ValueError):  # a line cut short by a kill
                continue
        return rows


def flight_report(
    mission: Mission, out: Path, logs: dict[int, dict[int, dict[str, float]]], vertical: dict[int, float]
) -> FlightReport:
    """Plan versus flight, the poses outside the fence, and the vertical separation within R_s.

    Plan versus flight over the swarm (median, p95, max of the per-step position and heading
    errors, all UAVs and each), the logged poses outside the fence (region plus margin), and the
    vertical separation of the steps with a pair within R_s horizontally (`read_vertical`)."""
    per_uav, position, heading = {}, [], []
    for i in range(mission.n_uavs):
        rows = _plan_rows(out / f"uav{i}_plan.csv")
        p, h = [r["error_m"] for r in rows], [r["error_deg"] for r in rows]
        position += p
        heading += h
        per_uav[i] = UavTracking(len(rows), percentiles(p), percentiles(h))
    region = region_hull(mission)
    fence = fence_polygon(mission)
    poses = np.array([(r["x"], r["y"]) for rows in logs.values() for r in rows.values()]).reshape(-1, 2)
    beyond = (poses @ region.normals.T - region.offsets).max(axis=1) if len(poses) else np.zeros(0)
    return FlightReport(
        steps=len(position),
        position_m=percentiles(position),
        heading_deg=percentiles(heading),
        per_uav=per_uav,
        fence_margin_m=fence_margin(mission),
        outside_fence=int(np.count_nonzero(~np.asarray(fence.contains(poses[:, 0], poses[:, 1])))),
        max_beyond_region_m=float(max(beyond.max(), 0.0)) if len(beyond) else 0.0,
        steps_within_rs=len(vertical),
        closest_vertical_within_rs_m=min(vertical.values()) if vertical else None,
    )
