"""The search shown in the ground station, sent through the autopilot's own link once a step.

Confirmed targets (STATUSTEXT and CAMERA_TRACKING_GEO_STATUS; a retraction as STATUSTEXT),
progress (NAMED_VALUE_FLOAT), the companion's health (its HEARTBEAT's system status, its CPU load
as NAMED_VALUE_FLOAT) and the peers as traffic (ADSB_VEHICLE). None names a target system, so an
autopilot forwards them to its other links, where a ground station connected to it sees them;
ArduPlane with ADS-B on keeps the ADSB_VEHICLEs and sends the peers in its own ADS-B list instead
(docs/companion.md, "What the ground station sees").
"""

from __future__ import annotations

import math
import resource
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.frames import LocalFrame, heading_to_yaw
from companion.contracts.mission import Mission
from companion.core.agent import Agent
from companion.core.messages import UavState
from companion.core.progress import SearchProgress, search_progress
from companion.node.vehicle_link import VehicleLink

ICAO_BASE = 0xFA0000  # peer j is ICAO address ICAO_BASE + j
ADSB_VALID = (
    mavlink.ADSB_FLAGS_VALID_COORDS
    | mavlink.ADSB_FLAGS_VALID_ALTITUDE
    | mavlink.ADSB_FLAGS_VALID_HEADING
    | mavlink.ADSB_FLAGS_VALID_VELOCITY
    | mavlink.ADSB_FLAGS_VALID_CALLSIGN
)
PROGRESS_NAMES = ("coverage", "mean_eta", "found", "p_unfound")  # NAMED_VALUE_FLOAT names (<= 10 chars)
CPU_NAME = "cpu_pct"  # the companion process's CPU load since the previous step, percent of one core


def target_text(uav: int, lat: float, lon: float, retracted: bool = False) -> bytes:
    """The STATUSTEXT of one confirmed target, or of its retraction: who and where (at most 50 bytes)."""
    return f"UAV{uav} target {'retracted' if retracted else 'at'} {lat:.6f} {lon:.6f}".encode()[:50]


class GroundStationFeed:
    """One companion's reports to the ground stations behind its autopilot (`Pilot.step` calls `step`)."""

    def __init__(self, link: VehicleLink, frame: LocalFrame, mission: Mission, uav: int) -> None:
        self.link, self.frame, self.mission, self.uav = link, frame, mission, uav
        self.dt, self.speed = mission.kinematics.step, mission.kinematics.speed
        self.announced: set[int] = set()  # confirmed target cells reported and not retracted since
        self.sent = 0  # messages sent so far
        self._start = time.monotonic()
        self._cpu = (self._start, self._cpu_seconds())

    def step(self, k: int, agent: Agent, steered: bool) -> SearchProgress:
        """Step k's reports: new targets, progress, health and the peers; the progress sent.

        The companion's HEARTBEAT says ACTIVE while it steers its vehicle, STANDBY while not.
        """
        self.link.system_status = mavlink.MAV_STATE_ACTIVE if steered else mavlink.MAV_STATE_STANDBY
        self._targets(agent)
        progress = search_progress(agent.seen, agent.eta, agent.belief.posterior(), agent.found)
        self._progress(progress)
        self._health()
        for state in sorted(agent.peers.values(), key=lambda s: s.uav):
            self._traffic(k, state)
        return progress

    def _uptime_ms(self) -> int:
        return int((time.monotonic() - self._start) * 1000) & 0xFFFFFFFF

    def _targets(self, agent: Agent) -> None:
        """A STATUSTEXT (NOTICE) and a CAMERA_TRACKING_GEO_STATUS for every confirmed target not reported yet.

        Only confirmed cells (`Agent.found`) are targets; one that fell back below the confirmation
        threshold is retracted by a STATUSTEXT, and announced again if confirmed again."""
        centres, mav = agent.world.grid.centres, self.link.mav
        for cell in sorted(self.announced - agent.found):
            x, y = centres[cell]
            lat, lon, _ = self.frame.to_geodetic(float(x), float(y))
            mav.statustext_send(mavlink.MAV_SEVERITY_NOTICE, target_text(self.uav, lat, lon, retracted=True))
            self.announced.discard(cell)
            self.sent += 1
        for cell in sorted(agent.found - self.announced):
            x, y = centres[cell]
            lat, lon, alt = self.frame.to_geodetic(float(x), float(y))
            mav.statustext_send(mavlink.MAV_SEVERITY_NOTICE, target_text(self.uav, lat, lon))
            half_diagonal = agent.world.grid.cell_size / math.sqrt(2.0)
            nan = math.nan
            mav.camera_tracking_geo_status_send(
                mavlink.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE, round(lat * 1e7), round(lon * 1e7), alt,
                half_diagonal, nan, nan, nan, nan, nan, nan, nan, nan,
            )  # fmt: skip
            self.announced.add(cell)
            self.sent += 2

    def _progress(self, progress: SearchProgress) -> None:
        """The progress as NAMED_VALUE_FLOATs."""
        now = self._uptime_ms()
        values = (progress.coverage, progress.mean_eta, float(progress.found), progress.p_unfound)
        for name, value in zip(PROGRESS_NAMES, values, strict=True):
            self.link.mav.named_value_float_send(now, name.encode(), value)
        self.sent += len(values)

    @staticmethod
    def _cpu_seconds() -> float:
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return usage.ru_utime + usage.ru_stime

    def _health(self) -> None:
        """The companion process's CPU load since the previous report, as NAMED_VALUE_FLOAT `cpu_pct`."""
        wall, cpu = time.monotonic(), self._cpu_seconds()
        busy = 100.0 * (cpu - self._cpu[1]) / max(wall - self._cpu[0], 1e-3)
        self._cpu = (wall, cpu)
        self.link.mav.named_value_float_send(self._uptime_ms(), CPU_NAME.encode(), busy)
        self.sent += 1

    def _traffic(self, k: int, state: UavState) -> None:
        """ADSB_VEHICLE of one peer from its latest state on the mesh: its layer, its age as tslc."""
        lat, lon, alt = self.frame.to_geodetic(state.x, state.y, self.mission.altitude_of(state.uav))
        course = math.degrees(heading_to_yaw(state.heading)) % 360.0
        age = max(k - state.stamp, 0) * self.dt
        self.link.mav.adsb_vehicle_send(
            ICAO_BASE + state.uav, round(lat * 1e7), round(lon * 1e7), mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC,
            round(alt * 1000), round(course * 100) % 36000, round(self.speed * 100), 0,
            f"UAV{state.uav}".encode(), mavlink.ADSB_EMITTER_TYPE_UAV, min(round(age), 255), ADSB_VALID, 0,
        )  # fmt: skip
        self.sent += 1
