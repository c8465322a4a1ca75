"""The flown separation: the closest approach of any two vehicles in each sampling step, measured at
the physics rate from the simulator's own state (`--separation FILE`).

One CSV row per step k (the ticks of [t_k, t_k+1)): `step, closest_m, uav_a, uav_b`, flushed as
it is written, appended to when the simulator resumes.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

COLUMNS = "step,closest_m,uav_a,uav_b\n"


class SeparationLog:
    """Per-step minimum pairwise horizontal distance of the fleet, written to `path`."""

    def __init__(self, path: Path, substeps: int) -> None:
        fresh = not path.exists() or path.stat().st_size == 0
        self._f = path.open("a")
        if fresh:
            self._f.write(COLUMNS)
            self._f.flush()
        self.substeps = substeps
        self._step = -1
        self._best = (math.inf, -1, -1)

    def observe(self, tick: int, x: np.ndarray, y: np.ndarray) -> None:
        """The fleet's positions at `tick`; a step's row is written when the next step begins."""
        step = tick // self.substeps
        if step != self._step:
            self._flush()
            self._step, self._best = step, (math.inf, -1, -1)
        n = x.shape[0]
        if n < 2:
            return
        d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
        d[np.diag_indices(n)] = np.inf
        a, b = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[a, b] < self._best[0]:
            self._best = (float(d[a, b]), int(min(a, b)), int(max(a, b)))

    def _flush(self) -> None:
        if self._step >= 0 and self._best[1] >= 0:
            closest, a, b = self._best
            self._f.write(f"{self._step},{closest:.3f},{a},{b}\n")
            self._f.flush()

    def close(self) -> None:
        self._flush()
        self._f.close()


def read_separation(path: Path) -> dict[int, tuple[float, int, int]]:
    """step -> (closest approach in metres, uav a, uav b); of a repeated step (a resumed
    simulator's), the smaller."""
    out: dict[int, tuple[float, int, int]] = {}
    if not path.exists():
        return out
    for line in path.read_text().splitlines()[1:]:
        parts = line.split(",")
        if len(parts) != 4:
            continue
        try:
            k, d, a, b = int(parts[0]), float(parts[1]), int(parts[2]), int(parts[3])
        except ValueError:
            continue
        if k not in out or d < out[k][0]:
            out[k] = (d, a, b)
    return out
