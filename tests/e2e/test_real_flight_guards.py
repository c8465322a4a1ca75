"""What the companion does for real flight, against the bundled simulator (ArduPilot flavour).

- The airframe check: the pilot lowered ROLL_LIMIT_DEG below the bank the mission's turns need;
  the companion warns, naming the fields.
- The region guard: the pilot flew the vehicle out of the region plus its margin before the
  companion started; the companion does not fly its plan there, repositions the vehicle back
  inside, and flies the plan again once the vehicle is back in the region.
- The altitude layer: the pilot climbed to 160 m; the companion brings the vehicle back to its
  layer (`kinematics.altitude`, 100 m for UAV 0) with GUIDED_CHANGE_ALTITUDE in heading mode.
- What the peers hear (a Zenoh peer holding the mission's seed): while the vehicle does not fly the
  plan, the companion's states say `steered = false` and commit to nothing; once it does, they
  carry its trajectory in force again.
"""

from __future__ import annotations

import math
from pathlib import Path

import zenoh
from pymavlink import mavutil

from companion.contracts.frames import LocalFrame
from companion.contracts.zenoh_config import peer_config
from companion.core.messages import StateMsg, UavState
from companion.node.mesh import decode_bundle, key_base
from tests.e2e.conftest import Procs, wait_rows

M = mavutil.mavlink
OUT_BY_M = 150.0  # how far south of the region (y = -1000) the pilot takes the vehicle: past the fence


def test_airframe_warning_region_guard_and_altitude_layer(
    make_mission, procs: Procs, ground, tmp_path: Path
) -> None:
    mission = make_mission(n=1)
    m = mission.mission
    frame = LocalFrame(m.region.origin)
    procs.sim(mission, "--speedup", "10")
    pilot = ground(mission.ports[0], 1)
    pilot.conn.mav.param_set_send(1, 1, b"ROLL_LIMIT_DEG", 20.0, M.MAV_PARAM_TYPE_REAL32)
    assert pilot.wait("PARAM_VALUE", lambda p: p.param_id == "ROLL_LIMIT_DEG" and p.param_value == 20.0)
    pilot.set_guided_and_arm()
    pilot.conn.mav.command_long_send(1, 1, M.MAV_CMD_GUIDED_CHANGE_HEADING, 0, 1, 180, 5, 0, 0, 0, 0)
    pilot.conn.mav.command_int_send(
        1,
        1,
        M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        M.MAV_CMD_GUIDED_CHANGE_ALTITUDE,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        160,
    )

    def out_and_up(g: object) -> bool:
        south = frame.to_local(g.lat * 1e-7, g.lon * 1e-7)[1] < -1000.0 - OUT_BY_M
        return south and g.relative_alt > 155_000

    assert pilot.wait("GLOBAL_POSITION_INT", out_and_up, timeout=120), "the pilot did not get out and up"
    lat, lon, _ = frame.to_geodetic(-300.0, -1000.0 - 2 * OUT_BY_M)  # circle out there meanwhile
    pilot.conn.mav.command_int_send(
        1,
        1,
        M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        M.MAV_CMD_DO_REPOSITION,
        0,
        0,
        -1,
        0,
        0,
        0,
        round(lat * 1e7),
        round(lon * 1e7),
        160,
    )
    out = tmp_path / "out"
    heard: dict[int, UavState] = {}

    def on_bundle(sample: zenoh.Sample) -> None:
        for msg in decode_bundle(sample.payload.to_bytes()).messages:
            if isinstance(msg, StateMsg):
                heard[msg.stamp] = msg.state

    hub = zenoh.open(peer_config((m.mesh.seed_endpoint,), ()))  # holds the seed: the companion joins it
    try:
        hub.declare_subscriber(f"{key_base(m)}/uav/0/msg", on_bundle)
        comp = procs.companion(mission, 0, out, "--command-mode", "heading", "--no-fence", "--steps", "1000")
        comp.wait_for_text("back inside the region: flying the plan", timeout=120)
        rows = wait_rows(out / "uav0.csv", 15, comp, cond=lambda r: r["steered"] == 1)
    finally:
        hub.close()
    states = {k: heard[k] for k in sorted(heard)}
    assert any(not s.steered for s in states.values()) and any(s.steered for s in states.values())
    for r in rows:
        s = states.get(int(r["step"]))
        if s is not None:  # what the peers heard is what the companion did
            assert s.steered == bool(r["steered"]), (r["step"], s)
            assert (s.committed is not None) == s.steered and (s.proposal is None or s.steered)
    text = comp.text()
    assert "left the region plus its margin" in text
    assert "ROLL_LIMIT_DEG = 20 deg" in text and "kinematics.turn_limit_deg = 45" in text
    assert rows[0]["steered"] == 0 and rows[0]["y"] < -1000.0 - OUT_BY_M  # outside: no plan flown
    assert rows[0]["up"] > 150.0
    back = [r for r in rows if r["steered"] == 1]
    assert back[0]["y"] >= -1000.0 - 1e-6  # the plan is flown again from inside the region
    assert math.isclose(back[-1]["up"], m.altitude_of(0), abs_tol=2.0), back[-1]["up"]  # its layer
    assert comp.stop() == 0, comp.text()
