"""The companion's pure pieces for real flight: the fence polygon, the way back inside, plan versus
flight, the region guard, the airframe check (what ArduPlane and PX4 can fly), the waypoint
modes' lead point inside the fence, and the autopilot's fence items and their read-back check."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as M

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import NoFlyCircle, NoFlyPolygon
from companion.core.feasibility import load_mission
from companion.core.geometry import ConvexPolygon
from companion.node.airframe import (
    GRAVITY,
    Airframe,
    bank_for,
    check_mission,
    heading_lead,
    refusal,
    turn_accel,
    turn_rate_limit,
)
from companion.node.fence import (
    CIRCLE_EXCLUSION,
    DEFAULT_MARGIN_M,
    EXCLUSION,
    fence_items,
    fence_margin,
    fence_mismatch,
    fence_polygon,
    fence_ring,
    nearest_inside,
    offset_polygon,
)
from companion.node.guidance import FENCE_CLEARANCE_M, lead_point
from companion.node.mission_upload import Item
from companion.node.tracking import Guard, PlanTracker, RegionGuard
from sim_vehicles.dynamics.navigation import heading_hold

ROOT = Path(__file__).resolve().parents[2]
CONTINUOUS = load_mission(ROOT / "mission_files" / "scenario1_continuous.toml")
SQUARE = ConvexPolygon.from_vertices(CONTINUOUS.region.polygon)  # +-1000 m


def test_fence_is_the_region_with_its_edges_pushed_out() -> None:
    assert fence_margin(CONTINUOUS) == DEFAULT_MARGIN_M
    fence = fence_polygon(CONTINUOUS)
    assert np.allclose(np.sort(np.abs(fence.vertices).ravel()), 1100.0)
    assert np.allclose(fence.offsets, SQUARE.offsets + DEFAULT_MARGIN_M)
    assert np.allclose(np.abs(offset_polygon(SQUARE, -100.0)), 900.0)
    triangle = ConvexPolygon.from_vertices([(0, 0), (100, 0), (0, 100)])
    moved = ConvexPolygon.from_vertices(offset_polygon(triangle, 10.0))
    assert np.allclose(moved.offsets, triangle.offsets + 10.0)  # every edge 10 m out, parallel


def test_nearest_point_inside() -> None:
    assert nearest_inside(SQUARE, 1200.0, 30.0, 100.0) == pytest.approx((900.0, 30.0))
    assert nearest_inside(SQUARE, 1200.0, 1300.0, 100.0) == pytest.approx((900.0, 900.0))
    assert nearest_inside(SQUARE, 10.0, -20.0, 100.0) == (10.0, -20.0)
    assert nearest_inside(SQUARE, 1200.0, 0.0, 5000.0) == pytest.approx((0.0, 0.0))  # too deep: centre


def test_plan_versus_flight() -> None:
    tracker = PlanTracker(0, speed=20.0, dt=2.0, bound_m=40.0, warn_steps=3)
    tracker.expect(1, 40.0, 0.0, 0.0)
    assert tracker.measure(0.9, 0.0, 0.0, 0.0) is None  # the plan's time has not come
    e = tracker.measure(2.1, 45.0, 3.0, math.radians(10.0))  # 0.1 s late: the plan moved on 2 m
    assert e is not None and e.position_m == pytest.approx(math.hypot(3.0, 3.0))
    assert e.heading_deg == pytest.approx(10.0)
    # grid mode turns at the step boundary: the sample just before it is the one that counts, the
    # planned point moved back by its earliness; the sample after it has the next step's heading
    tracker.expect(2, 80.0, 0.0, 0.0)
    assert tracker.measure(3.95, 79.0, 0.5, 0.0) is None
    e = tracker.measure(4.05, 81.0, 1.0, math.radians(45.0))
    assert e is not None and e.step == 2 and e.flown == (79.0, 0.5, 0.0)
    assert e.position_m == pytest.approx(0.5) and e.heading_deg == pytest.approx(0.0)
    tracker.expect(3, 80.0, 0.0, 0.0)
    assert tracker.measure(7.5, 80.0, 0.0, 0.0) is None and tracker.missed == 1  # telemetry too late
    for k in range(4, 7):
        tracker.expect(k, 0.0, 0.0, 0.0)
        tracker.measure(2.0 * k, 100.0, 0.0, 0.0)
    assert tracker.warnings == 1
    summary = tracker.summary()
    assert summary.steps == 5 and summary.position_m.max == pytest.approx(100.0)


def test_region_guard_repositions_then_releases() -> None:
    guard = RegionGuard(0, SQUARE, fence_polygon(CONTINUOUS), depth=100.0, step_length=40.0, patience=30)
    assert guard.check(0, 1050.0, 0.0) is None and guard.state is Guard.INSIDE  # within the margin
    assert guard.check(1, 1150.0, 0.0) == pytest.approx((900.0, 0.0))
    assert guard.state is Guard.RETURNING
    assert guard.check(2, 1050.0, 0.0) is None and guard.state is Guard.RETURNING  # not in the region yet
    assert guard.check(3, 990.0, 0.0) is None and guard.state is Guard.INSIDE
    assert guard.check(4, 0.0, 1200.0) == pytest.approx((0.0, 900.0))  # 300 m back: 8 steps
    guard.check(4 + 8 + 29, 0.0, 1200.0)
    assert guard.state is Guard.RETURNING
    guard.check(4 + 8 + 30, 0.0, 1200.0)
    assert guard.state is Guard.RELEASED and guard.exits == 2


def test_airframe_check_names_the_fields() -> None:
    assert turn_accel(CONTINUOUS.kinematics) == pytest.approx(20.0 * math.radians(45.0) / 2.0)
    assert bank_for(CONTINUOUS.kinematics) == pytest.approx(38.69, abs=0.01)
    plane = {"AIRSPEED_CRUISE": 22.0, "AIRSPEED_MIN": 10.0, "AIRSPEED_MAX": 30.0, "ROLL_LIMIT_DEG": 65.0}
    assert check_mission(CONTINUOUS, Airframe.from_params("ardupilot", plane)) == []
    tight = Airframe.from_params("ardupilot", {**plane, "ROLL_LIMIT_DEG": 30.0, "AIRSPEED_MAX": 18.0})
    warnings = check_mission(CONTINUOUS, tight)
    assert any("kinematics.speed" in w and "AIRSPEED_MIN..AIRSPEED_MAX" in w for w in warnings)
    assert any("kinematics.turn_limit_deg" in w and "ROLL_LIMIT_DEG = 30" in w for w in warnings)
    px4 = Airframe.from_params("px4", {"FW_AIRSPD_TRIM": 18.0})
    assert any("FW_AIRSPD_MIN, FW_AIRSPD_MAX, FW_R_LIM" in w for w in check_mission(CONTINUOUS, px4))


def test_what_a_real_autopilot_cannot_fly_is_refused() -> None:
    real = Airframe.from_params("ardupilot", {"AIRSPEED_CRUISE": 22.0})
    bundled = Airframe.from_params("ardupilot", {"AIRSPEED_CRUISE": 20.0, "SIM_TURN_LIMIT": 45.0})
    grid = msgspec.structs.replace(
        CONTINUOUS, kinematics=msgspec.structs.replace(CONTINUOUS.kinematics, mode="grid")
    )
    assert refusal(CONTINUOUS, real, "heading") is None
    assert refusal(CONTINUOUS, real, "reposition") is None
    assert "use --command-mode heading or reposition" in str(refusal(CONTINUOUS, real, "turn-rate"))
    assert 'kinematics.mode = "continuous"' in str(refusal(grid, real, "heading"))
    assert refusal(grid, bundled, "turn-rate") is None
    assert "ArduPlane takes only the altitude" in str(refusal(CONTINUOUS, bundled, "position-target"))
    px4 = Airframe.from_params("px4", {})
    assert "no MAV_CMD_GUIDED_CHANGE_HEADING" in str(refusal(CONTINUOUS, px4, "heading"))
    assert "use --command-mode position-target or reposition" in str(refusal(CONTINUOUS, px4, "turn-rate"))
    assert refusal(CONTINUOUS, px4, "position-target") is None
    assert refusal(CONTINUOUS, px4, "reposition") is None


def test_lead_points_stay_inside_the_fence() -> None:
    fence = fence_polygon(CONTINUOUS)  # the region (+-1000 m) plus 100 m
    assert lead_point((0.0, 0.0), 0.0, 200.0, fence) == (200.0, 0.0)  # far from the fence: the full lead
    x, y = lead_point((1000.0, 0.0), 0.0, 200.0, fence)  # heading out at the region's edge
    assert (x, y) == (1100.0 - FENCE_CLEARANCE_M, 0.0)
    x, y = lead_point((1000.0, 0.0), math.pi, 200.0, fence)  # heading in: the full lead
    assert math.isclose(x, 800.0) and abs(y) < 1e-9
    assert lead_point((1200.0, 0.0), 0.0, 200.0, fence) == (1400.0, 0.0)  # outside: the guard's business


def _fly_heading_commands(rate: float, lead: bool, steps: int = 8) -> float:
    """A turn at `rate` (below the bank limit) planned step by step and flown by ArduPlane's
    GUIDED_CHANGE_HEADING law (the simulator's `heading_hold`: bank GUIDED_P per radian of error,
    limited by param3), each step commanded the heading the plan reaches at its end (plus
    `heading_lead` if `lead`); the heading error (rad) after the last step."""
    k = CONTINUOUS.kinematics
    accel, v, h, dt = turn_accel(k), k.speed, 0.0, 0.01
    for step in range(steps):
        planned = (step + 1) * rate * k.step
        target = planned + (heading_lead(k, rate) if lead else 0.0)
        for _ in range(round(k.step / dt)):
            h += GRAVITY * math.tan(heading_hold(h, target, accel)) / v * dt
    return abs(h - steps * rate * k.step)


@given(st.floats(0.1, 0.9), st.sampled_from([-1.0, 1.0]))
def test_heading_lead_makes_arduplane_turn_at_the_planned_rate(fraction: float, sense: float) -> None:
    rate = sense * fraction * turn_rate_limit(CONTINUOUS.kinematics)
    led, unled = _fly_heading_commands(rate, True), _fly_heading_commands(rate, False)
    assert led < 0.25 * unled
    assert led < math.radians(3.0)


NOFLY = load_mission(ROOT / "mission_files" / "scenario1_nofly.toml")


def test_fence_items_are_the_inclusion_polygon_and_the_zones_as_given() -> None:
    frame = LocalFrame(NOFLY.region.origin)
    items = fence_items(NOFLY, frame, 140.0)
    square = [it for it in items if it.command == M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION]
    assert [(it.x, it.y) for it in square] == [
        tuple(round(v * 1e7) for v in frame.to_geodetic(float(x), float(y))[:2])
        for x, y in fence_polygon(NOFLY, 140.0).vertices
    ]  # a convex region's fence is the planning fence's polygon, pushed out
    assert all(it.params[0] == 4 for it in square)
    band = items[len(square) :]
    assert [it.command for it in band] == [M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION] * 4
    zone = NOFLY.region.nofly[0]
    assert isinstance(zone, NoFlyPolygon)
    for it, (x, y) in zip(band, zone.ring, strict=True):  # not inflated
        assert np.allclose(frame.to_local(it.x * 1e-7, it.y * 1e-7), (x, y), atol=0.02)
    assert fence_mismatch(items, list(items)) is None


def test_a_non_convex_region_is_fenced_mitred_and_a_circle_by_its_radius() -> None:
    ell = [(0.0, 0.0), (1000.0, 0.0), (1000.0, 400.0), (400.0, 400.0), (400.0, 1000.0), (0.0, 1000.0)]
    circle = NoFlyCircle(x=200.0, y=200.0, radius=50.0)
    closed = NoFlyPolygon(ring=[(700.0, 100.0), (800.0, 100.0), (800.0, 200.0), (700.0, 100.0)])
    region = msgspec.structs.replace(NOFLY.region, polygon=ell, nofly=[circle, closed])
    mission = msgspec.structs.replace(NOFLY, region=region)
    ring = fence_ring(mission, 100.0)
    mitred = [(-100, -100), (1100, -100), (1100, 500), (500, 500), (500, 1100), (-100, 1100)]
    assert np.allclose(sorted(ring), sorted(mitred))  # the corners mitred, the inner one too
    frame = LocalFrame(NOFLY.region.origin)
    items = fence_items(mission, frame, 100.0)
    assert [it.command for it in items[6:]] == [CIRCLE_EXCLUSION] + [EXCLUSION] * 3  # the closing vertex once
    assert items[6].params[0] == 50.0 and items[7].params[0] == 3
    assert "holds 7 fence items, 10 were sent" in (fence_mismatch(items, items[:7]) or "")
    c, v = items[6], items[7]
    moved = [*items[:6], Item(c.frame, CIRCLE_EXCLUSION, (49.0, 0, 0, 0), c.x, c.y), *items[7:]]
    assert "radius 49.00 m" in (fence_mismatch(items, moved) or "")
    shifted = [*items[:7], Item(v.frame, EXCLUSION, (3, 0, 0, 0), v.x + 2, v.y), *items[8:]]
    assert "fence item 7 is at" in (fence_mismatch(items, shifted) or "")
    nudged = [*items[:7], Item(v.frame, EXCLUSION, (3, 0, 0, 0), v.x - 1, v.y), *items[8:]]
    assert fence_mismatch(items, nudged) is None  # PX4 truncates lat * 1e7 when it sends it back
    swapped = [*items[:6], *items[7:], items[6]]
    assert "command" in (fence_mismatch(items, swapped) or "")
