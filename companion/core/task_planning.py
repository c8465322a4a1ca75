"""The mission planning system of one agent: bids (eq. 15), the local auction, eqs. 20-21.

`TaskPlanning` is the part of `Agent` (algorithm "proposed") that bids for tasks, runs the local
auction (Algorithm 2) over the CVT's tasks and the confirmation tasks of candidate cells
(docs/algorithm.md, "Imperfect sensing"), and reevaluates the task held.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from companion.core.auction import claim_priority, local_auction
from companion.core.belief import Belief
from companion.core.geometry import FloatArray
from companion.core.messages import UavState
from companion.core.routes import STRAIGHT
from companion.core.tasks import (
    TaskSet,
    Weights,
    auction_table,
    bid_rewards,
    confirm_bids,
    keep_task,
    task_completion,
    task_costs,
)
from companion.core.world import World

# a bidder's rewards (`BidsMsg`): one per CVT task, then the candidate cells and their rewards
Bids = tuple[tuple[float, ...], tuple[int, ...], tuple[float, ...]]


class TaskPlanning:
    """Algorithm 2 with eqs. 15 and 20-21 for the agent of UAV `uav` (mixed into `Agent`)."""

    world: World
    uav: int
    eta: FloatArray
    covered: np.ndarray
    candidates: np.ndarray
    belief: Belief
    peers: dict[int, UavState]
    task: int
    task_reward: float
    bids: Bids | None
    bid_stamp: int
    _tasks: TaskSet | None

    @cached_property
    def _costs(self) -> Weights:
        """The world's `CostWeights` as a plain tuple (a cheaper argument to the compiled kernels)."""
        return tuple(self.world.costs)  # type: ignore[return-value]

    def _my_bids(self, position: FloatArray, mst_nbrs: FloatArray) -> Bids:
        """Eq. 15 rewards, filtered by eq. 21 and the task held, and the confirmation tasks' rewards.

        Eq. 15 rewards; zero for tasks this UAV could not keep (eq. 21: complete or too costly)
        and, when it holds a task, for tasks not worth more than the task it holds (Algorithm 2's
        greedy bidder would not take them: lines 10-11). Then `confirm_bids` for the candidates."""
        w, tasks = self.world, self._tasks
        assert tasks is not None
        a = w.mission.algorithm
        n_tasks = tasks[2].shape[0]
        held = self.task if self.task < n_tasks else -1
        out = bid_rewards(
            self.eta, w.prior, self.covered, tasks, a.v_max, a.c_max, position, mst_nbrs, self._costs, held
        )
        out = out if out.size else np.zeros(n_tasks)  # every task complete
        floor = self._confirm_reward(position, mst_nbrs)[0] if self.task >= n_tasks else 0.0
        if floor > 0:
            out[out <= floor] = 0.0
        cvt = tuple(out.tolist())
        if not self.candidates.size:
            return cvt, (), ()
        cells, rewards = confirm_bids(
            self.candidates, self.belief.posterior(self.candidates), w.grid.centres, position, mst_nbrs,
            self._costs, a.c_max,
        )  # fmt: skip
        if self.task >= 0:
            current = self.task_reward if self.task < n_tasks else floor
            rewards = np.where(rewards > current, rewards, 0.0)
        keep = rewards > 0
        return cvt, tuple(cells[keep].tolist()), tuple(rewards[keep].tolist())

    def _confirm_reward(self, position: FloatArray, mst_nbrs: FloatArray) -> tuple[float, float]:
        """The held confirmation task's reward (eq. 15 with eq. 18's capped cost) and its eq. 21 cost."""
        w = self.world
        assert self.world.tessellation is not None
        c = self.task - self.world.tessellation.n_tasks
        if not (self.candidates == c).any():
            return 0.0, math.inf
        gen = w.grid.centres[c : c + 1]
        capped, uncapped = task_costs(
            position, mst_nbrs, gen, np.array([w.costs.fov_area]), self._costs, STRAIGHT, 0
        )
        return float(self.belief.posterior(np.array([c]))[0] / capped[0]), float(uncapped[0])

    def _plan_task(
        self, k: int, position: FloatArray, mst_nbrs: FloatArray, bids: dict[int, Bids]
    ) -> bool:
        """Algorithm 2 + synchronisation + eqs. 20-21; returns True when bids go out this step.

        Every UAV is a greedy bidder (Algorithm 2): it announces its rewards at step k (`BidsMsg`),
        and at k+1 runs the local auction over the bids it heard, the tasks held by the UAVs it knows
        of removed; a task it wins replaces the one it holds (its bids already exclude tasks worth
        less). The tasks are the CVT's and one confirmation task per candidate cell heard of
        (`auction_table`). The held task is then reevaluated (eqs. 20-21) and dropped on a
        conflicting claim of a higher priority."""
        tess = self.world.tessellation
        assert tess is not None
        if self.bids is not None and self.bid_stamp == k - 1:
            bidders = [self.uav, *sorted(bids)]
            held = [s.task for s in self.peers.values()] + [self.task]
            rows = [self.bids, *(bids[u] for u in sorted(bids))]
            ids, table, available = auction_table(tess.n_tasks, rows, held)
            won = local_auction(bidders, table, available).get(self.uav)
            if won is not None:
                self.task, self.task_reward = int(ids[won[0]]), won[1]
        if self.task >= 0:
            mine = claim_priority(self.task_reward, self.uav)
            lost = any(
                s.task == self.task and claim_priority(s.task_reward, u) > mine for u, s in self.peers.items()
            )
            if lost or not self._keep(position, mst_nbrs):
                self.task, self.task_reward = -1, 0.0
        self.bids = None
        rewards = self._my_bids(position, mst_nbrs)
        if max((*rewards[0], *rewards[2]), default=0.0) > 0:  # nothing left to win: no auction
            self.bids, self.bid_stamp = rewards, k
        return self.bids is not None

    def _keep(self, position: FloatArray, mst_nbrs: FloatArray) -> bool:
        """Eqs. 20-21 for the held task; a confirmation task is complete once its cell is decided."""
        w, tess = self.world, self.world.tessellation
        assert tess is not None
        a = w.mission.algorithm
        j = self.task
        if j >= tess.n_tasks:
            reward, cost = self._confirm_reward(position, mst_nbrs)
            return reward > 0 and keep_task(0.0, cost, a.v_max, a.c_max)
        completion = task_completion(int(self.covered[j]), int(tess.cell_counts[j]))
        _, holding = task_costs(
            position, mst_nbrs, tess.generators[j : j + 1], tess.areas[j : j + 1], self._costs, tess.routes, j
        )
        return keep_task(completion, float(holding[0]), a.v_max, a.c_max)

    # -- step ----------------------------------------------------------------------------------
