"""`uavsearch sensing-study`: the algorithms under imperfect sensing (issue 37), a grid of Pd x Pf.

A cell is (mission, Pd, Pf): the mission with `[sensor] pd`, `pf` set (Pd the same over the field
of view). Every algorithm flies runs 0 .. R-1 of every cell with the mission's seed (or --seed),
so run r is the same instance (targets, radio and sensor draws) for all three: the comparison is
paired run by run. The runs go to the Monte Carlo executors (`montecarlo.run_specs`); each cell's
per-run rows are written to `cells/` as soon as the cell is complete, and a study started again
in the same folder with the same definition (study.json) reads the cells there instead of
flying them again. From the rows: summary.csv (per cell and algorithm, `confirmation`'s metrics
with 95 % intervals and POS at a quarter, half and the end of the run), paired.csv (proposed -
baseline on the time to a confirmed detection, Student t 95 % intervals), pos_curves.csv, the
plots of `sensing_plots` and results_table.md (`sensing_tables`).
"""

from __future__ import annotations

import csv
import json
import os
import sys
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from companion.batch.confirmation import pos_curve
from companion.batch.engine import RunResult
from companion.batch.executors import RunExecutor
from companion.batch.montecarlo import RunSpec, ci95, run_specs
from companion.batch.progress import run_progress
from companion.batch.report import mean_band
from companion.batch.stats import mean_ci
from companion.contracts.mission import Mission
from companion.core.feasibility import validate

PD_VALUES = (1.0, 0.9, 0.7)
PF_VALUES = (0.0, 0.01, 0.05)
PROPOSED = "proposed"


@dataclass(frozen=True)
class Cell:
    """One mission with one detector: Pd (the same over the field of view) and Pf."""

    mission: Mission
    pd: float
    pf: float

    @property
    def name(self) -> str:
        """The cell's file stem: mission, Pd, Pf."""
        return f"{self.mission.name}_pd{self.pd:g}_pf{self.pf:g}"


def with_sensor(mission: Mission, pd: float, pf: float) -> Mission:
    """The mission with `[sensor] pd = pd, pf = pf` and no `pd_edge` (Pd flat), validated."""
    raw = msgspec.to_builtins(mission)
    raw["sensor"].update(pd=pd, pf=pf)
    raw["sensor"].pop("pd_edge", None)
    return validate(raw, f"{mission.name} (pd {pd:g}, pf {pf:g})")


def grid(missions: Sequence[Mission], pds: Sequence[float], pfs: Sequence[float]) -> list[Cell]:
    """Every (mission, Pd, Pf), in that order."""
    return [Cell(with_sensor(m, pd, pf), pd, pf) for m in missions for pd in pds for pf in pfs]


class RunRow(msgspec.Struct, frozen=True):
    """One run of a cell: each target's first-sight and confirmation steps (-1 never)."""

    mission: str
    pd: float
    pf: float
    algorithm: str
    run: int
    seed: int
    steps: int
    target_steps: list[int]
    confirm_steps: list[int]
    false_confirmations: int

    @property
    def first_sight_time(self) -> float:
        """Mean first-sight step of the targets (never: the run's length; 0 without targets)."""
        return _mean_time(self.target_steps, self.steps)

    @property
    def confirm_time(self) -> float:
        """Mean step of the targets' confirmations (never: the run's length; 0 without targets)."""
        return _mean_time(self.confirm_steps, self.steps)

    @property
    def never_confirmed(self) -> int:
        """Targets no UAV ever confirmed."""
        return sum(s < 0 for s in self.confirm_steps)


def _mean_time(steps: Sequence[int], length: int) -> float:
    return float(np.mean([s if s >= 0 else length for s in steps])) if steps else 0.0


def run_row(cell: Cell, r: RunResult) -> RunRow:
    """The `RunRow` of run `r` of `cell`."""
    return RunRow(
        cell.mission.name,
        cell.pd,
        cell.pf,
        r.algorithm,
        r.run,
        r.seed,
        r.steps,
        r.target_steps.tolist(),
        r.confirm_steps.tolist(),
        r.false_confirmations,
    )


ROW_COLUMNS = RunRow.__struct_fields__


