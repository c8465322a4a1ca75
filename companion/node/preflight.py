"""Before the first step: the airframe checked, the vehicle taken over, fence, return altitude, failsafe."""

from __future__ import annotations

import logging
import threading

from companion.node.airframe import SIMULATOR_PARAM, Airframe, check_mission, refusal
from companion.node.failsafe import FailsafeLoiter, arm_failsafe
from companion.node.fence import FenceMismatch, fence_items, fence_margin, upload_fence
from companion.node.pilot import Pilot
from companion.node.return_altitude import set_return_altitude
from companion.node.takeover import take_over
from companion.node.vehicle_link import VehicleLink
from companion.node.watch import VehicleWatch

log = logging.getLogger("companion")

PX4_OFFBOARD_LOSS = "COM_OF_LOSS_T"  # PX4: seconds without setpoints before the OFFBOARD failsafe
SIMULATOR_PARAM_WAIT_S = 3.0  # the airframe's parameters have answered by then: others need no longer


class Refused(RuntimeError):
    """The autopilot cannot fly the mission in the chosen command mode (the message says why)."""


class Preflight:
    """Readies the vehicle for the companion's steps and keeps what it found for the run's report."""

    def __init__(self, pilot: Pilot, watch: VehicleWatch, link: VehicleLink) -> None:
        self.pilot, self.watch, self.link = pilot, watch, link
        self.opts, self.uav = pilot.opts, pilot.opts.uav
        self.airframe_warnings: list[str] = []
        self.fence_uploaded = False

    def connect(self) -> None:
        """The vehicle answered: ask for its telemetry, keep the setpoints streaming, check its airframe.

        The setpoints stream whatever waits from now on; Refused if the airframe cannot fly the
        mission.
        """
        self.link.request_streams()
        self.link.on_poll = self.watch.keep_streaming  # from the take-over on, whatever waits
        self._check_airframe()

    def prepare(self, stop: threading.Event) -> None:
        """Wait for the vehicle's pose, then take it over and set its fence, return altitude and failsafe.

        Each is done as the options say; fence and failsafe default to the take-over's choice.
        """
        opts = self.opts
        while not stop.is_set() and not self.link.state.has_pose:
            self.link.poll(0.2)
        if opts.takeover:
            take_over(self.link, self.pilot.guidance, self.uav, stop)
        if (opts.takeover if opts.fence is None else opts.fence) and not stop.is_set():
            self._upload_fence()
            self._set_return_altitude()
        if (opts.takeover if opts.failsafe is None else opts.failsafe) and not stop.is_set():
            self._arm_failsafe()

    def _check_airframe(self) -> None:
        """Check the mission against the airframe's parameters: warn, or refuse (Refused).

        It reads the airframe's parameters, warns about what the mission asks beyond them and
        refuses what the autopilot cannot fly.
        """
        flavour = "px4" if self.link.state.px4 else "ardupilot"
        values = self.link.params.read(Airframe.names(flavour))
        values |= self.link.params.read([SIMULATOR_PARAM], timeout=SIMULATOR_PARAM_WAIT_S)
        airframe = Airframe.from_params(flavour, values)
        problem = refusal(self.opts.mission, airframe, self.opts.command_mode)
        if problem:
            raise Refused(f"uav {self.uav}: {problem}")
        self.airframe_warnings = check_mission(self.opts.mission, airframe)
        for warning in self.airframe_warnings:
            log.warning("uav %d: mission vs airframe: %s", self.uav, warning)
        cruise = airframe.get("cruise")
        k = self.opts.mission.kinematics
        self.pilot.guidance.set_speed = (
            k.mode == "continuous" and cruise is not None and abs(cruise - k.speed) > 0.1
        )

    def _upload_fence(self) -> None:
        """Upload the autopilot's fence: the planning fence plus one step of slack, and the no-fly zones.

        The planning fence is the region plus margin; the step of slack is for the vehicle's
        tracking error. The companion's own guard acts at the planning fence. The no-fly zones go
        as the operator gave them (the plans keep the margin from them). The fence is read back
        and compared with what was sent (`fence.upload_fence`): Refused if it differs, a warning
        if the autopilot refused the upload.
        """
        m = self.opts.mission
        margin = fence_margin(m) + m.kinematics.speed * m.kinematics.step
        items = fence_items(m, self.pilot.frame, margin)
        try:
            error = upload_fence(self.link, items)
        except FenceMismatch as exc:
            raise Refused(f"uav {self.uav}: {exc}") from exc
        if error:
            log.warning("uav %d: fence not set: %s", self.uav, error)
        else:
            self.fence_uploaded = True
            log.info(
                "uav %d: fence enabled and read back: the region plus %.0f m (%d vertices), %d no-fly zones",
                self.uav,
                margin,
                int(items[0].params[0]),
                len(m.region.nofly),
            )

    def _set_return_altitude(self) -> None:
        """The autopilot's return (the fence's breach action) at the UAV's layer (`return_altitude`)."""
        altitude = self.opts.mission.altitude_of(self.uav)
        error = set_return_altitude(self.link, altitude)
        if error:
            log.warning("uav %d: return altitude not set: %s", self.uav, error)
        else:
            log.info("uav %d: return (RTL) altitude set to its layer, %.0f m", self.uav, altitude)

    def _arm_failsafe(self) -> None:
        """PX4: note its own offboard-loss timeout; ArduPilot: arm the failsafe loiter for our silence."""
        if self.link.state.px4:
            if self.opts.command_mode == "position-target":
                loss = self.link.params.read([PX4_OFFBOARD_LOSS]).get(PX4_OFFBOARD_LOSS)
                self.watch.offboard_loss_s = loss
            if self.watch.offboard_loss_s is None:
                log.info("uav %d: failsafe: PX4's own failsafes apply", self.uav)
            else:
                log.info(
                    "uav %d: failsafe: PX4's own offboard-loss failsafe applies after %s = %g s; OFFBOARD "
                    "taken back when our setpoints paused that long",
                    self.uav,
                    PX4_OFFBOARD_LOSS,
                    self.watch.offboard_loss_s,
                )
            return
        pilot = self.pilot
        failsafe = FailsafeLoiter(self.link, pilot.world, self.uav, pilot.frame)
        error = arm_failsafe(failsafe, pilot.agent.commitments.inforce)
        if error:
            log.warning("uav %d: failsafe not set: %s", self.uav, error)
            return
        pilot.failsafe = failsafe
        log.info(
            "uav %d: failsafe armed: %g s without our HEARTBEAT, the aircraft circles the loiter of its "
            "trajectory in force",
            self.uav,
            self.opts.mission.failsafe_seconds,
        )
