"""Whether the companion may steer its vehicle: link alive, guided mode, our own failsafe taken back."""

from __future__ import annotations

import logging
import math
import time

from companion.node.failsafe import fired_by_our_silence
from companion.node.mesh import Mesh
from companion.node.pilot import Pilot
from companion.node.takeover import guided_mode
from companion.node.tracking import Guard
from companion.node.vehicle_link import ARDUPILOT_AUTO, PX4_HOLD, VehicleLink

log = logging.getLogger("companion")

LINK_TIMEOUT_S = 3.0  # wall seconds without HEARTBEAT before the link counts as lost
RETAKE_PERIOD_S = 1.0  # wall seconds between requests for GUIDED after our own failsafe fired


class VehicleWatch:
    """Watches the vehicle between steps: its link, its mode and the setpoint stream.

    The link: leaving and joining the mesh with it. The mode: taking GUIDED back after our own
    failsafe fired. The setpoint stream: the one PX4 must not lose.
    """

    def __init__(self, pilot: Pilot, link: VehicleLink, mesh: Mesh, lockstep: bool) -> None:
        """Watch `pilot`'s vehicle over `link`; in `lockstep` the loop itself joins the mesh again."""
        self.pilot, self.link, self.mesh, self.lockstep = pilot, link, mesh, lockstep
        self.uav = pilot.opts.uav
        self.offboard_loss_s: float | None = None  # PX4 OFFBOARD: its COM_OF_LOSS_T (vehicle seconds)
        self.resync = False  # lockstep: the link was lost, the vehicle may have gone on without us
        self._was_steerable = False
        self._texts_steering = 0  # the vehicle's STATUSTEXTs counted while we last steered it
        self._retake_asked: float | None = None  # our failsafe fired: when GUIDED was last asked for
        self._silent_at = -math.inf  # PX4 OFFBOARD: vehicle time our setpoints last paused that long

    def keep_streaming(self) -> None:
        """Repeat the streamed guidance when due, also while a request waits for its reply.

        PX4 leaves OFFBOARD when its setpoints stop for COM_OF_LOSS_T. The guidance streams also
        while the companion asks PX4 for OFFBOARD back (PX4 accepts it only while setpoints stream).
        """
        s, pilot = self.link.state, self.pilot
        loss = self.offboard_loss_s
        silent = s.time_s - pilot.guidance.last_send
        if loss is not None and self._was_steerable and pilot.guidance.due(s.time_s) and silent >= loss:
            self._silent_at = s.time_s  # in OFFBOARD, our setpoints paused: PX4's failsafe may have fired
        if (
            pilot.steering
            and pilot.guard.state is not Guard.RELEASED
            and (pilot.steerable() or (s.px4 and self._retake_asked is not None))
            and pilot.guidance.due(s.time_s)
        ):
            pilot.guidance.repeat()  # the plan's command, or the way back inside

    def check_link(self) -> bool:
        """Whether the vehicle link is up; leave the mesh when it is lost, join again when it is back.

        A companion whose link is lost cannot steer: it leaves the mesh (its peers take its UAV as
        gone, flying its last commitments and then its failsafe) and joins again when the link is
        back (in lockstep, once it has caught up: `lockstep`).
        """
        self._check_mode()
        alive = self.link.link_alive(time.monotonic(), LINK_TIMEOUT_S)
        if alive != self.pilot.steering:
            self.pilot.steering = alive
            log.warning(
                "uav %d: vehicle link %s",
                self.uav,
                "restored: steering again" if alive else "lost: not steering, state kept, left the mesh",
            )
            if not alive:
                self.mesh.leave()
                self.resync = True
            elif not self.lockstep:
                self.mesh.join()
        return alive

    def _check_mode(self) -> None:
        """Say when the vehicle leaves the mode the companion steers in; retake it from our own failsafe.

        The vehicle may leave for a failsafe or a pilot. It is taken back into GUIDED if it left for
        the GCS failsafe this companion armed (the companion was stalled).
        """
        steerable, s = self.pilot.steerable(), self.link.state
        if self._was_steerable and not steerable:
            log.warning(
                "uav %d: the vehicle left its guided mode (now custom mode %d%s): not steering",
                self.uav,
                s.custom_mode,
                f"; it said '{s.texts[-1]}'" if s.texts else "",
            )
        self._was_steerable = steerable
        if steerable:
            if self._retake_asked is not None:
                log.info("uav %d: back in GUIDED: steering again", self.uav)
            self._texts_steering, self._retake_asked = s.text_count, None
            return
        failsafe_mode = PX4_HOLD if s.px4 else ARDUPILOT_AUTO
        if self._retake_asked is None:
            if not self._our_failsafe_fired() or self.pilot.closing:
                return
            what = "offboard-loss" if s.px4 else "GCS"
            log.warning("uav %d: our own %s failsafe fired (we were stalled): taking it back", self.uav, what)
            self._retake_asked = -math.inf
        if s.custom_mode != failsafe_mode:  # someone else chose a mode since: theirs
            log.warning("uav %d: mode %d chosen since: not taking it back", self.uav, s.custom_mode)
            self._texts_steering, self._retake_asked = s.text_count, None
        elif time.monotonic() - self._retake_asked >= RETAKE_PERIOD_S:
            self.link.commands.set_mode(guided_mode(self.link, self.pilot.opts.command_mode))
            self._retake_asked = time.monotonic()

    def _our_failsafe_fired(self) -> bool:
        """Whether the vehicle left its guided mode for the failsafe our own silence set off.

        That is ArduPilot's GCS failsafe this companion armed (ArduPlane said so), or PX4's
        offboard-loss failsafe (Hold, found at most COM_OF_LOSS_T of vehicle time after our
        setpoints, streamed in OFFBOARD, had paused that long: a Hold a pilot chose while they
        flowed is not ours); never once the region guard has given the aircraft up to the
        autopilot's fence.
        """
        s = self.link.state
        if self.pilot.guard.state is Guard.RELEASED:  # it gave the aircraft up for good
            return False
        if s.px4:
            loss = self.offboard_loss_s
            return loss is not None and s.custom_mode == PX4_HOLD and s.time_s - self._silent_at <= loss
        return self.pilot.failsafe is not None and fired_by_our_silence(self.link, self._texts_steering)
