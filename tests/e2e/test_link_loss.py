"""Vehicle link lost and restored: the simulator is stopped mid-flight, then started again.

The companion runs without --takeover, as on a real aircraft: the test plays the pilot and puts
the vehicle in GUIDED and arms it. When the vehicle goes silent the companion says the link is
lost, stops steering and keeps running with its state; when a vehicle answers again on the same
endpoint (the pilot puts it back in GUIDED) it says the link is restored and steers again.
"""

from __future__ import annotations

import socket
from pathlib import Path

from tests.e2e.conftest import Procs, read_csv, wait_rows

LOST = "vehicle link lost"
RESTORED = "vehicle link restored"


def test_companion_survives_link_loss_and_resumes(make_mission, procs: Procs, ground, tmp_path: Path) -> None:
    mission = make_mission(n=1)
    out = tmp_path / "out"
    csv_path = out / "uav0.csv"
    sim = procs.sim(mission, "--speedup", "10")
    comp = procs.companion(mission, 0, out, "--steps", "100000")
    pilot = ground(mission.ports[0], 1)
    pilot.set_guided_and_arm()
    wait_rows(csv_path, 10, comp, cond=lambda r: r["steered"] == 1)

    # SIGINT to one of its threads other than the main one (the kernel may pick any): the vehicle goes silent
    assert sim.stop(through_a_thread=True) == 0, sim.text()
    comp.wait_for_text(LOST, timeout=60)
    assert comp.alive(), comp.text()
    before = read_csv(csv_path)
    last = int(before[-1]["step"])
    assert RESTORED not in comp.text()

    procs.sim(mission, "--speedup", "10", name="sim2")  # the same vehicle endpoint again
    pilot.set_guided_and_arm()
    comp.wait_for_text(RESTORED, timeout=60)
    rows = wait_rows(csv_path, 5, comp, cond=lambda r: r["step"] > last and r["steered"] == 1)

    # during the outage nothing was steered: no step at all between the loss and the restoration
    assert rows[: len(before)] == before
    after = [r for r in rows if r["step"] > last]
    assert after and all(r["step"] > last for r in rows[len(before) :])
    assert sum(r["steered"] for r in after) >= 5
    assert comp.text().index(LOST) < comp.text().index(RESTORED)

    # SIGINT, again to a thread other than the main one: a clean shutdown, its report written
    assert comp.stop(through_a_thread=True) == 0, comp.text()
    assert "Traceback" not in comp.text(), comp.text()
    assert (out / "uav0.json").exists()


def test_companion_stopped_before_its_vehicle_answers_exits_0(
    make_mission, procs: Procs, tmp_path: Path
) -> None:
    """No vehicle on the endpoint: a signal while it waits is a clean stop, not "no HEARTBEAT within
    120 s" and exit 1 (as it was); the signal goes to a thread other than the main one."""
    mission = make_mission(n=1)
    out = tmp_path / "out"
    comp = procs.companion(mission, 0, out)
    comp.wait_for_text("waiting for the vehicle")
    assert comp.stop(through_a_thread=True) == 0, comp.text()
    assert "stopped by a signal" in comp.text()
    assert "error:" not in comp.text(), comp.text()
    assert "0 steps flown" in comp.text()


def test_companion_waits_for_a_tcp_vehicle_not_listening_yet(
    make_mission, procs: Procs, tmp_path: Path
) -> None:
    """An autopilot's TCP port that refuses the connection (SITL still booting) is tried again, not a
    traceback (as it was); a signal meanwhile is a clean stop."""
    mission = make_mission(n=1)
    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        url = f"tcp:127.0.0.1:{s.getsockname()[1]}"
    comp = procs.companion(mission, 0, tmp_path / "out", "--vehicle", url)
    comp.wait_for_text(f"cannot open {url} yet")
    assert comp.stop() == 0, comp.text()
    assert "Traceback" not in comp.text() and "error:" not in comp.text(), comp.text()
