"""The fan of a silent UAV's path about its failsafe loiter's centre (`safety.fan_clearance`):
where its aircraft flies from wherever on its path the failsafe fires, before the inflation by the
failsafe's reach and stray (docs/algorithm.md, "The contingency clause"). Checked against a brute
force: points dense along the chords, each one's distance to the triangles and spokes."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.safety.fans import fan_clearance

coordinate = st.floats(-300, 300, allow_nan=False)
point = st.tuples(coordinate, coordinate)
SAMPLES = 400  # per chord


def _to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    dd = float(d @ d)
    s = np.zeros(len(p)) if dd == 0 else np.clip((p - a) @ d / dd, 0.0, 1.0)
    return np.hypot(*(p - a - s[:, None] * d).T)


def _inside(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric test: p within the triangle abc (never for a degenerate one)."""
    m = np.array([b - a, c - a]).T
    if abs(np.linalg.det(m)) < 1e-9:
        return np.zeros(len(p), dtype=bool)
    u, v = np.linalg.solve(m, (p - a).T)
    return (u >= -1e-12) & (v >= -1e-12) & (u + v <= 1 + 1e-12)


def brute(a: np.ndarray, path: np.ndarray, centre: np.ndarray) -> tuple[float, float]:
    """(closest sampled distance to the fan, the sampling's spacing along the chords)."""
    s = np.linspace(0.0, 1.0, SAMPLES)[:, None]
    pts = np.concatenate([a[t] + s * (a[t + 1] - a[t]) for t in range(len(a) - 1)])
    d = np.hypot(*(pts - centre).T)
    for p in range(len(path)):
        d = np.minimum(d, _to_segment(pts, path[p], centre))
        if p + 1 < len(path):
            d = np.minimum(d, _to_segment(pts, path[p], path[p + 1]))
            d[_inside(pts, path[p], path[p + 1], centre)] = 0.0
    spacing = max(float(np.hypot(*(a[t + 1] - a[t]))) for t in range(len(a) - 1)) / (SAMPLES - 1)
    return float(d.min()), spacing


@settings(max_examples=300, deadline=None)
@given(
    a=st.lists(point, min_size=2, max_size=6),
    path=st.lists(point, min_size=0, max_size=5),
    centre=point,
)
def test_fan_clearance_is_the_distance_to_the_triangles_and_spokes(a, path, centre) -> None:
    a_, path_, c = np.array(a, dtype=float), np.array(path, dtype=float).reshape(-1, 2), np.array(centre)
    padded = np.zeros((6, 2))
    padded[: len(path_)] = path_
    got = fan_clearance(a_, padded, len(path_), float(c[0]), float(c[1]))
    want, spacing = brute(a_, path_, c)
    assert got <= want + 1e-6  # never more than what a sampled point achieves
    assert got >= want - spacing - 1e-6  # and the sampled points come within a spacing of it


def test_a_point_inside_the_fan_has_no_clearance_and_a_disk_is_a_fan_without_path() -> None:
    path = np.array([[0.0, -200.0], [40.0, -160.0], [60.0, -100.0]])
    inside = np.array([[20.0, -120.0], [20.0, -119.0]])  # within triangle (path[0], path[1], centre)
    assert fan_clearance(inside, path, 3, 0.0, 0.0) == 0.0
    far = np.array([[0.0, 100.0], [10.0, 100.0]])
    assert math.isclose(fan_clearance(far, path, 0, 0.0, 0.0), 100.0)
    assert math.isclose(fan_clearance(far, path, 3, 0.0, 0.0), 100.0)  # the fan lies south of it
    beside = np.array([[-100.0, -200.0], [-100.0, -150.0]])  # 100 m west of the first spoke
    assert math.isclose(fan_clearance(beside, path, 3, 0.0, 0.0), 100.0)
    assert fan_clearance(beside, path, 0, 0.0, 0.0) > 150.0  # the disk alone is farther
