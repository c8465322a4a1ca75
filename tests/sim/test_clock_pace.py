"""`RealTimeClock.pace` and `Vehicle.awaits_gcs`: the simulated clock runs at real time while a GCS
failsafe waits on a silent ground station (docs/simulator.md, "GCS failsafe"). Wall times are
handed in: no clock is read."""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from companion.core.feasibility import load_mission
from sim_vehicles.clock import RealTimeClock
from sim_vehicles.modes import FLAVOURS
from sim_vehicles.protocols.params import ParamStore, param_specs
from sim_vehicles.vehicle import Vehicle

ROOT = Path(__file__).resolve().parents[2]

TICK = 0.02  # s of simulated time


@given(
    speedup=st.floats(1.5, 50.0),
    fast=st.floats(0.0, 2.0),
    slow=st.floats(0.0, 2.0),
    again=st.floats(0.0, 2.0),
)
def test_the_clock_runs_at_real_time_while_waiting_and_at_speedup_otherwise(
    speedup: float, fast: float, slow: float, again: float
) -> None:
    clock = RealTimeClock(TICK, speedup, wall_start=100.0)
    wall = 100.0 + fast
    tick = clock.target(wall)  # the host ran every tick due
    assert math.isclose(tick * TICK, fast * speedup, abs_tol=TICK)
    clock.pace(wall, tick, waiting=True)
    end_slow = wall + slow
    assert math.isclose(clock.paced_until(end_slow), slow, abs_tol=1e-9)  # a spell still running
    slow_ticks = clock.target(end_slow) - tick
    assert math.isclose(slow_ticks * TICK, slow, abs_tol=TICK)  # 1 simulated s per wall s
    tick += slow_ticks
    clock.pace(end_slow, tick, waiting=False)
    assert math.isclose(clock.paced, slow, abs_tol=1e-9)
    assert clock.paced_until(end_slow + again) == clock.paced  # no spell running
    fast_ticks = clock.target(end_slow + again) - tick
    assert math.isclose(fast_ticks * TICK, again * speedup, abs_tol=TICK)


def test_waiting_changes_nothing_at_or_below_real_time() -> None:
    for speedup in (0.5, 1.0):
        clock = RealTimeClock(TICK, speedup, wall_start=0.0)
        clock.pace(1.0, clock.target(1.0), waiting=True)
        assert clock.rate == speedup and clock.target(3.0) == round(3.0 * speedup / TICK)


def _vehicle() -> Vehicle:
    mission = load_mission(ROOT / "mission_files/scenario1.toml")
    params = ParamStore(param_specs(mission), "ardupilot", grid=True)
    vehicle = Vehicle(0, FLAVOURS["ardupilot"], params, (0.0, 0.0), 100.0, mission.kinematics.step)
    params.values |= {"gcs_sysid": 200.0, "gcs_failsafe": 1.0, "long_timeout": 2.0, "long_action": 4.0}
    vehicle.arm(True)
    return vehicle


def test_a_vehicle_awaits_its_gcs_only_while_its_failsafe_counts_a_silence() -> None:
    v = _vehicle()
    v.heartbeat(10.0, 200)
    assert not v.awaits_gcs(10.5, quiet=1.0)  # heard lately
    assert v.awaits_gcs(11.5, quiet=1.0)  # silent for longer than the quiet spell
    v.heartbeat(11.6, 255)  # another system: not its ground station
    assert v.awaits_gcs(11.7, quiet=1.0)
    v.steer(12.5, 0.0, 0.0, 0.0)  # 2.5 s of silence: the failsafe fires...
    assert v.gcs_failsafe
    assert not v.awaits_gcs(12.6, quiet=1.0)  # ...and waits no more
    v.params.values["gcs_failsafe"] = 0.0
    v.gcs_failsafe = False
    assert not v.awaits_gcs(20.0, quiet=1.0)  # no failsafe armed: nothing to wait for
