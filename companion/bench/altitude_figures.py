"""Altitude-keeping figures: a flight's phases, its samples from the .tlog, the table and CSVs."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from companion.node.vehicle_link import VehicleLink


@dataclass(frozen=True)
class Phase:
    """A stretch of one flight: vehicle times [start, end) and the altitude it should hold."""

    name: str
    start: float
    end: float
    target: float
    errors: bool = True  # False: only its climb and sink rates mean something (a layer change)


@dataclass(frozen=True)
class Sample:
    """One GLOBAL_POSITION_INT: vehicle time (s), height above home (m), climb rate (m/s, up +)."""

    t: float
    up: float
    climb: float


@dataclass(frozen=True)
class PhaseFigures:
    autopilot: str
    phase: str
    seconds: float
    samples: int
    max_error_m: float  # max |alt - layer|
    p95_error_m: float
    mean_error_m: float  # signed: below the layer is negative
    max_climb_ms: float
    max_sink_ms: float


@dataclass
class Flight:
    """What one autopilot's flight recorded.

    What one autopilot's flight recorded: its phases, the observer's .tlog, the vehicle's system
    id and the autopilot's altitude parameters as read."""

    autopilot: str
    tlog: Path
    system: int = 0
    phases: list[Phase] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)


class BenchError(RuntimeError):
    """A flight could not be done (the message says which step and why)."""


# -- reading the record ------------------------------------------------------------------------------
def read_samples(tlog: Path, system: int) -> list[Sample]:
    """The vehicle's GLOBAL_POSITION_INT in `tlog`, in order."""
    conn = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    out: list[Sample] = []
    try:
        while (msg := conn.recv_match(type="GLOBAL_POSITION_INT")) is not None:
            if msg.get_srcSystem() == system:
                out.append(Sample(msg.time_boot_ms * 1e-3, msg.relative_alt * 1e-3, -msg.vz * 0.01))
    finally:
        conn.close()
    return out


def figures(autopilot: str, phase: Phase, samples: Sequence[Sample]) -> PhaseFigures:
    """One phase's figures from the samples inside it."""
    inside = [s for s in samples if phase.start <= s.t < phase.end]
    if not inside:
        raise BenchError(
            f"{autopilot} {phase.name}: no GLOBAL_POSITION_INT between {phase.start:.0f} and "
            f"{phase.end:.0f} s"
        )
    err = np.array([s.up - phase.target for s in inside])
    climb = np.array([s.climb for s in inside])
    nan = math.nan
    return PhaseFigures(
        autopilot,
        phase.name,
        phase.end - phase.start,
        len(inside),
        float(np.max(np.abs(err))) if phase.errors else nan,
        float(np.percentile(np.abs(err), 95)) if phase.errors else nan,
        float(np.mean(err)) if phase.errors else nan,
        float(max(np.max(climb), 0.0)) if np.isfinite(climb).all() else nan,
        float(max(-np.min(climb), 0.0)) if np.isfinite(climb).all() else nan,
    )


class Sampler:
    """A link's altitude sampled at every poll, for a link without a .tlog.

    Samples a link's altitude at every poll (for a link without a .tlog): hook it on `on_poll`.
    Climb rates are not sampled (NaN)."""

    def __init__(self, link: VehicleLink) -> None:
        self.link, self.samples = link, list[Sample]()
        link.on_poll = self

    def __call__(self) -> None:
        s = self.link.state
        if s.has_pose and (not self.samples or s.time_s > self.samples[-1].t):
            self.samples.append(Sample(s.time_s, s.up, math.nan))


def flight_figures(flight: Flight) -> tuple[list[PhaseFigures], list[Sample]]:
    samples = read_samples(flight.tlog, flight.system)
    return [figures(flight.autopilot, p, samples) for p in flight.phases], samples



def format_table(rows: Sequence[PhaseFigures]) -> str:
    head = (
        f"{'autopilot':<15} {'phase':<16} {'s':>5} {'max |err| m':>11} {'p95 m':>7} {'mean m':>7} "
        f"{'climb m/s':>9} {'sink m/s':>8}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r.autopilot:<15} {r.phase:<16} {r.seconds:>5.0f} {r.max_error_m:>11.2f} {r.p95_error_m:>7.2f} "
            f"{r.mean_error_m:>7.2f} {r.max_climb_ms:>9.2f} {r.max_sink_ms:>8.2f}"
        )
    return "\n".join(lines)


def proposal(rows: Sequence[PhaseFigures], margin: float) -> tuple[float, float]:
    """The worst one-aircraft deviation and the vertical separation it asks for.

    (the largest one-aircraft deviation over the guarantee's phases, the vertical separation it
    gives: twice that (two aircraft straying towards each other) plus `margin`)."""
    worst = max((r.max_error_m for r in rows if math.isfinite(r.max_error_m)), default=math.nan)
    return worst, 2.0 * worst + margin


def write_csv(path: Path, rows: Sequence[PhaseFigures]) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(PhaseFigures.__dataclass_fields__))
        for r in rows:
            w.writerow(
                [
                    getattr(r, k) if not isinstance(getattr(r, k), float) else f"{getattr(r, k):.3f}"
                    for k in PhaseFigures.__dataclass_fields__
                ]
            )