def _steps_text(steps: Sequence[int]) -> str:
    return " ".join(str(s) for s in steps)


def write_rows(path: Path, rows: Sequence[RunRow]) -> None:
    """A cell's rows as CSV (step lists space-separated), written whole or not at all."""
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(ROW_COLUMNS)
        for r in rows:
            w.writerow(
                [
                    r.mission,
                    f"{r.pd:g}",
                    f"{r.pf:g}",
                    r.algorithm,
                    r.run,
                    r.seed,
                    r.steps,
                    _steps_text(r.target_steps),
                    _steps_text(r.confirm_steps),
                    r.false_confirmations,
                ]
            )
    os.replace(tmp, path)


def read_rows(path: Path) -> list[RunRow]:
    """The rows `write_rows` wrote."""
    with path.open(newline="") as f:
        raw = list(csv.DictReader(f))
    numbers = ("run", "seed", "steps", "false_confirmations")
    return [
        RunRow(
            **{k: int(v[k]) for k in numbers},
            mission=v["mission"],
            pd=float(v["pd"]),
            pf=float(v["pf"]),
            algorithm=v["algorithm"],
            target_steps=[int(s) for s in v["target_steps"].split()],
            confirm_steps=[int(s) for s in v["confirm_steps"].split()],
        )
        for v in raw
    ]


class Definition(msgspec.Struct, frozen=True):
    """study.json: what a study folder holds; a study resumed there must have the same."""

    missions: list[str]
    pd: list[float]
    pf: list[float]
    algorithms: list[str]
    runs: int
    steps: int
    seed: int | None  # None: each mission's own


def open_folder(out: Path, definition: Definition) -> None:
    """Make `out` (and out/cells) for `definition`; a folder holding another study is an error."""
    (out / "cells").mkdir(parents=True, exist_ok=True)
    path = out / "study.json"
    mine = msgspec.to_builtins(definition)
    if path.exists():
        theirs = json.loads(path.read_text())
        if theirs != mine:
            raise ValueError(f"{out} holds another study ({path}: {theirs}); use another --out")
    path.write_text(json.dumps(mine, indent=2) + "\n")


