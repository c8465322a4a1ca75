"""The autopilot's return (RTL) flown at the UAV's own altitude layer.

The fence's breach action is a return (ArduPilot RTL, PX4 Return: `companion.node.fence`), and an
autopilot may return for reasons of its own (battery, RC loss). Its return altitude is one value
for every aircraft unless set: they would all climb or sink to it and leave their layers. So with
`--takeover` (when the fence is set) the companion sets it to `Mission.altitude_of(uav)`:
- ArduPlane 4.5 on: RTL_ALTITUDE (m above home; -1 would be the altitude at the switch); before
  4.5: ALT_HOLD_RTL (cm above home, -1 the same). RTL_CLIMB_MIN, an extra climb on entering RTL,
  is set to 0 where it is not.
- PX4: RTL_RETURN_ALT (m above home, the lowest a return flies at: an aircraft above it returns at
  its own altitude), RTL_DESCEND_ALT (m above home: the altitude it circles home at) and
  RTL_CONE_ANG = 0 (the cone would lower the return altitude near home).
"""

from __future__ import annotations

from companion.node.vehicle_link import VehicleLink

ARDUPILOT_RTL = ("RTL_ALTITUDE", 1.0)  # (name, units per metre), ArduPlane 4.5 on
ARDUPILOT_RTL_OLD = ("ALT_HOLD_RTL", 100.0)  # before 4.5: centimetres
ARDUPILOT_CLIMB_MIN = "RTL_CLIMB_MIN"
PX4_RTL = ("RTL_RETURN_ALT", "RTL_DESCEND_ALT")
PX4_CONE = "RTL_CONE_ANG"
PARAM_WAIT_S = 3.0


def return_settings(link: VehicleLink, altitude: float) -> dict[str, float] | str:
    """The parameters that make this autopilot return at `altitude` m above home, or why none."""
    if link.state.px4:
        have = link.params.read([*PX4_RTL, PX4_CONE], timeout=PARAM_WAIT_S)
        if PX4_RTL[0] not in have:
            return f"the autopilot has no {PX4_RTL[0]}"
        out = {name: altitude for name in PX4_RTL if name in have}
        if have.get(PX4_CONE, 0.0) != 0.0:
            out[PX4_CONE] = 0.0
        return out
    have = link.params.read([ARDUPILOT_RTL[0], ARDUPILOT_CLIMB_MIN], timeout=PARAM_WAIT_S)
    if ARDUPILOT_RTL[0] in have:
        name, scale = ARDUPILOT_RTL
    else:
        name, scale = ARDUPILOT_RTL_OLD
        if not link.params.read([name], timeout=PARAM_WAIT_S):
            return f"the autopilot has neither {ARDUPILOT_RTL[0]} nor {ARDUPILOT_RTL_OLD[0]}"
    out = {name: round(altitude * scale, 2)}
    if have.get(ARDUPILOT_CLIMB_MIN, 0.0) != 0.0:
        out[ARDUPILOT_CLIMB_MIN] = 0.0
    return out


def set_return_altitude(link: VehicleLink, altitude: float) -> str | None:
    """Make the autopilot's return fly at `altitude` m above home; the reason on failure."""
    settings = return_settings(link, altitude)
    if isinstance(settings, str):
        return settings
    for name, value in settings.items():
        if not link.params.set(name, value):
            return f"{name} = {value:g} not confirmed"
    return None
