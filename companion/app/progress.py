"""`uavsearch run`'s live progress: the lines it prints while the swarm flies.

The step shown is the number of steps scored so far, counted as the run's summary counts them
(`evaluation.logged_span` of the companions' logs without their closing steps): the last line
printed, once the run is over, shows the summary's step count. Until every companion has logged a
step, one line says which companions the run waits for and how long it has waited, printed again
only when that set changes or every `WAIT_REPEAT_S` seconds.
"""

from __future__ import annotations

import numpy as np

from companion.app.evaluation import logged_span, mission_rows
from companion.core.connectivity import algebraic_connectivity, min_pair_distance
from companion.core.world import World

WAIT_REPEAT_S = 60.0


class Progress:
    """The progress lines of one run; `update` returns the line to print now, if any."""

    def __init__(self, world: World, targets_xy: np.ndarray, started: float) -> None:
        self.world = world
        self.xy = targets_xy
        self.seen = np.zeros(len(targets_xy), dtype=bool)
        self.started = started
        self._waiting: tuple[int, ...] | None = None
        self._waiting_said = -np.inf
        self._step = -1

    def update(
        self,
        logs: dict[int, dict[int, dict[str, float]]],
        new: dict[int, list[dict[str, float]]],
        now: float,
        final: bool = False,
    ) -> str | None:
        """The progress line for the companions' logs `logs` at time `now`, or None when it would repeat.

        `new` holds the rows since the last call; `now` is on the clock `started` is on. None when the
        line would repeat the last one; with `final` (the run is over) the line is given anyway, once
        every companion has logged.
        """
        for new_rows in new.values():  # targets in view of the search's rows (not the closing steps)
            flown = [r for r in new_rows if not r.get("closing")]
            if flown:
                p = np.array([(r["x"], r["y"]) for r in flown])
                d2 = np.sum((p[:, None, :] - self.xy[None, :, :]) ** 2, axis=-1)
                self.seen |= (d2 <= self.world.grid.fov_radius2).any(axis=0)
        rows = mission_rows(logs)
        waiting = tuple(i for i, r in rows.items() if not r)
        if waiting:
            if final:
                return None
            if waiting == self._waiting and now - self._waiting_said < WAIT_REPEAT_S:
                return None
            self._waiting, self._waiting_said = waiting, now
            who = ", ".join(str(i) for i in waiting)
            return (
                f"waiting for the companions of UAV {who} to fly their first step "
                f"({now - self.started:.0f} s since the start: vehicles starting, take-off)"
            )
        step = len(logged_span(rows))
        if step == self._step and not final:
            return None
        self._step = step
        latest = [r[max(r)] for r in rows.values()]
        pos = np.array([(r["x"], r["y"]) for r in latest])
        unc = float(np.mean([r["mean_eta"] for r in latest]))
        line = f"step {step:5d}  targets {int(self.seen.sum())}/{len(self.xy)}  mean uncertainty {unc:.4f}"
        if len(pos) < 2:  # one UAV: no link, no pair
            return line
        lam = algebraic_connectivity(pos, self.world.mission.comms.range)
        return f"{line}  lambda_2 {lam:.4f}  min distance {min_pair_distance(pos):7.1f} m"
