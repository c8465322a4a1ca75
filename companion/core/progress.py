"""One UAV's view of the search's progress: coverage, eq. 30's mean uncertainty, P(target left).

What a companion reports to its ground station each step (docs/companion.md, "What the ground
station sees"). `p_unfound` assumes, as the batch engine and the simulated camera do, that a
target in a cell some UAV has looked at is found: P = 1 - prod over cells never seen of
(1 - Pr_p), Pr_p the prior of eq. 1.
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
    found: int  # targets known (its own camera's and those the mesh reported)
    p_unfound: float  # the probability that a target lies in a cell nobody has looked at


def search_progress(
    seen: np.ndarray, eta: FloatArray, prior: FloatArray, found: Collection[int]
) -> SearchProgress:
    """Coverage, mean eta (eq. 30), targets found and P(a target is left unfound) from one agent's maps.

    P(left) = 1 - prod_{p unseen, not found} (1 - Pr_p): the cells of eq. 1 hold targets
    independently, and a seen cell's target would have been found.
    """
    unseen = ~seen.astype(bool)
    if found:
        unseen[np.fromiter(found, dtype=np.int64, count=len(found))] = False
    miss = float(np.prod(1.0 - np.clip(prior[unseen], 0.0, 1.0)))
    n = max(int(seen.shape[0]), 1)
    return SearchProgress(
        coverage=float(np.count_nonzero(seen)) / n,
        mean_eta=float(eta.mean()) if eta.size else 0.0,
        found=len(found),
        p_unfound=1.0 - miss,
    )
