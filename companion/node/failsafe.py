"""The silent companion's failsafe: if the companion dies, its aircraft loiters where it is.

ArduPlane knows its ground station by system id only (MAV_GCS_SYSID; SYSID_MYGCS before 4.7) and,
with FS_GCS_ENABL = 1, starts its long failsafe when no HEARTBEAT from that system has come for
FS_LONG_TIMEOUT seconds. What the long failsafe does in GUIDED is FS_LONG_ACTN: 0 nothing (a
heading hold flies straight on until the fence), 1 RTL (home, across the region), 2 glide, 4 AUTO;
FS_SHORT_ACTN (CIRCLE) acts on RC loss only, never on the GCS's silence. So with `--takeover` the
companion makes itself the autopilot's ground station and arms:

- a mission of one item (after ArduPilot's home, item 0): NAV_LOITER_UNLIM at latitude and
  longitude 0, which ArduPilot reads as "where the aircraft is when the item starts", at the UAV's
  altitude layer, radius `failsafe_loiter_radius` (clockwise);
- MAV_GCS_SYSID = the companion's own system id (`COMPANION_SYSTEM`), FS_LONG_TIMEOUT =
  `safety.failsafe_timeout`, FS_LONG_ACTN = 4 (AUTO), FS_GCS_ENABL = 1.

When the companion falls silent the aircraft flies its last guidance for FS_LONG_TIMEOUT, then
switches to AUTO and circles the point it reached, at its layer. The survivors' model of a silent
UAV (`safety.failsafe_reach`, `companion.core.world.failsafe_reach`) is built on this. When its
HEARTBEATs come back the autopilot clears the failsafe but stays in AUTO (the companion steers only
in GUIDED). The bundled simulator imitates all of it (docs/simulator.md).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core.world import failsafe_loiter_radius
from companion.mission import Mission
from companion.node.mission_upload import Item, upload
from companion.node.vehicle_link import VehicleLink

GCS_SYSID_PARAMS = ("MAV_GCS_SYSID", "SYSID_MYGCS")  # ArduPilot 4.7 on, and before
FS_GCS_HEARTBEAT = 1  # FS_GCS_ENABL: failsafe when the GCS's HEARTBEATs stop
FS_LONG_AUTO = 4  # FS_LONG_ACTN: switch to AUTO
RENAMED_PARAM_WAIT_S = 3.0  # the parameters have answered by then: a missing name is missing


def loiter_here(mission: Mission, uav: int) -> list[Item]:
    """The failsafe's mission: ArduPilot's home (item 0, replaced by the autopilot) and an unlimited
    loiter where the aircraft is when it starts, at the UAV's altitude layer."""
    home = Item(mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0))
    radius = failsafe_loiter_radius(mission)
    loiter = Item(
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_CMD_NAV_LOITER_UNLIM,
        (0, 0, radius, 0),
        0,
        0,
        mission.altitude_of(uav),
    )
    return [home, loiter]


def arm_failsafe(link: VehicleLink, mission: Mission, uav: int) -> str | None:
    """Set up ArduPlane's GCS failsafe as the silent companion's failsafe; the reason on failure."""
    names = link.read_params([GCS_SYSID_PARAMS[0]], timeout=RENAMED_PARAM_WAIT_S)
    if not names:
        names = link.read_params([GCS_SYSID_PARAMS[1]], timeout=RENAMED_PARAM_WAIT_S)
    if not names:
        return f"the autopilot has no {' or '.join(GCS_SYSID_PARAMS)}: no GCS failsafe to use"
    error = upload(link, mavlink.MAV_MISSION_TYPE_MISSION, loiter_here(mission, uav), "failsafe mission")
    if error:
        return error
    sysid_param = next(iter(names))
    if not link.set_param(sysid_param, float(link.system_id)):
        return f"{sysid_param} = {link.system_id} not confirmed"
    link.send_heartbeat()  # heard before the failsafe is enabled: it must not fire on an old silence
    settings = {
        "FS_LONG_TIMEOUT": mission.safety.failsafe_timeout,
        "FS_LONG_ACTN": float(FS_LONG_AUTO),
        "FS_GCS_ENABL": float(FS_GCS_HEARTBEAT),
    }
    for name, value in settings.items():
        if not link.set_param(name, value):
            return f"{name} = {value:g} not confirmed"
    return None
