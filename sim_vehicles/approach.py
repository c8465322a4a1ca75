"""Ground truth of separation: the closest approach of every pair of vehicles, at the physics rate.

Each physics tick brings every vehicle's position; for the current sampling step (dT) the recorder
keeps each pair's smallest horizontal distance and, over the ticks in which the pair was
horizontally closer than `conflict_within` (R_s), its smallest vertical separation. When the step
ends it appends to a CSV file one row per pair that came within `report_within` metres (and always
the step's closest pair): `step,i,j,distance_m,vertical_m`; `vertical_m` is empty when the pair was
never within `conflict_within` in the step (or no altitudes were given), and the column is absent
when no `conflict_within` is given (a horizontal record). A simulator resumed from its state file
appends. A step whose `vertical_m` is below `vertical_separation` lost 3D separation
(docs/simulator.md); `companion.app.evaluation` reads the file (`read_approach`, `read_vertical`)
for the flown mission's evaluation and the fault matrix.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.core.geometry import FloatArray


class ApproachRecorder:
    """Per-step closest approaches of `n` vehicles, written to `path` as each step ends.

    It records the minimum pairwise horizontal distances, and the vertical separations while
    horizontally within `conflict_within`.
    """

    def __init__(
        self, path: Path, n: int, step_s: float, report_within: float, conflict_within: float = 0.0
    ) -> None:
        self.path, self.step_s, self.report_within = path, step_s, report_within
        self.conflict_within = conflict_within
        self.pairs = np.triu_indices(n, 1)
        self.step = -1
        self.minimum = np.full(len(self.pairs[0]), math.inf)
        self.vertical = np.full(len(self.pairs[0]), math.inf)
        path.parent.mkdir(parents=True, exist_ok=True)
        fresh = not path.exists() or path.stat().st_size == 0
        self._file = path.open("a", encoding="utf-8")  # a resumed simulator (`--state`) appends
        if fresh:
            self._file.write("step,i,j,distance_m" + (",vertical_m\n" if conflict_within > 0 else "\n"))
            self._file.flush()

    def update(self, t: float, x: FloatArray, y: FloatArray, z: FloatArray | None = None) -> None:
        """Take in the positions at vehicle time `t` (seconds); the tick belongs to step floor(t / dT).

        Altitudes `z` are in metres, if known.
        """
        if not len(self.minimum):
            return
        step = math.floor(t / self.step_s + 1e-9)
        if step != self.step:
            self._flush()
            self.step = step
            self.minimum[:] = math.inf
            self.vertical[:] = math.inf
        i, j = self.pairs
        d = np.hypot(x[i] - x[j], y[i] - y[j])
        np.minimum(self.minimum, d, out=self.minimum)
        if z is not None:
            dz = np.where(d < self.conflict_within, np.abs(z[i] - z[j]), math.inf)
            np.minimum(self.vertical, dz, out=self.vertical)

    def _flush(self) -> None:
        if self.step < 0 or not np.isfinite(self.minimum).any():
            return
        keep = self.minimum <= self.report_within
        keep[int(np.argmin(self.minimum))] = True
        i, j = self.pairs
        near = zip(i[keep], j[keep], self.minimum[keep], self.vertical[keep], strict=True)
        if self.conflict_within > 0:
            self._file.writelines(f"{self.step},{a},{b},{d:.3f},{_metres(v)}\n" for a, b, d, v in near)
        else:
            self._file.writelines(f"{self.step},{a},{b},{d:.3f}\n" for a, b, d, _ in near)
        self._file.flush()

    def close(self) -> None:
        self._flush()
        self._file.close()


def _metres(v: float) -> str:
    return f"{v:.3f}" if math.isfinite(v) else ""
