"""The search as a ground station connected to the autopilot (not to the companion) sees it.

MAVProxy, headless, on vehicle 0's endpoint of the bundled simulator, while two companions search
scenario1_nofly (a no-fly band across the area, from the operator's .plan): the simulator routes
the companion's reports to it as ArduPlane routes its links, and its .tlog must hold a STATUSTEXT
and a CAMERA_TRACKING_GEO_STATUS at each target's cell for every target companion 0 knows, the
progress and the companion's CPU load as NAMED_VALUE_FLOATs, its HEARTBEAT saying ACTIVE while it
steers, and UAV 1 as ADSB_VEHICLE traffic at the positions it logged. The fence, read back from
each vehicle by pymavlink, is the mission's: the inclusion polygon and the band as the .plan draws it.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from pymavlink import mavutil

from companion.contracts.frames import LocalFrame
from companion.core.world import build_world
from companion.node.vehicle_link import COMPANION_COMPONENT, COMPANION_SYSTEM
from tests.e2e.conftest import SCENARIO1_NOFLY, Ground, Procs, mavproxy_argv, read_csv, wait_rows
from tests.fence_readback import assert_exclusions_as_drawn, companion_fence, read_fence

WAIT_S = 600.0  # generous: two companions, a simulator and MAVProxy on a busy 2-core machine
AUTOPILOT = mavutil.mavlink.MAV_COMP_ID_AUTOPILOT1
# targets companion 0 must know before the run is stopped: one, since two UAVs searching in
# real time may never cross the band to the targets north of it (a run once flew 3,000 steps
# south of it: docs/results.md, "No-fly zones")
TARGETS = 1
TEXT = re.compile(r"UAV(\d+) target at (-?\d+\.\d+) (-?\d+\.\d+)")


def _received(tlog: Path) -> dict[str, list]:
    """The companion's messages in MAVProxy's .tlog, by type; the autopilot's STATUSTEXTs as "autopilot"."""
    log = mavutil.mavlink_connection(str(tlog))
    kinds = ["STATUSTEXT", "CAMERA_TRACKING_GEO_STATUS", "NAMED_VALUE_FLOAT", "HEARTBEAT"]
    out: dict[str, list] = {k: [] for k in [*kinds, "ADSB_VEHICLE", "autopilot"]}
    while (msg := log.recv_match(type=[*kinds, "ADSB_VEHICLE"])) is not None:
        if (msg.get_srcSystem(), msg.get_srcComponent()) == (COMPANION_SYSTEM, COMPANION_COMPONENT):
            out[msg.get_type()].append(msg)
        elif msg.get_type() == "STATUSTEXT" and msg.get_srcComponent() == AUTOPILOT:
            out["autopilot"].append(msg.text)
    return out


