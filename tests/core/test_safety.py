"""The safety layer's geometry (core.trajectory, core.safety): trajectories, compatibility over all
later time, the fence, the start tree and contingencies, and the mission checks built on them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.contracts.mission import MissionError
from companion.core.feasibility import parse_mission
from companion.core.geometry import ConvexPolygon
from companion.core.kinematics import Kinematics, arc_advance
from companion.core.safety.failsafe_regions import clears_loiters
from companion.core.safety.limits import Limits
from companion.core.safety.separation import compatible
from companion.core.safety.start import initial_trajectories, minimum_margin, tether_tree
from companion.core.trajectory import (
    HEAD,
    Reach,
    Trajectory,
    arc_chord_deviation,
    expand,
    segment_clearance,
    step_pose,
)

GRID = Kinematics("grid", 20.0, 2.0, math.pi / 4, 40.0)
CONT = Kinematics("continuous", 20.0, 2.0, math.pi / 4, 40.0)
BIG = ConvexPolygon.from_vertices([(-5000, -5000), (5000, -5000), (5000, 5000), (-5000, 5000)])


def limits(kin: Kinematics, region: ConvexPolygon = BIG, margin: float = 100.0) -> Limits:
    return Limits.build(kin, 3, region, 60.0, 1000.0, margin, 5.0)


turns_st = st.lists(st.sampled_from([-1, 0, 1]), min_size=3, max_size=3)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["grid", "continuous"]), st.integers(0, 7), turns_st)
def test_step_pose_is_eq_2(mode: str, h8: int, turns: list[int]) -> None:
    kin = GRID if mode == "grid" else CONT
    x, y, h = 20.0, -20.0, h8 * math.pi / 4
    for q in turns:
        a = step_pose(x, y, h, q * math.pi / 4, mode == "grid", 20.0, 2.0, 40.0)
        b = kin.advance(x, y, h, q * math.pi / 4)
        assert a == pytest.approx(tuple(float(v) for v in b), abs=1e-9)
        x, y, h = a


@pytest.mark.parametrize("kin", [GRID, CONT], ids=["grid", "continuous"])
def test_the_loiter_closes_after_its_period(kin: Kinematics) -> None:
    reach = Reach.of(kin, 3)
    row = np.array([0, 100.0, 200.0, 0.3 if kin.mode == "continuous" else 0.0, -1, 0.0, math.pi / 4, 0.0])
    pts = expand(row, 0, 3 + 2 * reach.period, reach.loiter_turn, kin.mode == "grid", 20.0, 2.0, 40.0)
    assert reach.period == 8
    assert np.allclose(pts[3], pts[3 + reach.period], atol=1e-9)
    assert np.allclose(pts[3], pts[3 + 2 * reach.period], atol=1e-9)
    # every later point lies within `extent` of every earlier one
    assert np.max(np.linalg.norm(pts[:, None] - pts[None], axis=-1)) <= reach.extent


@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(-300, 300), min_size=8, max_size=8))
def test_segment_clearance_is_the_closest_approach_of_straight_motion(v: list[float]) -> None:
    a = np.array([[v[0], v[1]], [v[2], v[3]]])
    b = np.array([[v[4], v[5]], [v[6], v[7]]])
    s = np.linspace(0, 1, 2001)[:, None]
    dense = np.linalg.norm(a[0] + s * (a[1] - a[0]) - (b[0] + s * (b[1] - b[0])), axis=1).min()
    spacing = np.linalg.norm((a[1] - a[0]) - (b[1] - b[0])) / 2000  # how far apart two samples lie
    assert dense - spacing - 1e-9 <= segment_clearance(a, b) <= dense + 1e-9


@settings(max_examples=40, deadline=None)
@given(st.floats(0.05, math.pi), st.floats(5.0, 40.0), st.floats(0.5, 4.0))
def test_an_arc_strays_from_its_chord_by_at_most_the_sagitta(turn: float, speed: float, dt: float) -> None:
    f = np.linspace(0, 1, 501)
    x, y, _ = arc_advance(0.0, 0.0, 0.0, turn / dt, speed, dt * f)
    x1, y1, _ = arc_advance(0.0, 0.0, 0.0, turn / dt, speed, dt)
    deviation = np.hypot(x - f * x1, y - f * y1).max()
    assert deviation <= arc_chord_deviation(turn, speed, dt) + 1e-9
    assert deviation == pytest.approx(arc_chord_deviation(turn, speed, dt), rel=1e-3)


def dense_track(t: Trajectory, kin: Kinematics, steps: int, sub: int = 40) -> np.ndarray:
    """Positions of a trajectory at `sub` instants a step for `steps` steps, flown by eq. 2 (arcs in
    continuous mode, straight cell-to-cell motion in grid mode)."""
    reach = Reach.of(kin, 3)
    x, y, h = t.x, t.y, t.heading
    out = []
    for k in range(t.start, t.start + steps):
        turn = t.turn_at(k, reach.loiter_turn)
        x1, y1, h1 = (float(v) for v in kin.advance(x, y, h, turn))
        for j in range(sub):
            f = j / sub
            if kin.mode == "grid":
                out.append((x + f * (x1 - x), y + f * (y1 - y)))
            else:
                px, py, _ = arc_advance(x, y, h, turn / kin.dt, kin.speed, kin.dt * f)
                out.append((float(px), float(py)))
        x, y, h = x1, y1, h1
    return np.array(out)


traj_st = st.tuples(
    st.floats(-150, 150), st.floats(-150, 150), st.integers(0, 7), turns_st, st.sampled_from([1, -1])
)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["grid", "continuous"]), traj_st, traj_st)
def test_compatible_trajectories_stay_apart_for_all_later_time(mode: str, a: tuple, b: tuple) -> None:
    """The window of `Reach.window` steps covers every later instant: two trajectories judged
    compatible stay farther than R_s + buffer apart over five loiter periods, between sampling
    moments too; and two that are judged incompatible do come close (or break the tether)."""
    kin = GRID if mode == "grid" else CONT
    lim = limits(kin)
    q = math.pi / 4

    def make(v: tuple) -> Trajectory:
        x, y, h8, turns, side = v
        if mode == "grid":
            x, y = 40.0 * round(x / 40), 40.0 * round(y / 40)
        return Trajectory(0, x, y, h8 * q, tuple(t * q for t in turns), side)

    ta, tb = make(a), make(b)
    pts = lim.expand(lim.rows([ta, tb]), 0)
    empty, no_disks = np.zeros((0, lim.reach.window + 1, 2)), np.zeros((0, 3))
    ok = compatible(pts[0], pts[1:], no_disks, empty, no_disks, *lim.clearances)
    steps = 3 + 5 * lim.reach.period
    gap = np.linalg.norm(dense_track(ta, kin, steps) - dense_track(tb, kin, steps), axis=1).min()
    if ok:
        assert gap > 65.0
    else:
        assert gap <= 65.0 + 2 * lim.reach.sagitta + 1e-6


def test_compatible_checks_disks_and_tethers() -> None:
    lim = limits(CONT)
    t = Trajectory(0, 0.0, 0.0, 0.0, (0.0, 0.0, 0.0), 1)
    pts = lim.expand(lim.rows([t]), 0)[0]
    empty, no = np.zeros((0, lim.reach.window + 1, 2)), np.zeros((0, 3))
    assert compatible(pts, empty, no, empty, no, *lim.clearances)
    # a disk the track passes through
    assert not compatible(pts, empty, np.array([[60.0, 0.0, 10.0]]), empty, no, *lim.clearances)
    assert compatible(pts, empty, np.array([[60.0, 500.0, 10.0]]), empty, no, *lim.clearances)
    # a tether to a UAV loitering 800 m away holds; to one 1,200 m away it does not
    for dist, holds in ((800.0, True), (1200.0, False)):
        other = Trajectory(0, 0.0, dist, 0.0, (0.0, 0.0, 0.0), 1)
        tether = lim.expand(lim.rows([other]), 0)
        assert compatible(pts, tether, no, tether, no, *lim.clearances) == holds
    # every point of a tethered disk must be in range: centre 700 m + radius 200 m is, 350 m is not
    assert compatible(pts, empty, no, empty, np.array([[0.0, 700.0, 200.0]]), *lim.clearances)
    assert not compatible(pts, empty, no, empty, np.array([[0.0, 700.0, 350.0]]), *lim.clearances)


def test_minimum_margin_is_what_turning_back_needs() -> None:
    assert minimum_margin(GRID, 3) == pytest.approx(40.0)  # one cell: the octagon from heading out
    radius = 20.0 * 2.0 / (math.pi / 4)
    assert minimum_margin(CONT, 3) == pytest.approx(
        radius + arc_chord_deviation(math.pi / 4, 20.0, 2.0), rel=1e-3
    )


def test_tether_tree_ranks_breadth_first_and_parents_are_nearer_the_root() -> None:
    pos = np.array([[0, 0], [900, 0], [1700, 0], [100, 0]], dtype=float)
    ranks, parents = tether_tree(pos, 995.0)
    assert ranks == (0, 2, 3, 1)  # 0, then its neighbours nearest first: 3 then 1; 2 through 1
    assert parents == (-1, 3, 1, 0)  # 1's nearest lower-rank neighbour is 3, not 0
    # a layout in two parts is a forest: 2 is a root of its own
    ranks, parents = tether_tree(np.array([[0, 0], [900, 0], [2000, 0]], dtype=float), 995.0)
    assert ranks == (0, 1, 2) and parents == (-1, 0, -1)


def test_initial_trajectories_are_pairwise_compatible_and_refused_when_impossible() -> None:
    lim = limits(GRID)
    poses = np.array([[0, 0, math.pi / 2], [120, 0, math.pi / 2], [240, 0, math.pi / 2]])
    ranks, parents = tether_tree(poses[:, :2], lim.link)
    start = initial_trajectories(poses, parents, ranks, lim)
    pts = lim.expand(lim.rows(start), 0)
    empty, no = np.zeros((0, lim.reach.window + 1, 2)), np.zeros((0, 3))
    for i in range(3):
        others = np.delete(pts, i, axis=0)
        assert compatible(pts[i], others, no, empty, no, *lim.clearances)
    # head-on at 80 m: no loiter or straight run keeps them 65 m apart
    head_on = np.array([[0, 0, 0.0], [80, 0, math.pi]])
    ranks, parents = tether_tree(head_on[:, :2], lim.link)
    with pytest.raises(ValueError, match="no start contingency"):
        initial_trajectories(head_on, parents, ranks, lim)


MISSION = """
name = "t"
[region]
polygon = [[-1000.0, -1000.0], [1000.0, -1000.0], [1000.0, 1000.0], [-1000.0, 1000.0]]
cell_size = 40.0
origin = {{ lat = -35.0, lon = 149.0 }}
[prior]
sigma = 250.0
targets = 3
centres = [{{ x = 0.0, y = 0.0, peak = 0.01 }}]
[sensor]
radius = 60.0
[kinematics]
speed = 20.0
step = 2.0
turn_limit_deg = 45.0
[comms]
range = 1000.0
attraction = 700.0
safety = 60.0
repulsion = 120.0
[safety]
margin = {margin}
{vehicles}
"""


def mission_text(vehicles: list[tuple[float, float, float]], margin: float = 100.0) -> str:
    v = "".join(f"[[vehicles]]\nx = {x}\ny = {y}\nheading_deg = {h}\n" for x, y, h in vehicles)
    return MISSION.format(margin=margin, vehicles=v)


@pytest.mark.parametrize(
    ("vehicles", "margin", "field", "reason"),
    [
        ([(-20, -980, 90), (20, -980, 90)], 100.0, "vehicles", "vehicles 0 and 1 start 40.0 m apart"),
        ([(-620, -980, 90), (580, -980, 90)], 100.0, "vehicles", "not connected: vehicles [1]"),
        ([(-20, -980, 0), (60, -980, 180)], 100.0, "vehicles", "no start contingency"),
        ([(-20, -980, 90)], 20.0, "safety.margin", "needs 40.0 m beyond it"),
    ],
    ids=["not separated", "not connected", "no contingency", "margin too small"],
)
def test_bad_start_geometry_is_a_clear_mission_error(
    vehicles: list[tuple[float, float, float]], margin: float, field: str, reason: str
) -> None:
    with pytest.raises(MissionError) as err:
        parse_mission(mission_text(vehicles, margin), "m.toml")
    assert err.value.field == field and reason in err.value.reason
    assert str(err.value).startswith("m.toml: ")


def test_a_good_start_layout_is_accepted() -> None:
    mission = parse_mission(mission_text([(-620, -980, 90), (-220, -980, 90)]), "m.toml")
    assert mission.safety.margin == 100.0 and mission.safety.buffer == 5.0


def test_expand_starts_at_the_anchor_and_takes_loiter_turns_past_the_plan() -> None:
    row = np.full(HEAD + 3, np.nan)
    row[:HEAD] = (5, 0.0, 0.0, 0.0, -1)
    row[HEAD] = 0.0
    pts = expand(row, 5, 3, math.pi / 4, True, 20.0, 2.0, 40.0)
    # straight one cell east, then the loiter turns clockwise: south-east, south
    assert pts.tolist() == [[0, 0], [40, 0], [80, -40], [80, -80]]


@settings(max_examples=40, deadline=None)
@given(
    mode=st.sampled_from(["grid", "continuous"]),
    h8=st.integers(0, 7),
    turns=st.lists(st.sampled_from([-1, 0, 1]), min_size=3, max_size=3),
    side=st.sampled_from([1, -1]),
    start=st.integers(0, 50),
)
def test_the_loiter_circle_goes_through_every_loiter_point(
    mode: str, h8: int, turns: list[int], side: int, start: int
) -> None:
    kin = GRID if mode == "grid" else CONT
    lim = limits(kin)
    heading = h8 * math.pi / 4 + (0.0 if mode == "grid" else 0.3)
    t = Trajectory(start, 120.0, -80.0, heading, tuple(u * math.pi / 4 for u in turns), side)
    cx, cy, r = lim.loiter_circle(t)
    pts = lim.expand(lim.rows([t]), start)[0][lim.horizon :]  # from the plan's end on: the loiter
    d = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)
    assert np.allclose(d, r, atol=1e-6)  # concyclic (grid: the octagon's circumscribed circle)
    assert r == pytest.approx(50.93 if mode == "continuous" else 63.25, abs=0.01)
    ahead = pts[1] - pts[0]  # the loiter turns towards its centre, on its side
    centre = np.array([cx, cy]) - pts[0]
    assert side * (ahead[0] * centre[1] - ahead[1] * centre[0]) > 0


def test_a_trajectory_must_stay_out_of_a_loiter_disk_or_head_out_of_it() -> None:
    lim = limits(CONT)  # 40 m per step, 3 planned steps, then a 51 m loiter circle
    disk = np.array([[0.0, 0.0, 80.0]])
    no_path, none = np.zeros((1, 4, 2)), np.zeros(1, dtype=np.int64)  # a disk: a fan of no path
    sep, progress = lim.disk_separation, 10.0  # 68.9 m

    def clears(x: float, heading: float, turns: tuple[float, ...] = (0.0, 0.0, 0.0)) -> bool:
        t = Trajectory(0, x, 0.0, heading, turns, 1)
        return clears_loiters(lim.expand(lim.rows([t]), 0)[0], disk, no_path, none, sep, 3, progress)

    assert clears(-90.0, math.pi)  # inside, straight out, and its loiter stays clear
    assert clears(-50.0, math.pi)  # its loiter comes back in, but it heads straight out: next plan
    assert clears(0.0, 0.0)  # from the centre, straight out
    assert not clears(-50.0, 0.0)  # inside, heading in
    q = math.pi / 4
    assert not clears(-50.0, math.pi, (q, q, q))  # inside, turning back in within its plan
    assert not clears(-250.0, 0.0)  # outside, flying in
    assert clears(-250.0, math.pi)  # outside, flying away
    empty = np.zeros((0, 3)), np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64)
    assert clears_loiters(np.zeros((5, 2)), *empty, sep, 3, progress)  # no silent UAV
