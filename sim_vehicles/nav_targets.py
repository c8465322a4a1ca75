"""What a simulated vehicle's guidance flies to, and the turn it asks of the flight model."""

from __future__ import annotations

import math
from dataclasses import dataclass

NO_BANK_LIMIT = math.pi / 2  # the airframe's roll limit applies


@dataclass(frozen=True)
class Loiter:
    """Circle (x, y); radius > 0 clockwise (ArduPlane's default), < 0 counter-clockwise."""

    x: float
    y: float
    radius: float


@dataclass
class Leg:
    """An AUTO leg: track the line from `start` to (x, y), which counts as reached near it."""

    start: tuple[float, float]
    x: float
    y: float
    arrived: bool = False


@dataclass(frozen=True)
class HeadingHold:
    """Hold a heading (rad CCW from east), turning with at most `accel` m/s^2 (param3)."""

    heading: float
    accel: float


@dataclass(frozen=True)
class RateHold:
    """Turn at `rate` (rad/s, CCW positive) until `expires` (simulated s)."""

    rate: float
    expires: float


Nav = Loiter | Leg | HeadingHold | RateHold | None  # None: wings level, straight on


@dataclass(frozen=True)
class Turn:
    """What guidance asks of the flight model: a bank angle or a turn rate.

    What guidance asks of the flight model: a bank angle (rad) or, if `bank` is None, a turn
    rate (rad/s); both counter-clockwise positive; `limit` the command's own bank limit (rad)."""

    bank: float | None = 0.0
    rate: float = 0.0
    limit: float = NO_BANK_LIMIT


@dataclass(frozen=True)
class Waypoint:
    """A flyable mission item in the local frame.

    A flyable mission item in the local frame; `up` None keeps the altitude; `here`: wherever the
    vehicle is when the item starts (x, y unused); `radius` a loiter's (0: WP_LOITER_RAD)."""

    seq: int
    command: int
    x: float
    y: float
    up: float | None
    here: bool = False
    radius: float = 0.0
