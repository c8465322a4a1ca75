"""The silent companion's failsafe: a dead companion's aircraft circles its trajectory's last loiter.

If the companion dies, its aircraft circles the loiter its trajectory in force ends in, the loiter
every other UAV's trajectory already keeps clear of. With `--takeover` the companion makes itself
ArduPlane's ground station (MAV_GCS_SYSID = `COMPANION_SYSTEM`) and arms its GCS failsafe
(FS_LONG_ACTN = AUTO) on a one-item mission, NAV_LOITER_UNLIM about that loiter (`FailsafeLoiter`,
uploaded again whenever the loiter changes). At the mission's end it hands the aircraft over at
once (`hand_over`); a companion that was only stalled sees its own failsafe fired
(`fired_by_our_silence`) and takes GUIDED back (`watch.VehicleWatch`). Why each parameter, and what
ArduPlane does: docs/companion.md, "The failsafe for a silent companion".
"""

from __future__ import annotations

import math
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission
from companion.core.trajectory import Trajectory
from companion.core.world import World
from companion.node.mission_upload import Item
from companion.node.vehicle_link import ARDUPILOT_AUTO, VehicleLink

GCS_SYSID_PARAMS = ("MAV_GCS_SYSID", "SYSID_MYGCS")  # ArduPilot 4.7 on, and before
FS_GCS_HEARTBEAT = 1  # FS_GCS_ENABL: failsafe when the GCS's HEARTBEATs stop
FS_LONG_AUTO = 4  # FS_LONG_ACTN: switch to AUTO
RENAMED_PARAM_WAIT_S = 3.0  # the parameters have answered by then: a missing name is missing
HAND_OVER_WAIT_S = 5.0  # an autopilot confirms a mode change in its next HEARTBEAT, within 1 s
SAME_CENTRE_M = 0.5  # a loiter centre that moved less is not uploaded again
FAILSAFE_TEXT = "GCS Failsafe On"  # ArduPlane's STATUSTEXT as its GCS failsafe fires ("...: AUTO")

Circle = tuple[float, float, float, int]  # local centre x, y (m), radius (m), +1 CCW / -1 CW


def failsafe_mission(mission: Mission, uav: int, frame: LocalFrame, loiter: Circle) -> list[Item]:
    """The failsafe's mission: ArduPilot's home, then an unlimited loiter about the circle `loiter`.

    Item 0 is the home, which the autopilot replaces; item 1 loiters at the UAV's altitude layer (a
    negative radius is ArduPilot's counter-clockwise).
    """
    home = Item(mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0))
    cx, cy, radius, side = loiter
    lat, lon, _ = frame.to_geodetic(cx, cy)
    item = Item(
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_CMD_NAV_LOITER_UNLIM,
        (0, 0, -radius if side > 0 else radius, 0),
        round(lat * 1e7),
        round(lon * 1e7),
        mission.altitude_of(uav),
    )
    return [home, item]


def loiter_of(world: World, trajectory: Trajectory) -> Circle:
    """The circle `trajectory` loiters on, as the failsafe flies it."""
    cx, cy, radius = world.safety.limits.loiter_circle(trajectory)
    return cx, cy, radius, trajectory.loiter


class FailsafeLoiter:
    """Keeps the failsafe mission's loiter on the loiter of the trajectory in force."""

    def __init__(self, link: VehicleLink, world: World, uav: int, frame: LocalFrame) -> None:
        self.link, self.world, self.uav, self.frame = link, world, uav, frame
        self.current: Circle | None = None
        self.uploads = 0

    def follow(self, trajectory: Trajectory) -> str | None:
        """Upload the loiter of `trajectory` unless it is the one armed; the reason on failure."""
        loiter = loiter_of(self.world, trajectory)
        if self.current is not None and _same(loiter, self.current):
            return None
        items = failsafe_mission(self.world.mission, self.uav, self.frame, loiter)
        error = self.link.mission.upload(mavlink.MAV_MISSION_TYPE_MISSION, items, "failsafe mission")
        if error is None:
            self.current = loiter
            self.uploads += 1
        return error


def fired_by_our_silence(link: VehicleLink, texts_before: int) -> bool:
    """Whether the aircraft is in AUTO because the GCS failsafe fired: our own HEARTBEATs stopped.

    ArduPlane says so in a STATUSTEXT after the first `texts_before` it sent.
    """
    s = link.state
    return (
        not s.px4
        and s.custom_mode == ARDUPILOT_AUTO
        and any(t.startswith(FAILSAFE_TEXT) for t in s.texts_since(texts_before))
    )


def _same(a: Circle, b: Circle) -> bool:
    return a[3] == b[3] and math.hypot(a[0] - b[0], a[1] - b[1]) < SAME_CENTRE_M and abs(a[2] - b[2]) < 0.1


def arm_failsafe(loiter: FailsafeLoiter, trajectory: Trajectory) -> str | None:
    """Set up ArduPlane's GCS failsafe as the silent companion's failsafe; the reason on failure.

    It runs on `loiter`'s link and circles the loiter of `trajectory` (the trajectory in force).
    """
    link, mission = loiter.link, loiter.world.mission
    names = link.params.read([GCS_SYSID_PARAMS[0]], timeout=RENAMED_PARAM_WAIT_S)
    if not names:
        names = link.params.read([GCS_SYSID_PARAMS[1]], timeout=RENAMED_PARAM_WAIT_S)
    if not names:
        return f"the autopilot has no {' or '.join(GCS_SYSID_PARAMS)}: no GCS failsafe to use"
    error = loiter.follow(trajectory)
    if error:
        return error
    sysid_param = next(iter(names))
    if not link.params.set(sysid_param, float(link.system_id)):
        return f"{sysid_param} = {link.system_id} not confirmed"
    link.send_heartbeat()  # heard before the failsafe is enabled: it must not fire on an old silence
    settings = {
        "FS_LONG_TIMEOUT": mission.failsafe_seconds,
        "FS_LONG_ACTN": float(FS_LONG_AUTO),
        "FS_GCS_ENABL": float(FS_GCS_HEARTBEAT),
    }
    for name, value in settings.items():
        if not link.params.set(name, value):
            return f"{name} = {value:g} not confirmed"
    return None


def hand_over(loiter: FailsafeLoiter, trajectory: Trajectory, abort: threading.Event) -> str | None:
    """The mission's end: hand the aircraft over to AUTO now; the reason on failure.

    The aircraft circles the loiter of `trajectory` (the trajectory in force) in AUTO, as the
    failsafe would after FS_LONG_TIMEOUT of silence, but now.
    """
    link = loiter.link
    error = loiter.follow(trajectory)
    if error:
        return error
    deadline = time.monotonic() + HAND_OVER_WAIT_S
    asked = -math.inf
    while link.state.custom_mode != ARDUPILOT_AUTO:
        if abort.is_set() or time.monotonic() > deadline:
            return f"AUTO not confirmed (mode {link.state.custom_mode})"
        if time.monotonic() - asked > 1.0:
            link.commands.set_mode(ARDUPILOT_AUTO)
            asked = time.monotonic()
        link.poll(0.1)
    return None
