"""Eq. 2 kinematics, grid and continuous, and the path enumeration of eq. 23."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from companion.core.kinematics import Kinematics, PathTree, arc_advance, wrap_angle

Q = math.pi / 4  # 45 degrees
GRID = Kinematics("grid", 20.0, 2.0, Q, 40.0)
CONT = Kinematics("continuous", 20.0, 2.0, Q, 40.0)


def test_grid_turn_options() -> None:
    assert sorted(GRID.turn_options.tolist()) == pytest.approx([-Q, 0.0, Q])
    wide = Kinematics("grid", 20.0, 2.0, math.pi / 2, 40.0)
    assert sorted(wide.turn_options.tolist()) == pytest.approx([-2 * Q, -Q, 0.0, Q, 2 * Q])
    assert GRID.turn_options[0] == 0.0  # straight first


@pytest.mark.parametrize(
    ("heading", "turn", "dx", "dy", "h1"),
    [
        (math.pi / 2, 0.0, 0.0, 40.0, math.pi / 2),  # north, straight: one cell up
        (math.pi / 2, Q, -40.0, 40.0, 3 * Q),  # north, left 45: diagonal NW, 40 m per axis
        (0.0, -Q, 40.0, -40.0, -Q),  # east, right 45: diagonal SE
        (math.pi, Q, -40.0, -40.0, -3 * Q),  # west, left 45 -> 225 deg, wrapped to -135 deg
        (-3 * Q, Q, 0.0, -40.0, -math.pi / 2),  # SW (-135), left 45 -> south (-90)
        (-3 * Q, -Q, -40.0, 0.0, -math.pi),  # SW (-135), right 45 -> west (-180)
    ],
)
def test_grid_advance(heading: float, turn: float, dx: float, dy: float, h1: float) -> None:
    x, y, h = GRID.advance(100.0, 200.0, heading, turn)
    assert float(x) == pytest.approx(100.0 + dx, abs=1e-9)
    assert float(y) == pytest.approx(200.0 + dy, abs=1e-9)
    assert float(h) == pytest.approx(h1, abs=1e-9)


def test_arc_advance_quarter_circle() -> None:
    # v = 10 m/s, omega = pi/2 rad/s for 1 s: radius r = v / omega = 20 / pi = 6.3661977 m.
    # From (0, 0) heading east, a left quarter circle ends at (r, r) heading north.
    x, y, h = arc_advance(0.0, 0.0, 0.0, math.pi / 2, 10.0, 1.0)
    assert (float(x), float(y), float(h)) == pytest.approx((6.3661977, 6.3661977, math.pi / 2), abs=1e-6)
    # turning right: (r, -r) heading south
    x, y, h = arc_advance(0.0, 0.0, 0.0, -math.pi / 2, 10.0, 1.0)
    assert (float(x), float(y), float(h)) == pytest.approx((6.3661977, -6.3661977, -math.pi / 2), abs=1e-6)
    # from heading north, a left quarter: (-r, r) heading west
    x, y, h = arc_advance(1.0, 2.0, math.pi / 2, math.pi / 2, 10.0, 1.0)
    assert (float(x), float(y), float(h)) == pytest.approx((1 - 6.3661977, 2 + 6.3661977, math.pi), abs=1e-6)


def test_arc_advance_straight() -> None:
    # omega = 0: 20 m/s * 2 s = 40 m along heading 30 deg -> (34.641016, 20)
    x, y, h = arc_advance(0.0, 0.0, math.pi / 6, 0.0, 20.0, 2.0)
    assert (float(x), float(y), float(h)) == pytest.approx((34.641016, 20.0, math.pi / 6), abs=1e-6)


@settings(max_examples=50, deadline=None)
@example(0.0, 0.0, 1.0, 1e-12, 1.0, 2)  # a turn rate too small for sin(h1) - sin(h) over omega
@given(
    st.floats(-1000, 1000),
    st.floats(-1000, 1000),
    st.floats(-math.pi, math.pi),
    st.floats(-1.0, 1.0),
    st.floats(1.0, 30.0),
    st.integers(1, 12),
)
def test_arc_advance_in_substeps_equals_one_step(
    x: float, y: float, h: float, omega: float, speed: float, n: int
) -> None:
    dt = 2.0
    one = arc_advance(x, y, h, omega, speed, dt)
    px, py, ph = x, y, h
    for _ in range(n):
        px, py, ph = arc_advance(px, py, ph, omega, speed, dt / n)
    assert np.allclose([px, py, ph], one, atol=1e-6)


def test_continuous_advance_turns_at_rate_turn_over_dt() -> None:
    # 45 deg over 2 s at 20 m/s: arc radius 40 / (pi/4) = 50.929582; chord 2 r sin(pi/8) = 38.979
    # at angle pi/8 from east: (36.012, 14.917).
    x, y, h = CONT.advance(0.0, 0.0, 0.0, Q)
    r = 40.0 / Q
    assert (float(x), float(y), float(h)) == pytest.approx((r * math.sin(Q), r * (1 - math.cos(Q)), Q))
    assert math.hypot(float(x), float(y)) == pytest.approx(2 * r * math.sin(Q / 2))


def test_wrap_angle() -> None:
    assert float(wrap_angle(3 * math.pi / 2)) == pytest.approx(-math.pi / 2)
    assert float(wrap_angle(math.pi)) == pytest.approx(-math.pi)
    assert float(wrap_angle(-math.pi / 4)) == pytest.approx(-math.pi / 4)


def test_turn_sequences() -> None:
    seqs = GRID.turn_sequences(3)
    assert seqs.shape == (27, 3)  # 3^M
    assert len({tuple(s) for s in seqs.tolist()}) == 27
    assert np.all(seqs[0] == 0.0)  # the straight path first
    assert np.all(np.diff(np.abs(seqs).sum(axis=1)) >= -1e-12)  # fewest turns first


def step_headings(pts: np.ndarray, x: float, y: float) -> np.ndarray:
    """Direction of each step of each path (from the previous point)."""
    full = np.concatenate([np.broadcast_to((x, y), (pts.shape[0], 1, 2)), pts], axis=1)
    d = np.diff(full, axis=1)
    return np.arctan2(d[..., 1], d[..., 0])


@settings(max_examples=50, deadline=None)
@given(st.integers(-40, 40), st.integers(-40, 40), st.integers(0, 7), st.integers(1, 4))
def test_grid_path_tree_respects_turn_limit(col: int, row: int, h8: int, horizon: int) -> None:
    tree = PathTree.build(GRID, horizon)
    x, y, heading = 20.0 + 40 * col, 20.0 + 40 * row, float(wrap_angle(h8 * Q))
    pts = tree.expand(x, y, heading)
    assert pts.shape == (3**horizon, horizon, 2)
    dirs = step_headings(pts, x, y)
    # every step moves to an adjacent cell: 40 m straight or 40 m per axis diagonally
    steps = np.diff(np.concatenate([np.broadcast_to((x, y), (len(pts), 1, 2)), pts], axis=1), axis=1)
    assert np.all(np.isin(np.abs(steps), (0.0, 40.0)))
    assert np.all(np.abs(steps).max(axis=-1) == 40.0)
    # consecutive headings (starting from the UAV's) differ by at most omega_max
    full = np.concatenate([np.full((len(pts), 1), heading), dirs], axis=1)
    assert np.all(np.abs(wrap_angle(np.diff(full, axis=1))) <= Q + 1e-9)
    # the pre-rotated tables agree with integrating eq. 2 from the pose
    ref, _ = GRID.paths(x, y, heading, tree.sequences)
    assert np.allclose(pts, ref)
    for p in (0, len(pts) - 1):
        assert tree.headings_along(heading, p)[0] == pytest.approx(float(wrap_angle(dirs[p, 0])), abs=1e-9)


@settings(max_examples=50, deadline=None)
@given(st.floats(-500, 500), st.floats(-500, 500), st.floats(-math.pi, math.pi), st.integers(1, 4))
def test_continuous_path_tree_respects_turn_limit(x: float, y: float, heading: float, horizon: int) -> None:
    tree = PathTree.build(CONT, horizon)
    pts = tree.expand(x, y, heading)
    ref, heads = CONT.paths(x, y, heading, tree.sequences)
    assert np.allclose(pts, ref, atol=1e-6)  # rotating the heading-0 table = integrating eq. 2
    full = np.concatenate([np.full((len(pts), 1), heading), heads], axis=1)
    assert np.all(np.abs(wrap_angle(np.diff(full, axis=1))) <= Q + 1e-9)
    # constant speed: each chord is 2 r sin(turn / 2) <= 40 m and >= the 45-degree chord 38.98 m
    chords = np.linalg.norm(
        np.diff(np.concatenate([np.broadcast_to((x, y), (len(pts), 1, 2)), pts], 1), axis=1), axis=-1
    )
    assert np.all((chords <= 40.0 + 1e-9) & (chords >= 2 * (40 / Q) * math.sin(Q / 2) - 1e-9))


def test_max_step_is_the_diagonal() -> None:
    assert PathTree.build(GRID, 3).max_step == pytest.approx(40 * math.sqrt(2))
    assert PathTree.build(CONT, 3).max_step == pytest.approx(40.0)
