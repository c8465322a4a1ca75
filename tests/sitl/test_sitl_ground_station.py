"""ArduPlane SITL shows the companion's reports to a ground station on another of its links.

One instance on the ground (ADS-B on as `uavsearch run` sets it, AVD_* untouched), in a real run's
order: the companion's link on SERIAL1 (system 200, as `uavsearch companion` speaks) asks for
telemetry, waits for the pose, uploads the mission's fence (`fence.upload_fence`, as the preflight:
read-back check, FENCE_ENABLE), and only then sends what `GroundStationFeed` sends each step, for
two known targets and one peer. MAVProxy on SERIAL2 must see the companion's STATUSTEXT,
CAMERA_TRACKING_GEO_STATUS, NAMED_VALUE_FLOAT and HEARTBEAT as sent, and the peer as ArduPlane's own
ADSB_VEHICLE (system 1) at a position the companion sent: with ADS-B on, ArduPlane never routes
another system's ADSB_VEHICLE, it takes it into its ADS-B list and sends the list
(docs/companion.md, "What the ground station sees"). The mission is scenario1_nofly; the fence read
back on SERIAL2 by plain pymavlink must be the mission's, the no-fly band as the operator's .plan
draws it.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from pymavlink import mavutil

from companion.app import sitl
from companion.contracts.frames import LocalFrame
from companion.core.agent import Agent
from companion.core.messages import UavState
from companion.core.world import build_world
from companion.node.fence import fence_items, fence_margin, upload_fence
from companion.node.ground_station import GroundStationFeed
from companion.node.vehicle_link import COMPANION_SYSTEM, VehicleLink, open_link
from tests.e2e.conftest import SCENARIO1_NOFLY, Proc, mavproxy_argv
from tests.fence_readback import assert_exclusions_as_drawn, companion_fence, read_fence
from tests.sitl.conftest import GCS_COMPONENT, STARTUP_S, write_mission

STEPS = 15


def _drain(link: VehicleLink, stop: threading.Event) -> None:
    while not stop.is_set():
        link.poll(0.2)


def test_arduplane_shows_the_reports_to_its_ground_station(sitl_binary: Path, tmp_path: Path) -> None:
    mission = write_mission(tmp_path, n=2, base=SCENARIO1_NOFLY)
    m, ports = mission.mission, mission.ports(0)
    assert len(m.region.nofly) == 1
    frame = LocalFrame(m.region.origin)
    home = tmp_path / "sitl0"
    home.mkdir()
    extra = sitl.write_run_params(home)  # ADS-B on, as `uavsearch run` sets it
    assert sitl.RUN_PARAMS["ADSB_TYPE"] == 1
    argv = sitl.sitl_argv(sitl_binary, sitl.find_defaults(sitl_binary), m, 0, 1.0, extra)
    proc = Proc("sitl0", argv, home / "out.log", cwd=home, stop_signal=sitl.STOP_SIGNAL)
    stop = threading.Event()
    links: list[VehicleLink] = []
    proxy = None
    try:
        gone = lambda: not proc.alive()  # noqa: E731
        # SERIAL0: SITL's clock starts when a client connects there (the camera's port in a run)
        serial0 = open_link(ports.url(ports.serial0), frame, STARTUP_S, gone, component=GCS_COMPONENT)
        assert serial0 is not None and serial0.wait_heartbeat(STARTUP_S, gone), proc.text()
        links.append(serial0)
        threading.Thread(target=_drain, args=(serial0, stop), daemon=True).start()
        argv, tlog = mavproxy_argv(ports.url(ports.serial2), tmp_path / "mavproxy")
        proxy = Proc("mavproxy", argv, tmp_path / "mavproxy.log", cwd=tlog.parent)
        proxy.wait_for_text("Mode ", timeout=STARTUP_S)
        sent = tmp_path / "companion.tlog"  # what the companion sent (and received)
        url = ports.url(ports.serial1)
        companion = open_link(url, frame, STARTUP_S, gone, system=COMPANION_SYSTEM, heartbeat=True, tlog=sent)
        assert companion is not None and companion.wait_heartbeat(STARTUP_S, gone)
        links.append(companion)
        # a real run's preflight: telemetry, the pose, then the fence, before the first report
        companion.request_streams()
        while not companion.state.has_pose:
            assert proc.alive(), proc.text()
            companion.poll(0.2)
        margin = fence_margin(m) + m.kinematics.speed * m.kinematics.step  # as the preflight's
        assert upload_fence(companion, fence_items(m, frame, margin)) is None
        agent = Agent(build_world(m, m.seed, 0), 0)
        agent.found = {10, 20}
        v = m.vehicles[1]
        feed = GroundStationFeed(companion, frame, m, 0)
        for k in range(STEPS):
            agent.peers = {1: UavState(1, k, v.x, v.y + 20.0 * k, 1.5708, ())}
            feed.step(k + 1, agent, steered=True)
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                companion.poll(0.1)
        proxy.stop(timeout=15)
        url = ports.url(ports.serial2)  # MAVProxy gone: SERIAL2 is free
        reader = mavutil.mavlink_connection(url, source_system=250, dialect="ardupilotmega")
        try:
            fence = read_fence(reader, 1)
        finally:
            reader.close()
    finally:
        stop.set()
        if proxy is not None:
            proxy.stop(timeout=15)
        for link in links:
            link.close()
        proc.stop()

    assert fence == companion_fence(m), fence
    assert_exclusions_as_drawn(fence, SCENARIO1_NOFLY.parent / m.region.area)
    seen: dict[tuple[int, str], list] = {}
    log = mavutil.mavlink_connection(str(tlog))
    while (msg := log.recv_match()) is not None:
        seen.setdefault((msg.get_srcSystem(), msg.get_type()), []).append(msg)
    for kind in ("STATUSTEXT", "CAMERA_TRACKING_GEO_STATUS", "NAMED_VALUE_FLOAT", "HEARTBEAT"):
        assert (COMPANION_SYSTEM, kind) in seen, (kind, sorted(seen))
    targets = [t.text for t in seen[(COMPANION_SYSTEM, "STATUSTEXT")] if "target at" in t.text]
    assert len(targets) == 2, targets
    names = {n.name for n in seen[(COMPANION_SYSTEM, "NAMED_VALUE_FLOAT")]}
    assert names == {"coverage", "mean_eta", "found", "p_unfound", "cpu_pct"}, names
    beats = seen[(COMPANION_SYSTEM, "HEARTBEAT")]
    assert any(b.system_status == mavutil.mavlink.MAV_STATE_ACTIVE for b in beats)
    # the peer: not the companion's ADSB_VEHICLE (ArduPlane's ADS-B takes it, MAVLink_routing.cpp)
    # but ArduPlane's own, each at a position the companion sent
    assert (COMPANION_SYSTEM, "ADSB_VEHICLE") not in seen, len(seen[(COMPANION_SYSTEM, "ADSB_VEHICLE")])
    ours = mavutil.mavlink_connection(str(sent), dialect="ardupilotmega")
    reported: set[tuple[int, int, int]] = set()
    while (msg := ours.recv_match(type="ADSB_VEHICLE")) is not None:
        reported.add((msg.ICAO_address, msg.lat, msg.lon))
    assert len(reported) == STEPS, reported
    listed = [a for a in seen.get((1, "ADSB_VEHICLE"), []) if a.callsign == "UAV1"]
    assert listed, f"UAV1 not in ArduPlane's ADS-B list; it sent {len(seen.get((1, 'ADSB_VEHICLE'), []))}"
    assert {(a.ICAO_address, a.lat, a.lon) for a in listed} <= reported, listed
