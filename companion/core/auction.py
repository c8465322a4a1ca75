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

from companion.core.geometry import FloatArray


def local_auction(
    bidders: Sequence[int], bids: FloatArray, available: np.ndarray
) -> dict[int, tuple[int, float]]:
    """Allocate tasks to `bidders` (UAV ids, one row of `bids` each).

    `available[j]` is False for tasks already held outside the auction. Returns
    {uav: (task, reward)}; a bidder is left out only when no task with a positive reward remains.
    """
    order = np.argsort(np.asarray(bidders), kind="stable")
    ids = [int(bidders[i]) for i in order]
    r = np.where(available[None, :], np.asarray(bids, dtype=float)[order], -np.inf)
    r = np.where(r > 0, r, -np.inf)
    result: dict[int, tuple[int, float]] = {}
    open_rows = np.ones(len(ids), dtype=bool)
    while open_rows.any():
        live = np.where(open_rows[:, None], r, -np.inf)
        best = live.max(axis=0)
        tasks = np.flatnonzero(np.isfinite(best))
        if tasks.size == 0:
            break
        winners = np.argmax(live[:, tasks], axis=0)  # first (lowest id) among equals
        for row in np.unique(winners):
            won = tasks[winners == row]
            j = int(won[np.argmax(r[row, won])])
            result[ids[row]] = (j, float(r[row, j]))
            open_rows[row] = False
            r[:, j] = -np.inf
    return result


def claim_priority(reward: float, uav: int) -> tuple[float, int]:
    """Conflict rule of the multi-hop synchronisation: the higher reward keeps a task, then the lower id."""
    return (reward, -uav)
