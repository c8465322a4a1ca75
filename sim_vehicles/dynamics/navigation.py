"""ArduPlane's lateral guidance laws as the simulator imitates them, in the local frame.

Every law returns a lateral acceleration demand in m/s^2, positive turning counter-clockwise (the
core's sense), flown as the bank angle atan(a / g): `heading_hold` (GUIDED_CHANGE_HEADING), `track`
(AUTO legs: L1 navigation, Park, Deyst and How 2004) and `loiter` (L1 capture, then circle
tracking). The formulas and their parameters: docs/simulator.md, "Dynamics".
"""

from __future__ import annotations

import math

GRAVITY = 9.80665
GUIDED_P = 50.0  # bank degrees per radian of heading error (ArduPlane GUIDED_P = 5000 cd/rad)
MIN_HEADING_ACCEL = 0.05  # m/s^2: ArduPlane's lower clamp of GUIDED_CHANGE_HEADING's param3
L1_PERIOD, L1_DAMPING = 15.0, 0.75


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def l1_distance(v: float, period: float = L1_PERIOD, damping: float = L1_DAMPING) -> float:
    return damping * period * max(v, 1.0) / math.pi


def heading_bank_limit(accel: float) -> float:
    """The bank limit (rad) of a heading hold with centripetal acceleration `accel` (param3)."""
    return math.atan(max(accel, MIN_HEADING_ACCEL) / GRAVITY)


def heading_hold(heading: float, target: float, accel: float) -> float:
    """Bank angle (rad, positive turning counter-clockwise) holding `target` heading (rad CCW from east)."""
    limit = heading_bank_limit(accel)
    return max(-limit, min(limit, math.radians(GUIDED_P) * _wrap(target - heading)))


def _l1_towards(
    x: float, y: float, heading: float, v: float, tx: float, ty: float, period: float, damping: float
) -> float:
    eta = _wrap(math.atan2(ty - y, tx - x) - heading)
    eta = max(-math.pi / 2, min(math.pi / 2, eta))
    return 4.0 * damping**2 * v * v / l1_distance(v, period, damping) * math.sin(eta)


def track(
    x: float,
    y: float,
    heading: float,
    v: float,
    a: tuple[float, float],
    b: tuple[float, float],
    period: float = L1_PERIOD,
    damping: float = L1_DAMPING,
) -> float:
    """Lateral acceleration following the leg from `a` to `b`."""
    l1 = l1_distance(v, period, damping)
    ux, uy = b[0] - a[0], b[1] - a[1]
    length = math.hypot(ux, uy)
    if length < 1e-6:
        return _l1_towards(x, y, heading, v, *b, period, damping)
    ux, uy = ux / length, uy / length
    px, py = x - a[0], y - a[1]
    along, cross = px * ux + py * uy, ux * py - uy * px
    if along < 0 and math.hypot(px, py) > l1:  # well behind the start of the leg: go to it first
        return _l1_towards(x, y, heading, v, *a, period, damping)
    ahead = math.sqrt(max(l1 * l1 - cross * cross, 0.0))
    tx, ty = a[0] + ux * (along + ahead), a[1] + uy * (along + ahead)
    return _l1_towards(x, y, heading, v, tx, ty, period, damping)


def loiter(
    x: float,
    y: float,
    heading: float,
    v: float,
    centre: tuple[float, float],
    radius: float,
    period: float = L1_PERIOD,
    damping: float = L1_DAMPING,
) -> float:
    """Lateral acceleration circling `centre` at `radius`.

    `radius` > 0 circles clockwise (ArduPlane's default), < 0 counter-clockwise.
    """
    sense = -1.0 if radius > 0 else 1.0  # +1: counter-clockwise
    r = max(abs(radius), 1.0)
    dx, dy = x - centre[0], y - centre[1]
    d = math.hypot(dx, dy)
    if d > 0.1:
        ox, oy = dx / d, dy / d
    else:  # on the centre: as if on the circle, flying along it
        ox, oy = math.cos(heading - sense * math.pi / 2), math.sin(heading - sense * math.pi / 2)
    vx, vy = v * math.cos(heading), v * math.sin(heading)
    outward = vx * ox + vy * oy
    tangential = sense * (ox * vy - oy * vx)  # speed along the circle in the loiter sense
    omega = 2 * math.pi / period
    pd = (d - r) * omega * omega + outward * 2 * damping * omega  # > 0: towards the centre
    if outward > 0 and tangential < 0:  # flying outwards the wrong way round: do not turn away
        pd = max(pd, 0.0)
    circle = sense * (pd + tangential * tangential / max(0.5 * r, d))
    capture = _l1_towards(x, y, heading, v, *centre, period, damping)
    if d > r and sense * capture < sense * circle:
        return capture
    return circle
