"""One step of the map as the page receives it: UAV poses, looks, finds, links and figures.

A frame is a compact JSON object (`frame_json`); the live listener and the replay loader build
the same frames, so the page draws a flying swarm and a finished run alike.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.core.connectivity import algebraic_connectivity, kruskal_mst, min_pair_distance


@dataclass(frozen=True)
class UavPose:
    """A UAV as drawn at one step.

    A UAV as drawn at one step: pose, task (-1: none), silent flag, planned path, and whether its
    companion steers it (`UavState.steered`)."""

    x: float
    y: float
    heading: float
    task: int = -1
    silent: bool = False
    plan: tuple[tuple[float, float], ...] = ()
    steered: bool = True


@dataclass(frozen=True)
class Figures:
    """The mission figures of one step: targets found so far, eq. 30, lambda_2, min distance."""

    found: int
    uncertainty: float
    lambda2: float
    min_distance: float


def links(positions: np.ndarray, comm_range: float) -> tuple[np.ndarray, float, float]:
    """The MST (eq. 26) edges, lambda_2 and the minimum pairwise distance of `positions` (N x 2)."""
    if len(positions) < 2:
        return np.zeros((0, 2), dtype=np.int64), 0.0, math.inf
    p = np.ascontiguousarray(positions, dtype=float)
    return kruskal_mst(p), algebraic_connectivity(p, comm_range), min_pair_distance(p)


def _num(v: float, digits: int) -> float | None:
    return round(float(v), digits) if math.isfinite(v) else None


def frame_json(
    step: int,
    uavs: Sequence[UavPose | None],
    looks: Sequence[int],
    found: Sequence[tuple[int, int]],
    figures: Figures,
    mst: np.ndarray,
) -> str:
    """The frame of `step` as the page reads it (a JSON string).

    The frame of `step`: `u` one entry per UAV ([x, y, heading, task, silent, steered] or null), `p` the
    planned paths, `l` the cells looked at in this step (with repeats: one look each), `f` the
    targets first found in this step as [cell, uav], `m` [found, eq. 30, lambda_2, min distance]
    and `t` the MST edges as UAV index pairs."""
    u = [
        None
        if s is None
        else [round(s.x, 3), round(s.y, 3), round(s.heading, 5), s.task, int(s.silent), int(s.steered)]
        for s in uavs
    ]
    p = [[] if s is None else [[round(x, 2), round(y, 2)] for x, y in s.plan] for s in uavs]
    m = [
        figures.found,
        _num(figures.uncertainty, 7),
        _num(figures.lambda2, 6),
        _num(figures.min_distance, 3),
    ]
    frame = {"k": step, "u": u, "p": p, "l": list(map(int, looks)), "f": [list(x) for x in found], "m": m}
    frame["t"] = mst.tolist()
    return json.dumps(frame, separators=(",", ":"))
