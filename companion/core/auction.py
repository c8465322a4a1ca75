"""Local auction (Algorithm 2, eq. 19) with removal of allocated tasks (the synchronisation step).

With a local price agreed by all participants (eq. 19), the valuation e_lj = R_lj - P_j ranks the
bidders of one task exactly as their rewards do, so the winner of task j is the bidder with the
highest R_lj; ties go to the lower UAV id. Each winner keeps the best task it won (lines 10-11);
allocated tasks and satisfied bidders are removed and the auction repeats until every bidder holds
one task or no task with a positive reward is left (eq. 14: one task per UAV, one UAV per task).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray


def local_auction(
    bidders: Sequence[int], bids: FloatArray, available: np.ndarray
) -> dict[int, tuple[int, float]]:
    """Algorithm 2: allocate tasks to `bidders` (UAV ids, one row of `bids` each) by local auction.

    `available[j]` is False for tasks already held outside the auction. Returns
    {uav: (task, reward)}; a bidder is left out only when no task with a positive reward remains.
    """
    order = sorted(range(len(bidders)), key=bidders.__getitem__)  # stable, as the ids rise
    r = np.asarray(bids, dtype=float)[order]
    tasks = _auction_rounds(r, np.asarray(available, dtype=np.bool_)).tolist()
    return {int(bidders[order[row]]): (j, float(r[row, j])) for row, j in enumerate(tasks) if j >= 0}


@njit(cache=True)
def _auction_rounds(r: FloatArray, available: np.ndarray) -> IntArray:
    """The rounds of Algorithm 2 over rewards `r` (eq. 15); returns each row's task, -1 for none.

    Rows are by ascending UAV id; a bidder may take only an `available` task of a positive reward.
    Each task goes to its highest open bidder (the first row among equals), each winner keeps the
    best task it won (the first among equals), and its row and task leave the auction.
    """
    n, m = r.shape
    task = np.full(n, -1, dtype=np.int64)
    winner = np.empty(m, dtype=np.int64)
    taken = ~available
    while True:
        winner[:] = -1
        for j in range(m):
            best = 0.0  # a reward must be positive
            for i in range(n):
                if not taken[j] and task[i] < 0 and r[i, j] > best:
                    best, winner[j] = r[i, j], i
        if (winner < 0).all():
            return task
        for i in range(n):
            mine = -1
            for j in range(m):
                if winner[j] == i and (mine < 0 or r[i, j] > r[i, mine]):
                    mine = j
            if mine >= 0:
                task[i], taken[mine] = mine, True


def claim_priority(reward: float, uav: int) -> tuple[float, int]:
    """Conflict rule of the multi-hop synchronisation: the higher reward keeps a task, then the lower id."""
    return (reward, -uav)
