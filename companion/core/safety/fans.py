"""The fan a silent UAV's aircraft may fly (its path spoked to its loiter's centre) and distances to it."""

from __future__ import annotations

import math

from numba import njit

from companion.core.geometry import FloatArray


@njit(cache=True)
def to_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """The distance from (px, py) to the segment from (ax, ay) to (bx, by)."""
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    s = 0.0 if dd == 0.0 else min(max(((px - ax) * dx + (py - ay) * dy) / dd, 0.0), 1.0)
    return math.hypot(px - ax - s * dx, py - ay - s * dy)


@njit(cache=True)
def _cross(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True)
def _crosses(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float) -> bool:
    """Whether the segments AB and CD cross (strictly: each one's ends on either side of the other)."""
    d1, d2 = _cross(cx, cy, dx, dy, ax, ay), _cross(cx, cy, dx, dy, bx, by)
    d3, d4 = _cross(ax, ay, bx, by, cx, cy), _cross(ax, ay, bx, by, dx, dy)
    return d1 * d2 < 0 and d3 * d4 < 0


@njit(cache=True)
def _in_fan(px: float, py: float, path: FloatArray, count: int, cx: float, cy: float) -> bool:
    """Whether (px, py) lies in one of the fan's triangles (path[p], path[p + 1], centre)."""
    for p in range(count - 1):
        ax, ay, bx, by = path[p, 0], path[p, 1], path[p + 1, 0], path[p + 1, 1]
        area = _cross(ax, ay, bx, by, cx, cy)
        if area == 0.0:
            continue  # degenerate: its edges are the fan's spokes and path
        d1 = _cross(ax, ay, bx, by, px, py) * area
        d2 = _cross(bx, by, cx, cy, px, py) * area
        d3 = _cross(cx, cy, ax, ay, px, py) * area
        if d1 >= 0 and d2 >= 0 and d3 >= 0:
            return True
    return False


@njit(cache=True)
def fan_clearance(a: FloatArray, path: FloatArray, count: int, cx: float, cy: float) -> float:
    """The closest approach of a polyline to the fan of a path about a centre.

    The closest approach of the polyline `a` (its chords between sampling moments; a point if
    it has one) to the *fan* of path[:count] about the centre (cx, cy): the union of the triangles
    (path[p], path[p + 1], centre), the spokes path[p] -> centre and the centre itself. A silent
    UAV's aircraft, from wherever on its path its failsafe fires, flies towards that centre (its
    committed loiter's): inflated by the failsafe's reach, the fan holds all it flies
    (docs/algorithm.md, "The contingency clause")."""
    for t in range(a.shape[0]):
        if _in_fan(a[t, 0], a[t, 1], path, count, cx, cy):
            return 0.0
    best = math.inf
    if a.shape[0] == 1:
        best = math.hypot(a[0, 0] - cx, a[0, 1] - cy)
        for p in range(count):
            best = min(best, to_segment(a[0, 0], a[0, 1], path[p, 0], path[p, 1], cx, cy))
        return best
    # the distance between two segments is 0 where they cross, else the least of their ends'
    # distances to the other: a chord crossing a spoke or a path edge touches the fan, and every
    # end-to-segment distance is taken once (a point ends two chords, a path point two edges)
    width = a.shape[0]
    for t in range(width - 1):
        ax, ay, bx, by = a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]
        for p in range(count):
            qx, qy = path[p, 0], path[p, 1]
            if _crosses(ax, ay, bx, by, qx, qy, cx, cy):
                return 0.0
            if p + 1 < count and _crosses(ax, ay, bx, by, qx, qy, path[p + 1, 0], path[p + 1, 1]):
                return 0.0
    for t in range(width):  # each sampling point to each spoke and path edge
        px, py = a[t, 0], a[t, 1]
        for p in range(count):
            qx, qy = path[p, 0], path[p, 1]
            best = min(best, to_segment(px, py, qx, qy, cx, cy))
            if p + 1 < count:
                best = min(best, to_segment(px, py, qx, qy, path[p + 1, 0], path[p + 1, 1]))
    for t in range(width - 1):  # the centre and each path point to each chord
        ax, ay, bx, by = a[t, 0], a[t, 1], a[t + 1, 0], a[t + 1, 1]
        best = min(best, to_segment(cx, cy, ax, ay, bx, by))
        for p in range(count):
            best = min(best, to_segment(path[p, 0], path[p, 1], ax, ay, bx, by))
    return best


@njit(cache=True)
def fan_count(entry: int, width: int) -> int:
    """How many points of an expanded trajectory its fan takes (up to its loiter's entry).

    How many points of an expanded trajectory (`width` of them) its fan takes: those up to its
    loiter's entry index `entry`; none once it loiters (its aircraft, holding the loiter turn, then
    stays on the loiter circle: the centre, inflated, covers it)."""
    return 0 if entry <= 0 else min(entry, width - 1) + 1


@njit(cache=True)
def fan_radius(path: FloatArray, count: int, cx: float, cy: float) -> float:
    """The radius about (cx, cy) of the disk that holds the fan of path[:count]."""
    r = 0.0
    for p in range(count):
        r = max(r, math.hypot(path[p, 0] - cx, path[p, 1] - cy))
    return r
