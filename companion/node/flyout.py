"""The mission's end: the trajectory in force flown out, then the aircraft handed to its loiter."""

from __future__ import annotations

import logging
import threading
import time

from companion.node.failsafe import hand_over
from companion.node.lockstep import LockstepLoop
from companion.node.pilot import Pilot
from companion.node.realtime import RealtimeLoop

log = logging.getLogger("companion")

FLY_OUT_SLACK_S = 10.0  # wall seconds the fly-out may take beyond twice its vehicle time


def fly_out(pilot: Pilot, loop: RealtimeLoop | LockstepLoop, stopped: bool, abort: threading.Event) -> None:
    """Fly out the trajectory in force, then hand the aircraft to its loiter (`hand_over`).

    The fly-out is horizon + 1 steps without a new proposal, so that every turn it planned is flown
    and the aircraft is in its loiter; docs/companion.md. In lockstep every companion takes those
    steps, steering or not, and a swarm stopped by a signal stops its simulated time with it:
    nothing to fly out.
    """
    uav, lockstep = pilot.opts.uav, isinstance(loop, LockstepLoop)
    if (stopped and lockstep) or (not lockstep and not (pilot.steering and pilot.steerable())):
        return
    pilot.closing = True
    steps = pilot.opts.mission.algorithm.horizon + 1
    log.info("uav %d: mission over: flying out the trajectory in force (%d steps)", uav, steps)
    deadline = time.monotonic() + FLY_OUT_SLACK_S + 2 * steps * pilot.dt

    def cut() -> bool:  # a second signal, a vehicle whose clock stands still, a lost link
        return abort.is_set() or time.monotonic() > deadline or (not lockstep and not pilot.steering)

    loop.run(cut, loop.budget_after(steps))
    if cut():
        log.warning("uav %d: fly-out cut short: no hand-over", uav)
        return
    if not (pilot.steering and pilot.steerable()):
        log.warning("uav %d: not steering at the mission's end: no hand-over", uav)
        return
    if not pilot.agent.commitments.loitering():
        log.warning("uav %d: the trajectory in force is not in its loiter yet", uav)
    if pilot.failsafe is None:
        log.warning("uav %d: no failsafe loiter armed: the aircraft flies its last guidance", uav)
        return
    error = hand_over(pilot.failsafe, pilot.agent.commitments.inforce, abort)
    if error:
        log.warning("uav %d: hand-over failed: %s", uav, error)
    elif pilot.failsafe.current is not None:
        cx, cy, radius, _ = pilot.failsafe.current
        log.info("uav %d: handed over: AUTO, circling (%.0f, %.0f) m, radius %.0f m", uav, cx, cy, radius)
