"""What the autopilot can fly, read from its parameters on connecting, checked against the mission.

The companion reads the cruise airspeed, its range and the bank limit (ArduPlane AIRSPEED_CRUISE,
AIRSPEED_MIN, AIRSPEED_MAX, ROLL_LIMIT_DEG; PX4 FW_AIRSPD_TRIM, FW_AIRSPD_MIN, FW_AIRSPD_MAX,
FW_R_LIM) and warns, naming the fields, when the mission's speed or turn limit cannot be flown.
It also decides which command modes the autopilot can fly: the yaw-rate target of `turn-rate`
and the cell-centre poses of grid kinematics exist only in the bundled simulator, which says so
with its own parameter SIM_TURN_LIMIT.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.contracts.mission import Kinematics, Mission

GRAVITY = 9.80665
GUIDED_P = 50.0  # ArduPlane's GUIDED_P default: 5000 centidegrees of bank per radian of heading error
SIMULATOR_PARAM = "SIM_TURN_LIMIT"
PARAMS = {
    "ardupilot": {
        "cruise": "AIRSPEED_CRUISE",
        "min": "AIRSPEED_MIN",
        "max": "AIRSPEED_MAX",
        "bank": "ROLL_LIMIT_DEG",
    },
    "px4": {"cruise": "FW_AIRSPD_TRIM", "min": "FW_AIRSPD_MIN", "max": "FW_AIRSPD_MAX", "bank": "FW_R_LIM"},
}


def turn_rate_limit(k: Kinematics) -> float:
    """The mission's largest turn rate (rad/s): turn_limit_deg per step."""
    return math.radians(k.turn_limit_deg) / k.step


def turn_accel(k: Kinematics) -> float:
    """Centripetal acceleration (m/s^2) of the mission's tightest turn at its speed: v * omega_max."""
    return k.speed * turn_rate_limit(k)


def bank_for(k: Kinematics) -> float:
    """Bank angle (degrees) of a coordinated turn at the mission's speed and turn limit."""
    return math.degrees(math.atan(turn_accel(k) / GRAVITY))


def heading_lead(k: Kinematics, rate: float) -> float:
    """How far (rad) past the plan's heading at the step's end to command GUIDED_CHANGE_HEADING.

    With that lead ArduPlane, in a turn at the planned `rate` (rad/s), ends each step on the plan's
    heading. ArduPlane banks GUIDED_P per radian of heading error; linearised, its heading closes the
    error at c = g * GUIDED_P / v per second, so a command that moves on by rate * dT each step leaves
    an error rate * dT * q / (1 - q), q = exp(-c * dT), at the step's end: the lead.
    """
    q = math.exp(-GRAVITY * math.radians(GUIDED_P) * k.step / k.speed)
    return rate * k.step * q / (1.0 - q)


@dataclass(frozen=True)
class Airframe:
    """The autopilot's parameters that matter to the mission (None: it did not answer)."""

    flavour: str
    values: dict[str, float]
    simulator: bool  # the bundled simulator (it has SIM_TURN_LIMIT)

    @staticmethod
    def names(flavour: str) -> list[str]:
        """The parameters to read (SIMULATOR_PARAM separately: only the bundled simulator has it)."""
        return list(PARAMS[flavour].values())

    @classmethod
    def from_params(cls, flavour: str, values: dict[str, float]) -> Airframe:
        return cls(flavour, dict(values), SIMULATOR_PARAM in values)

    def name(self, role: str) -> str:
        return PARAMS[self.flavour][role]

    def get(self, role: str) -> float | None:
        return self.values.get(self.name(role))


def check_mission(mission: Mission, airframe: Airframe) -> list[str]:
    """Warnings (empty: flyable) when the mission's speed or turn limit is beyond the airframe."""
    k = mission.kinematics
    out = []
    lo, hi = airframe.get("min"), airframe.get("max")
    if lo is not None and hi is not None and not lo <= k.speed <= hi:
        out.append(
            f"kinematics.speed = {k.speed:g} m/s is outside the autopilot's airspeed range "
            f"{airframe.name('min')}..{airframe.name('max')} = {lo:g}..{hi:g} m/s"
        )
    bank_limit = airframe.get("bank")
    if bank_limit is not None and bank_for(k) > bank_limit:
        out.append(
            f"kinematics.turn_limit_deg = {k.turn_limit_deg:g} per kinematics.step = {k.step:g} s at "
            f"kinematics.speed = {k.speed:g} m/s needs a {bank_for(k):.1f} deg bank, more than the "
            f"autopilot's {airframe.name('bank')} = {bank_limit:g} deg"
        )
    missing = [n for n in PARAMS[airframe.flavour].values() if n not in airframe.values]
    if missing:
        out.append(
            f"the autopilot did not report {', '.join(missing)}: the mission is not checked against them"
        )
    return out


def refusal(mission: Mission, airframe: Airframe, command_mode: str) -> str | None:
    """Why this autopilot cannot fly the mission in this command mode (None: it can)."""
    px4 = airframe.flavour == "px4"
    if command_mode == "heading" and px4:
        return "PX4 has no MAV_CMD_GUIDED_CHANGE_HEADING: use --command-mode reposition or position-target"
    if command_mode == "position-target" and not px4:
        return (
            "ArduPlane takes only the altitude from SET_POSITION_TARGET_GLOBAL_INT in GUIDED: "
            "use --command-mode heading or reposition"
        )
    if airframe.simulator:
        return None
    if mission.kinematics.mode == "grid":
        return (
            'kinematics.mode = "grid" is the paper\'s idealised model (the pose snaps to cell centres and '
            "turns in 45 degree steps), which a real autopilot cannot fly: use "
            'kinematics.mode = "continuous"'
        )
    if command_mode == "turn-rate":
        instead = "position-target or reposition" if px4 else "heading or reposition"
        return (
            "--command-mode turn-rate is the bundled simulator's yaw-rate target, which this autopilot "
            f"does not fly: use --command-mode {instead}"
        )
    return None
