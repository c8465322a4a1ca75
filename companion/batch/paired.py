"""Paired runs over sets of missions, shared by `uavsearch evaluate` and `uavsearch tune`.

Run r of mission m is the same mission instance for every algorithm and every weight candidate
(common random numbers): the run seed is the mission's seed, so its CVT draw, targets and radio
draws, and with random starts its start layout, depend on (mission, r) only. `measure` is the one
place where this module's callers map runs (through `montecarlo.run_specs`).
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import msgspec
import numpy as np

from companion.batch.confirmation import confirm_time, never_confirmed
from companion.batch.engine import RunResult
from companion.batch.executors import RunExecutor
from companion.batch.montecarlo import RunSpec, run_specs
from companion.batch.starts import random_start
from companion.contracts.mission import Mission, MissionError
from companion.core.feasibility import load_mission, validate

METRICS = ("target_time", "mean_uncertainty")
# reported per run beside METRICS (`measure(confirmations=True)`): an imperfect sensor's
# confirmations (`confirmation`); for a perfect one, target_time, the unfound targets and 0
CONFIRMATIONS = ("confirm_time", "never_confirmed", "false_confirmations")


def run_metrics(r: RunResult) -> tuple[float, float]:
    """A run's two figures of merit, both lower-is-better: mean target time and eq. 30's mean.

    The first is the mean step at which its targets were first seen (an unfound target counting as
    the run's length; 0 without targets). The second is the global average uncertainty of eq. 30
    averaged over the run's steps (the area under the coverage curve).
    """
    time = float(r.target_times().mean()) if len(r.target_steps) else 0.0
    return time, float(r.uncertainty.mean())


def specs_grid(
    missions: Sequence[Mission],
    algorithms: Sequence[str],
    runs: int,
    steps: int,
    layouts: tuple[str, ...] = (),
    first_run: int = 0,
) -> list[RunSpec]:
    """One spec per (mission, algorithm, run), in that order.

    The runs are first_run .. first_run + runs - 1. Run r of a mission has the mission's seed and,
    with `layouts`, the start layout `random_start` draws for (mission, seed, r).
    """
    specs = []
    indices = range(first_run, first_run + runs)
    for m in missions:
        starts = {r: random_start(m, m.seed, r, layouts)[0] if layouts else m for r in indices}
        specs += [RunSpec(starts[r].with_algorithm(a), m.seed, r, steps) for a in algorithms for r in indices]
    return specs


def measure(
    specs: Sequence[RunSpec],
    executor: RunExecutor | None = None,
    advance: Callable[[], object] | None = None,
    confirmations: bool = False,
) -> np.ndarray:
    """`run_metrics` of every spec, shape (len(specs), len(METRICS)), in spec order.

    They are computed on `executor` (default: a local pool of every core); `advance` is called as
    each run comes back. With `confirmations`, each row goes on with the run's CONFIRMATIONS.
    """
    out = np.empty((len(specs), len(METRICS) + len(CONFIRMATIONS) * confirmations))
    for i, r in enumerate(run_specs(list(specs), executor=executor, on_result=advance)):
        extra = (confirm_time(r), never_confirmed(r), r.false_confirmations) if confirmations else ()
        out[i] = (*run_metrics(r), *extra)
    return out


def write_json(path: Path, content: object) -> None:
    """Strict JSON: a NaN (an interval from one observation) is written as null."""

    def clean(v: object) -> object:
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [clean(x) for x in v]
        return v

    path.write_text(json.dumps(clean(content), indent=2, allow_nan=False) + "\n")


def load_weights(path: str | Path) -> dict:
    """The `[algorithm]` table of a TOML file (a tune's weights.toml, or a mission file)."""
    p = Path(path)
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MissionError(str(p), "(file)", exc.strerror or str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise MissionError(str(p), "(syntax)", str(exc)) from None
    table = raw.get("algorithm")
    if not isinstance(table, dict):
        raise MissionError(str(p), "algorithm", "the file has no [algorithm] table")
    if "name" in table:
        raise MissionError(str(p), "algorithm.name", "the command chooses the algorithms, not the weights")
    return table


def apply_weights(mission: Mission, weights: Mapping[str, object], source: str) -> Mission:
    """The mission with `[algorithm]` fields replaced by `weights` (nested tables merged), validated.

    A bad field or value is a MissionError naming `source`.
    """

    def merge(base: dict, new: Mapping[str, object]) -> dict:
        out = dict(base)
        for key, value in new.items():
            old = out.get(key)
            out[key] = merge(old, value) if isinstance(old, dict) and isinstance(value, Mapping) else value
        return out

    raw = msgspec.to_builtins(mission)
    raw["algorithm"] = merge(raw["algorithm"], weights)
    return validate(raw, source)


def load_missions(folder: str | Path) -> list[Mission]:
    """Every `*.toml` mission file of a folder, by name."""
    paths = sorted(Path(folder).glob("*.toml"))
    if not paths:
        raise ValueError(f"{folder}: no mission files (*.toml)")
    return [load_mission(p) for p in paths]