def test_mavproxy_on_the_autopilot_sees_the_search(make_mission, procs: Procs, tmp_path: Path) -> None:
    mission = make_mission(n=2, base=SCENARIO1_NOFLY)
    m = mission.mission
    assert len(m.region.nofly) == 1
    out = tmp_path / "out"
    procs.sim(mission, "--speedup", "10")
    argv, tlog = mavproxy_argv(f"udpout:127.0.0.1:{mission.ports[0]}", tmp_path / "mavproxy")
    proxy = procs.start("mavproxy", argv, cwd=tlog.parent)
    proxy.wait_for_text("Mode ", timeout=WAIT_S)  # it hears the vehicle: the simulator knows it
    comps = [procs.companion(mission, i, out, "--takeover", "--steps", "5000") for i in range(2)]
    wait_rows(out / "uav0.csv", 1, comps[0], timeout=WAIT_S, cond=lambda r: r["found"] >= TARGETS)
    for comp in comps:
        assert comp.stop() == 0, comp.text()
        assert "fence enabled and read back" in comp.text(), comp.text()
    for i, port in enumerate(mission.ports):  # the fence each vehicle holds, read by pymavlink alone
        ground = Ground(port, i + 1)
        try:
            fence = read_fence(ground.conn, i + 1)
        finally:
            ground.close()
        assert fence == companion_fence(m), fence
        assert_exclusions_as_drawn(fence, SCENARIO1_NOFLY.parent / m.region.area)
    assert proxy.alive(), proxy.text()
    proxy.stop(timeout=15)
    assert "Traceback" not in proxy.text(), proxy.text()
    got = _received(tlog)
    assert not [t for t in got["autopilot"] if "Fence" in t], got["autopilot"]  # the band kept clear

    # every target companion 0 knows: a STATUSTEXT and a CAMERA_TRACKING_GEO_STATUS at its cell
    report = json.loads((out / "uav0.json").read_text())
    # MAVProxy's HEARTBEATs (one a second), routed to the companion, are not refused; its first
    # REQUEST_DATA_STREAM to every system is, as on ArduPlane SITL
    assert report["mavlink_wrong_system"] <= 3, report["refused"]
    assert report["fence_uploaded"], report
    found = report["found_cells"]
    assert len(found) >= TARGETS
    world, frame = build_world(m, m.seed, 0), LocalFrame(m.region.origin)
    texts = [TEXT.fullmatch(t.text) for t in got["STATUSTEXT"]]
    said = [(float(t[2]), float(t[3])) for t in texts if t is not None and t[1] == "0"]
    plotted = [(g.lat * 1e-7, g.lon * 1e-7) for g in got["CAMERA_TRACKING_GEO_STATUS"]]
    for cell in found:
        lat, lon, _ = frame.to_geodetic(*map(float, world.grid.centres[cell]))
        assert any(abs(a - lat) < 2e-6 and abs(b - lon) < 2e-6 for a, b in said), (cell, said)
        assert any(abs(a - lat) < 2e-7 and abs(b - lon) < 2e-7 for a, b in plotted), (cell, plotted)
    assert len(said) == len(plotted) == len(found), (said, plotted, found)

    # the progress, once a step: every name, and the targets found counted up to the last
    values: dict[str, list[float]] = {}
    for msg in got["NAMED_VALUE_FLOAT"]:
        values.setdefault(msg.name, []).append(msg.value)
    assert set(values) == {"coverage", "mean_eta", "found", "p_unfound", "cpu_pct"}, values.keys()
    assert max(values["found"]) == len(found)
    assert 0 < max(values["coverage"]) <= 1 and 0 < min(values["mean_eta"]) <= 1
    assert all(0 <= p <= 1 for p in values["p_unfound"]) and values["p_unfound"][-1] < values["p_unfound"][0]

    # the companion's health: its HEARTBEAT, ACTIVE while it steers, and its CPU load
    beats = got["HEARTBEAT"]
    assert all(b.type == mavutil.mavlink.MAV_TYPE_ONBOARD_CONTROLLER for b in beats)
    assert any(b.system_status == mavutil.mavlink.MAV_STATE_ACTIVE for b in beats), len(beats)
    assert all(0 <= c <= 200 for c in values["cpu_pct"])  # two cores: a process may use more than one

    # UAV 1 as traffic, where it logged itself, at its layer
    traffic = got["ADSB_VEHICLE"]
    assert traffic, "no ADSB_VEHICLE"
    rows = read_csv(out / "uav1.csv")
    alt = m.region.origin.alt + m.altitude_of(1)
    for msg in traffic:
        assert msg.callsign == "UAV1" and msg.emitter_type == mavutil.mavlink.ADSB_EMITTER_TYPE_UAV
        assert abs(msg.altitude * 1e-3 - alt) < 0.01 and msg.tslc <= 10
        x, y = frame.to_local(msg.lat * 1e-7, msg.lon * 1e-7)
        assert min(math.hypot(x - r["x"], y - r["y"]) for r in rows) < 0.5, (x, y)