def fly(
    cells: Sequence[Cell],
    algorithms: Sequence[str],
    definition: Definition,
    out: Path,
    executor: RunExecutor,
    progress: bool = True,
) -> dict[str, list[RunRow]]:
    """Every cell's rows by cell name: those in out/cells, the others flown and written there.

    A cell's runs are `definition.runs` per algorithm, algorithm by algorithm; its file is written
    once all of them are in, so an interrupted study loses only the cells not yet complete.
    """
    folder = out / "cells"
    done = {c.name: read_rows(folder / f"{c.name}.csv") for c in cells if (folder / f"{c.name}.csv").exists()}
    todo = [c for c in cells if c.name not in done]
    if done and progress:
        print(f"resuming: {len(done)} of {len(cells)} cells already in {folder}", file=sys.stderr)
    runs, per_cell = definition.runs, len(algorithms) * definition.runs
    specs = [
        RunSpec(c.mission.with_algorithm(a), c.mission.seed if definition.seed is None else definition.seed,
                r, definition.steps)
        for c in todo
        for a in algorithms
        for r in range(runs)
    ]  # fmt: skip
    label = f"sensing study: {len(todo)} of {len(cells)} cells, {len(specs)} runs on {executor.description}"
    with run_progress(len(specs), label, progress and bool(specs)) as advance:
        rows: list[RunRow] = []
        for i, result in enumerate(run_specs(specs, executor=executor, on_result=advance)):
            cell = todo[i // per_cell]
            rows.append(run_row(cell, result))
            if len(rows) == per_cell:
                write_rows(folder / f"{cell.name}.csv", rows)
                done[cell.name], rows = rows, []
    return {c.name: done[c.name] for c in cells}


def by_algorithm(rows: Sequence[RunRow]) -> dict[str, list[RunRow]]:
    """A cell's rows per algorithm, in run order."""
    out: dict[str, list[RunRow]] = {}
    for r in sorted(rows, key=lambda r: r.run):
        out.setdefault(r.algorithm, []).append(r)
    return out


def pos_band(rows: Sequence[RunRow]) -> tuple[np.ndarray, np.ndarray]:
    """POS over the runs: its mean per step and the 95 % half-width (`report.mean_band`)."""
    return mean_band(np.array([pos_curve(np.array(r.confirm_steps), r.steps) for r in rows]))


class CellSummary(msgspec.Struct, frozen=True):
    """summary.csv: one cell and algorithm, means over its runs with 95 % half-widths (ci95).

    pos_quarter, pos_half, pos_end: POS at steps // 4, steps // 2 and the last step."""

    mission: str
    pd: float
    pf: float
    algorithm: str
    runs: int
    steps: int
    confirm_time: float
    confirm_time_ci95: float
    first_sight_time: float
    false_confirmations: float
    false_confirmations_ci95: float
    never_confirmed: float
    never_confirmed_ci95: float
    pos_quarter: float
    pos_half: float
    pos_end: float


def summarize_cell(rows: Sequence[RunRow]) -> CellSummary:
    """The `CellSummary` of one algorithm's rows in one cell."""
    first = rows[0]
    confirm = np.array([r.confirm_time for r in rows])
    false = np.array([r.false_confirmations for r in rows], dtype=float)
    never = np.array([r.never_confirmed for r in rows], dtype=float)
    pos, _ = pos_band(rows)
    return CellSummary(
        first.mission,
        first.pd,
        first.pf,
        first.algorithm,
        len(rows),
        first.steps,
        float(confirm.mean()),
        ci95(confirm),
        float(np.mean([r.first_sight_time for r in rows])),
        float(false.mean()),
        ci95(false),
        float(never.mean()),
        ci95(never),
        float(pos[first.steps // 4]),
        float(pos[first.steps // 2]),
        float(pos[-1]),
    )


class PairedRow(msgspec.Struct, frozen=True):
    """paired.csv: proposed - baseline on the time to a confirmed detection, over matching runs."""

    mission: str
    pd: float
    pf: float
    baseline: str
    runs: int
    proposed: float
    baseline_value: float
    difference: float
    difference_low: float
    difference_high: float


def paired_rows(rows: Sequence[RunRow], algorithms: Sequence[str]) -> list[PairedRow]:
    """One cell's `PairedRow` per baseline: the runs both flew, matched by run index."""
    per = by_algorithm(rows)
    if PROPOSED not in per:
        return []
    mine = {r.run: r.confirm_time for r in per[PROPOSED]}
    out = []
    for baseline in (a for a in algorithms if a != PROPOSED):
        theirs = {r.run: r.confirm_time for r in per[baseline]}
        runs = sorted(mine.keys() & theirs.keys())
        a, b = np.array([mine[r] for r in runs]), np.array([theirs[r] for r in runs])
        d = mean_ci(a - b)
        first = rows[0]
        out.append(
            PairedRow(first.mission, first.pd, first.pf, baseline, len(runs), float(a.mean()),
                      float(b.mean()), d.estimate, d.low, d.high)
        )  # fmt: skip
    return out


def write_table(path: Path, rows: Sequence[msgspec.Struct]) -> None:
    """Structs as a CSV, one column per field (floats to 6 significant digits)."""
    fields = list(type(rows[0]).__struct_fields__) if rows else []
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(fields)
        for row in rows:
            w.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in msgspec.structs.astuple(row)])


def write_pos_curves(path: Path, flown: Mapping[str, Sequence[RunRow]]) -> None:
    """pos_curves.csv: per cell, algorithm and step, POS with its 95 % half-width."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["mission", "pd", "pf", "algorithm", "step", "pos", "pos_ci95"])
        for rows in flown.values():
            for name, mine in by_algorithm(rows).items():
                pos, ci = pos_band(mine)
                r = mine[0]
                w.writerows(
                    [r.mission, f"{r.pd:g}", f"{r.pf:g}", name, k, f"{p:.4f}", f"{c:.4f}"]
                    for k, (p, c) in enumerate(zip(pos, ci, strict=True))
                )


def summaries(flown: Mapping[str, Sequence[RunRow]]) -> Iterator[CellSummary]:
    """Every cell's `CellSummary` per algorithm, in cell order."""
    for rows in flown.values():
        yield from (summarize_cell(mine) for mine in by_algorithm(rows).values())
