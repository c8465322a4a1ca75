"""What a UAV sees of the swarm: the MST over the UAVs it knows of (eq. 26) and their predicted tracks."""

from __future__ import annotations

import numpy as np
from numba import njit

from companion.core.connectivity import kruskal_mst, mst_neighbours
from companion.core.geometry import FloatArray


@njit(cache=True)
def predict_tracks(seqs: FloatArray, stamps: np.ndarray, first: int, count: int) -> FloatArray:
    """Positions of UAVs at steps first..first+count-1 from their last states.

    `seqs[u]` is UAV u's position at its stamp followed by its planned path; past the plan the
    UAV is assumed to keep its last planned velocity.
    """
    n, length = seqs.shape[0], seqs.shape[1]
    out = np.empty((n, count, 2))
    for u in range(n):
        for t in range(count):
            i = first + t - stamps[u]
            c = min(max(i, 0), length - 1)
            for a in range(2):
                out[u, t, a] = seqs[u, c, a]
                if length >= 2:
                    out[u, t, a] += (i - c) * (seqs[u, length - 1, a] - seqs[u, length - 2, a])
    return out


@njit(cache=True)
def swarm_view(table: FloatArray, k: int, position: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The MST (eq. 26) over this UAV at `position` and the UAVs it knows of, at t_k.

    Row r of `table` holds a UAV's last state: its stamp, its position then its planned path
    (M + 1 points, x and y), its heading then the heading at each planned point (M + 1). Returns
    the MST neighbours' positions at t_k and their predicted tracks over t_k..t_{k+M}.
    """
    horizon = (table.shape[1] - 1) // 3 - 1
    stamps = table[:, 0].astype(np.int64)
    track = np.ascontiguousarray(table[:, 1 : 2 * horizon + 3]).reshape(-1, horizon + 1, 2)
    tracks = predict_tracks(track, stamps, k, horizon + 1)
    now = np.empty((table.shape[0] + 1, 2))
    now[0] = position
    now[1:] = tracks[:, 0, :]
    rows = mst_neighbours(kruskal_mst(now), 0) - 1
    return tracks[rows, 0, :], tracks[rows]
