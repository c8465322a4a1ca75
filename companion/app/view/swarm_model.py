"""What a listener knows of the swarm, step by step, from the bundles the UAVs put on the mesh.

Bundles arrive in any order; `SwarmModel` holds them by stamp and closes step k (turns it into a
frame) once every UAV expected at k has reported, or a later step is well under way, or k has
waited `hold_s` seconds; what closing a step makes of the bundles (poses, the fused map for eq.
30, targets found): docs/view.md, "Closing a step". Pure: no I/O and no clock (the caller hands in
`now`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.app.view.frames import Figures, UavPose, frame_json, links
from companion.core.messages import CoverageMsg, StateMsg
from companion.core.uncertainty import apply_looks, global_average_uncertainty
from companion.node.mesh import Bundle

LAG_STEPS = 3  # a step closes once a bundle this many steps later has arrived
HOLD_S = 2.0  # ... or once it has waited this long for its last UAVs


@dataclass(frozen=True)
class Report:
    """What one UAV said about itself at one step."""

    uav: int
    stamp: int
    pose: UavPose
    cells: tuple[int, ...]
    detections: tuple[int, ...]

    @classmethod
    def of(cls, bundle: Bundle) -> Report:
        """The report in a (validated) bundle."""
        pose = UavPose(bundle.x, bundle.y, math.nan)
        cells: tuple[int, ...] = ()
        detections: tuple[int, ...] = ()
        for msg in bundle.messages:
            if isinstance(msg, StateMsg):
                s = msg.state
                pose = UavPose(s.x, s.y, s.heading, s.task, False, tuple(s.plan), s.steered)
            elif isinstance(msg, CoverageMsg):
                cells, detections = cells + msg.cells, detections + msg.detections
        return cls(bundle.sender, bundle.stamp, pose, cells, detections)


class SwarmModel:
    """Turns reports into frames (JSON strings, see `frames.frame_json`), in step order."""

    def __init__(
        self,
        n_uavs: int,
        n_cells: int,
        eta0: float,
        gamma: float,
        comm_range: float,
        peer_timeout_steps: int,
        hold_s: float = HOLD_S,
    ) -> None:
        self.n, self.gamma, self.comm_range = n_uavs, gamma, comm_range
        self.timeout, self.hold_s = peer_timeout_steps, hold_s
        self.etas = np.full((n_uavs, n_cells), eta0)
        self.pending: dict[int, dict[int, Report]] = {}
        self.arrived: dict[int, float] = {}  # stamp -> when its first report came
        self.last: dict[int, Report] = {}  # uav -> its latest closed report
        self.previous: dict[int, Report] = {}  # the reports of the last closed step
        self.closed = -1  # the last closed step
        self.found: dict[int, tuple[int, int]] = {}  # cell -> (step, uav)
        self.departed: set[int] = set()  # UAVs whose liveliness token went
        self.late = 0  # reports for a step already closed

    def set_alive(self, uav: int, alive: bool) -> None:
        """A liveliness change: a departed UAV is silent and no step waits for it."""
        if alive:
            self.departed.discard(uav)
        else:
            self.departed.add(uav)

    def add(self, report: Report, now: float) -> None:
        if report.stamp <= self.closed:
            self.late += 1
            return
        self.pending.setdefault(report.stamp, {}).setdefault(report.uav, report)
        self.arrived.setdefault(report.stamp, now)

    def _expected(self) -> set[int]:
        """The UAVs a step waits for: those that reported at the last closed step and did not leave."""
        return set(self.previous) - self.departed

    def close_ready(self, now: float) -> list[str]:
        """Close every step that is ready, oldest first; returns their frames."""
        frames = []
        while self.pending:
            k = min(self.pending)
            reports = self.pending[k]
            newest = max(self.pending)
            complete = bool(self.previous) and self._expected() <= set(reports)
            if not (complete or newest >= k + LAG_STEPS or now - self.arrived[k] >= self.hold_s):
                break
            del self.pending[k], self.arrived[k]
            frames.append(self._close(k, reports))
        return frames

    def _close(self, k: int, reports: dict[int, Report]) -> str:
        before = self.last.copy()
        prev = self.previous if self.closed == k - 1 else {}
        looks: list[int] = []
        for i, r in sorted(reports.items()):
            own = np.array(r.cells, dtype=np.int64)
            looks.extend(r.cells)
            mine = prev.get(i) or before.get(i)
            heard = [
                c
                for j, q in sorted(prev.items())
                if j != i
                and mine is not None
                and math.hypot(q.pose.x - mine.pose.x, q.pose.y - mine.pose.y) <= self.comm_range
                for c in q.cells
            ]
            apply_looks(self.etas[i], np.concatenate([own, np.array(heard, dtype=np.int64)]), self.gamma)
            if math.isnan(r.pose.heading):  # a bundle without its state: keep the last heading
                heading = before[i].pose.heading if i in before else 0.0
                r = Report(i, k, UavPose(r.pose.x, r.pose.y, heading), r.cells, r.detections)
            self.last[i] = r
        new_found = []
        for i, r in sorted(reports.items()):
            for cell in r.detections:
                if cell not in self.found:
                    self.found[cell] = (k, i)
                    new_found.append((cell, i))
        self.previous, self.closed = reports, k
        seen = sorted(self.last)
        poses: list[UavPose | None] = [None] * self.n
        for u in seen:
            r = self.last[u]
            silent = u in self.departed or k - r.stamp > self.timeout
            plan = r.pose.plan if r.stamp == k else ()
            poses[u] = UavPose(r.pose.x, r.pose.y, r.pose.heading, r.pose.task, silent, plan, r.pose.steered)
        positions = np.array([(self.last[u].pose.x, self.last[u].pose.y) for u in seen])
        mst, lam, mind = links(positions, self.comm_range)
        unc = global_average_uncertainty([self.etas[u] for u in seen])
        mst_ids = np.array(seen, dtype=np.int64)[mst] if len(mst) else mst
        return frame_json(k, poses, looks, new_found, Figures(len(self.found), unc, lam, mind), mst_ids)
