"""Simulated time, counted in physics ticks: real time (with speedup) or lockstep.

The host asks its clock how many ticks it may have run by now and how long it may sleep.
`RealTimeClock` maps wall time to ticks (`speedup` times faster than the wall clock).
`LockstepClock` lets time advance only by whole sampling steps, when every vehicle's driver has
reported "ready for step k+1" (see docs/simulator.md, "Lockstep").
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class RealTimeClock:
    """Ticks of `tick_dt` simulated seconds, `speedup` times faster than the wall clock.

    They are counted from tick `origin_tick` at `wall_start` (a resumed simulator starts from its
    saved tick).

    Simulated time never runs ahead in a burst: when the host falls more than `max_lag` simulated
    seconds behind (the process was not scheduled, the machine is busy), the clock slips, as
    ArduPilot's SITL does under load, so that every vehicle's clients are heard at least every
    `max_lag` seconds of simulated time (an autopilot's GCS failsafe counts simulated time).
    `slipped` is the simulated time given up so far.

    While a vehicle's GCS failsafe waits on a ground station that has fallen silent (`pace`), the
    clock runs at real time (at most): a client that was not scheduled for d wall seconds then
    misses at most d simulated seconds beyond the quiet spell, as it would on a real aircraft,
    instead of S d at speedup S. `paced` is the wall time run so.
    """

    def __init__(self, tick_dt: float, speedup: float, wall_start: float, max_lag: float = 0.5) -> None:
        self.tick_dt, self.speedup, self.wall_start = tick_dt, speedup, wall_start
        self.rate = speedup  # simulated seconds per wall second now
        self.origin_tick = 0
        self.max_lag_ticks = max(1, math.floor(max_lag / tick_dt))
        self.slipped = self.paced = self._paced_from = 0.0

    def slip(self, wall: float, tick: int) -> None:
        """Re-anchor so that tick `tick` is at most `max_lag` behind at `wall`."""
        behind = self.target(wall) - tick
        if behind > self.max_lag_ticks:
            self.slipped += (behind - self.max_lag_ticks) * self.tick_dt
            self.origin_tick, self.wall_start = tick + self.max_lag_ticks, wall

    def pace(self, wall: float, tick: int, waiting: bool) -> None:
        """Run at real time (or slower, if `speedup` < 1) while `waiting`, else at `speedup`.

        The clock is re-anchored at tick `tick` whenever the rate changes.
        """
        rate = min(self.speedup, 1.0) if waiting else self.speedup
        if rate != self.rate:
            if waiting:
                self._paced_from = wall
            else:
                self.paced = self.paced_until(wall)
            self.origin_tick, self.wall_start, self.rate = tick, wall, rate

    def paced_until(self, wall: float) -> float:
        """`paced`, counting a paced spell still running at `wall` up to then."""
        return self.paced + (wall - self._paced_from if self.rate != self.speedup else 0.0)

    def target(self, wall: float) -> int:
        return self.origin_tick + math.floor((wall - self.wall_start) * self.rate / self.tick_dt + 1e-9)

    def sleep(self, wall: float, tick: int) -> float:
        """Wall seconds until tick `tick` + 1 is due."""
        ahead = tick + 1 - self.origin_tick
        return max(0.0, self.wall_start + ahead * self.tick_dt / self.rate - wall)


class LockstepClock:
    """Simulated time advances by one sampling step when every vehicle is ready for it.

    A driver (one per vehicle) reports "ready for step s". `step` is the current step k (simulated
    time k * dT). Reports of s = k + 1 count towards the next advance; s = k, or s = 0 (a driver
    that (re)starts and does not know k), asks for a snapshot of the current step; other s < k are
    stale duplicates; anything else is refused.
    """

    def __init__(self, tick_dt: float, substeps: int, n_vehicles: int) -> None:
        self.tick_dt, self.substeps, self.n = tick_dt, substeps, n_vehicles
        self.step = 0
        self.ready: set[int] = set()

    def target(self, wall: float) -> int:
        return self.step * self.substeps

    def sleep(self, wall: float, tick: int) -> float:
        return math.inf

    def report(self, vehicle: int, step: float) -> tuple[int, bool]:
        """(COMMAND_ACK result, whether a snapshot of the current step is asked for)."""
        if not (math.isfinite(step) and step == int(step)):
            return mavlink.MAV_RESULT_DENIED, False
        s = int(step)
        if s == self.step + 1:
            self.ready.add(vehicle)
            if len(self.ready) == self.n:
                self.step += 1
                self.ready.clear()
            return mavlink.MAV_RESULT_ACCEPTED, False
        if s in (self.step, 0):
            return mavlink.MAV_RESULT_ACCEPTED, True
        if s < self.step:
            return mavlink.MAV_RESULT_ACCEPTED, False
        return mavlink.MAV_RESULT_DENIED, False
