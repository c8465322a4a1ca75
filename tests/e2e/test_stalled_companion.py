"""A companion stalled past its failsafe, and a vehicle a pilot takes, in one swarm
(`uavsearch run`, scenario1's four UAVs, continuous, sped up).

- UAV 2's companion is stopped (SIGSTOP) until its autopilot's GCS failsafe fired and 2.5 s of wall
  time more (the simulator runs at real time meanwhile: `RealTimeClock.pace`), then continued: the
  failsafe fired ("GCS Failsafe On: AUTO"), the companion, running again, sees that
  the failsafe was its own and takes the aircraft back into GUIDED, and steers it again
  (docs/companion.md, "A stalled companion").
- UAV 1 is switched to AUTO by a pilot (a ground station) at the same moment: its companion never
  takes it back, and never moves the failsafe loiter while it does not steer, so the aircraft
  circles one fixed circle, the loiter of the last trajectory in force it announced, which is what
  its peers keep clear of (docs/algorithm.md, "A UAV nobody steers").
- No two aircraft lose separation at any time (the simulator's physics-rate record): none comes
  within R_s horizontally while closer vertically than the layers' floor.
"""

from __future__ import annotations

import math
import os
import signal
import time
from pathlib import Path

from companion.app.evaluation import losses_3d, read_approach
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.world import FAILSAFE_WIDE, build_world
from companion.node.vehicle_link import PX4_HOLD, PX4_OFFBOARD
from tests.e2e.conftest import GUIDED, PY, Procs, companion_pid, read_csv, wait_rows, wait_vehicles
from tests.sim.conftest import fit_circle

STEPS = 90
EVENT_AFTER = 15  # steps logged by UAV 2 before the stall and the pilot
STALLED, PILOTED = 2, 1
AUTO = 10
SPEEDUP = 4
FAILSAFE_TIMEOUT_S = 2.0  # FS_LONG_TIMEOUT (one step): 0.5 s of wall time at SPEEDUP
STALL_S = 2.5  # wall seconds after the failsafe fired (simulated seconds too: the clock is paced)


def test_stalled_companion_takes_back_its_aircraft_and_a_piloted_one_stays_put(
    make_mission, procs: Procs, ground, tmp_path: Path
) -> None:
    mission = make_mission(n=4, safety=f"failsafe_timeout = {FAILSAFE_TIMEOUT_S}")
    m = mission.mission
    out = tmp_path / "out"
    run = procs.start(
        "run",
        [PY, "-m", "companion.cli", "run", str(mission.path), "--speedup", str(SPEEDUP),
         "--steps", str(STEPS), "--out", str(out), "--quiet", "--keep-going"],
    )  # fmt: skip
    stalled_pid = companion_pid(run, STALLED)
    wait_vehicles(run, out, m.n_uavs)
    stalled_gcs = ground(mission.ports[STALLED], STALLED + 1)
    pilot = ground(mission.ports[PILOTED], PILOTED + 1)
    wait_rows(out / f"uav{STALLED}.csv", EVENT_AFTER, run)
    for i in (STALLED, PILOTED):
        assert "failsafe armed" in (out / f"companion{i}.log").read_text()

    os.kill(stalled_pid, signal.SIGSTOP)
    try:
        pilot.set_mode(AUTO)
        piloted_from = int(read_csv(out / f"uav{PILOTED}.csv")[-1]["step"])
        fired = stalled_gcs.wait("STATUSTEXT", lambda s: s.text.startswith("GCS Failsafe On"), timeout=60.0)
        assert fired is not None, "the stalled companion's failsafe did not fire"
        time.sleep(STALL_S)
        # read while it is stopped: once continued, it logs its first (unsteered) step at once
        stopped_at = int(read_csv(out / f"uav{STALLED}.csv")[-1]["step"])
    finally:
        os.kill(stalled_pid, signal.SIGCONT)
    back = stalled_gcs.wait("HEARTBEAT", lambda h: h.get_srcComponent() == 1 and h.custom_mode == GUIDED, 60)
    assert back is not None, "the stalled companion did not take its aircraft back into GUIDED"

    # the piloted aircraft: AUTO to the end, circling one circle (its loiter is never moved)
    frame = LocalFrame(m.region.origin)
    track: list[tuple[float, tuple[float, float]]] = []  # (vehicle time s, local position)
    modes: set[int] = set()
    while run.alive():
        msg = pilot.wait(["GLOBAL_POSITION_INT", "HEARTBEAT"], timeout=2.0)
        if msg is None:
            continue
        if msg.get_type() == "GLOBAL_POSITION_INT":
            track.append((msg.time_boot_ms * 1e-3, frame.to_local(msg.lat * 1e-7, msg.lon * 1e-7)))
        elif msg.get_srcComponent() == 1:
            modes.add(msg.custom_mode)
    assert run.popen.returncode in (0, 1), run.text()  # 1: pass criteria not met in so short a mission
    assert modes == {AUTO}, f"the piloted vehicle left AUTO: modes {modes}"
    world = build_world(m)
    start, end = track[0][0] + 30.0, track[-1][0]  # on its circle 30 s after the pilot took it
    lap = 2 * math.pi * FAILSAFE_WIDE * world.safety.loiter_radius / m.kinematics.speed
    assert end - start > 3 * lap, "the run ended too soon after the pilot took over"
    first = fit_circle([p for t, p in track if start <= t < start + lap])
    last = fit_circle([p for t, p in track if t >= end - lap])
    drift = math.dist(first[:2], last[:2])
    print(f"piloted: circle r {first[2]:.0f} m; its centre moved {drift:.1f} m in {end - start:.0f} s")
    assert drift < 5.0, "the piloted aircraft's loiter moved"
    assert max(math.dist(p, first[:2]) for t, p in track if t >= start) <= world.safety.failsafe_reach
    piloted = read_csv(out / f"uav{PILOTED}.csv")
    assert not any(r["steered"] for r in piloted if r["step"] > piloted_from + 1), "uav 1 steered again"
    assert "not taking it back" not in (out / f"companion{PILOTED}.log").read_text()

    # the stalled companion: its own failsafe seen, the aircraft taken back, steering again
    log = (out / f"companion{STALLED}.log").read_text()
    assert "our own GCS failsafe fired" in log and "back in GUIDED" in log, log
    rows = read_csv(out / f"uav{STALLED}.csv")
    after = [r for r in rows if r["step"] > stopped_at]
    assert any(not r["steered"] for r in after), "no unsteered step after the stall"
    assert sum(1 for r in after if r["steered"]) >= 20, "it did not steer again"

    assert_separated(out / "approach.csv", m)


