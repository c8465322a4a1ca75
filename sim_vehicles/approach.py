"""Ground truth of separation: the closest approach of every pair of vehicles, at the physics rate.

Every physics tick the simulator hands in all vehicles' horizontal positions; the recorder keeps,
for the current sampling step (dT), each pair's smallest distance, and when the step ends it
appends to a CSV file one row per pair that came within `report_within` metres (and always the
step's closest pair): `step,i,j,distance_m`; a simulator resumed from its state file appends. The
flown mission's evaluation and the fault matrix read it
(`companion.app.evaluation.read_approach`). Altitude layers are ignored on purpose: the safety
layer's separation is horizontal.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.core.geometry import FloatArray


class ApproachRecorder:
    """Per-step minimum pairwise horizontal distances of `n` vehicles, written to `path` as they end."""

    def __init__(self, path: Path, n: int, step_s: float, report_within: float) -> None:
        self.path, self.step_s, self.report_within = path, step_s, report_within
        self.pairs = np.triu_indices(n, 1)
        self.step = -1
        self.minimum = np.full(len(self.pairs[0]), math.inf)
        path.parent.mkdir(parents=True, exist_ok=True)
        fresh = not path.exists() or path.stat().st_size == 0
        self._file = path.open("a", encoding="utf-8")  # a resumed simulator (`--state`) appends
        if fresh:
            self._file.write("step,i,j,distance_m\n")
            self._file.flush()

    def update(self, t: float, x: FloatArray, y: FloatArray) -> None:
        """Positions at vehicle time `t` (seconds): the tick belongs to step floor(t / dT)."""
        if not len(self.minimum):
            return
        step = math.floor(t / self.step_s + 1e-9)
        if step != self.step:
            self._flush()
            self.step = step
            self.minimum[:] = math.inf
        i, j = self.pairs
        np.minimum(self.minimum, np.hypot(x[i] - x[j], y[i] - y[j]), out=self.minimum)

    def _flush(self) -> None:
        if self.step < 0 or not np.isfinite(self.minimum).any():
            return
        keep = self.minimum <= self.report_within
        keep[int(np.argmin(self.minimum))] = True
        i, j = self.pairs
        near = zip(i[keep], j[keep], self.minimum[keep], strict=True)
        self._file.writelines(f"{self.step},{a},{b},{d:.3f}\n" for a, b, d in near)
        self._file.flush()

    def close(self) -> None:
        self._flush()
        self._file.close()
