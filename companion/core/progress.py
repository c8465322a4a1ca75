"""One UAV's view of the search's progress: coverage, eq. 30's mean uncertainty, P(target left).

What a companion reports to its ground station each step (docs/companion.md, "What the ground
station sees"). `p_unfound` reads the UAV's target-probability map (`core.belief`): P = 1 - prod
over cells not confirmed of (1 - P_p), P_p the posterior of every look fused. With the paper's
perfect sensor a looked-at empty cell's posterior is below 1e-8 and an unseen cell's is eq. 1's
prior, so P is the prior's mass left unseen; with a detector that misses, looked-at cells keep
part of theirs.
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
from msgspec import Struct

from companion.core.geometry import FloatArray


class SearchProgress(Struct, frozen=True):
    """The search as one UAV knows it at one step."""

    coverage: float  # fraction of the cells seen by this UAV or the neighbours it heard
    mean_eta: float  # eq. 30 for one UAV: the mean of its uncertainty map
    found: int  # targets confirmed (its own looks' and those the mesh relayed)
    p_unfound: float  # the probability that a target lies in a cell not confirmed


def search_progress(
    seen: np.ndarray, eta: FloatArray, posterior: FloatArray, found: Collection[int]
) -> SearchProgress:
    """Coverage, mean eta (eq. 30), targets found and P(a target is left unconfirmed) from one agent's maps.

    P(left) = 1 - prod_{p not confirmed} (1 - P_p): cells hold targets independently (eq. 1), and
    `posterior` is each cell's P_p given every look fused (`Belief.posterior`).
    """
    left = np.ones(posterior.shape[0], dtype=bool)
    if found:
        left[np.fromiter(found, dtype=np.int64, count=len(found))] = False
    miss = float(np.prod(1.0 - np.clip(posterior[left], 0.0, 1.0)))
    n = max(int(seen.shape[0]), 1)
    return SearchProgress(
        coverage=float(np.count_nonzero(seen)) / n,
        mean_eta=float(eta.mean()) if eta.size else 0.0,
        found=len(found),
        p_unfound=1.0 - miss,
    )