def test_stalled_companion_takes_its_px4_aircraft_back_from_the_offboard_loss_hold(
    make_mission, procs: Procs, ground, tmp_path: Path
) -> None:
    """PX4 (the simulator's PX4 flavour, position-target in OFFBOARD): a companion stopped for longer
    than COM_OF_LOSS_T finds its aircraft in Hold, PX4's offboard-loss failsafe, and takes it back
    into OFFBOARD once it runs again (docs/companion.md, "A stalled companion"); separation is kept."""
    mission = make_mission(n=4)
    m = mission.mission
    out = tmp_path / "out"
    run = procs.start(
        "run",
        [PY, "-m", "companion.cli", "run", str(mission.path), "--speedup", str(SPEEDUP),
         "--steps", str(STEPS), "--out", str(out), "--quiet", "--keep-going", "--flavour", "px4",
         "--command-mode", "position-target"],
    )  # fmt: skip
    stalled_pid = companion_pid(run, STALLED)
    wait_vehicles(run, out, m.n_uavs)
    stalled_gcs = ground(mission.ports[STALLED], STALLED + 1)
    wait_rows(out / f"uav{STALLED}.csv", EVENT_AFTER, run)
    assert "OFFBOARD taken back" in (out / f"companion{STALLED}.log").read_text()

    os.kill(stalled_pid, signal.SIGSTOP)
    try:
        held = stalled_gcs.wait(
            "HEARTBEAT", lambda h: h.get_srcComponent() == 1 and h.custom_mode == PX4_HOLD, 60
        )
        assert held is not None, (
            "PX4's offboard-loss failsafe did not put the stalled companion's aircraft in Hold"
        )
        time.sleep(STALL_S)
        stopped_at = int(read_csv(out / f"uav{STALLED}.csv")[-1]["step"])
    finally:
        os.kill(stalled_pid, signal.SIGCONT)
    back = stalled_gcs.wait(
        "HEARTBEAT", lambda h: h.get_srcComponent() == 1 and h.custom_mode == PX4_OFFBOARD, 60
    )
    assert back is not None, "the stalled companion did not take its aircraft back into OFFBOARD"
    assert run.wait(timeout=600) in (0, 1), run.text()  # 1: pass criteria not met in so short a mission

    log = (out / f"companion{STALLED}.log").read_text()
    assert "our own offboard-loss failsafe fired" in log and "back in GUIDED" in log, log
    after = [r for r in read_csv(out / f"uav{STALLED}.csv") if r["step"] > stopped_at]
    assert sum(1 for r in after if r["steered"]) >= 20, "it did not steer again"
    assert_separated(out / "approach.csv", m)


def assert_separated(approach: Path, m: Mission) -> None:
    """Separation throughout, from the simulator's physics-rate record, in three dimensions: a
    stalled companion's aircraft is not a live peer, so a UAV on a layer apart may pass it closer
    than R_s horizontally (docs/algorithm.md, "Separation in three dimensions")."""
    closest = min(read_approach(approach).values())
    print(f"closest horizontal approach of any two aircraft: {closest:.1f} m (R_s {m.comms.safety:g} m)")
    assert losses_3d(approach, m) == 0, f"separation lost in 3D (closest horizontal {closest:.1f} m)"
