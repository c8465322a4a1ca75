"""The mission's local frame (x east, y north, metres) and its geodetic and MAVLink conventions.

This is the one place where lat/lon/alt and MAVLink yaw are converted.

Altitudes: `up` is metres above the mission origin (the home altitude); AMSL = origin.alt + up.
Headings: the core measures them counter-clockwise from east (radians); MAVLink yaw is
clockwise from north.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d

from companion.contracts.mission import Origin


def heading_to_yaw(heading: float) -> float:
    """Core heading (CCW from east) to MAVLink yaw (CW from north), wrapped to [-pi, pi)."""
    return (math.pi / 2 - heading + math.pi) % (2 * math.pi) - math.pi


def yaw_to_heading(yaw: float) -> float:
    """MAVLink yaw (CW from north) to core heading (CCW from east), wrapped to [-pi, pi)."""
    return (math.pi / 2 - yaw + math.pi) % (2 * math.pi) - math.pi


class LocalFrame:
    """Conversions between local metres and lat/lon around the mission origin (pymap3d ENU)."""

    def __init__(self, origin: Origin) -> None:
        self.lat0, self.lon0, self.alt0 = origin.lat, origin.lon, origin.alt

    def to_geodetic(self, x: float, y: float, up: float = 0.0) -> tuple[float, float, float]:
        """(lat deg, lon deg, alt m AMSL) of local point (x, y) at `up` metres above the origin."""
        lat, lon, _ = pymap3d.enu2geodetic(x, y, up, self.lat0, self.lon0, self.alt0)
        return float(lat), float(lon), self.alt0 + up

    def to_local(self, lat: float, lon: float) -> tuple[float, float]:
        """Local (x east, y north) of a geodetic point, projected at the origin's altitude."""
        x, y, _ = pymap3d.geodetic2enu(lat, lon, self.alt0, self.lat0, self.lon0, self.alt0)
        return float(x), float(y)

    def cells_to_geodetic(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lat, lon) arrays in degrees of local points (n, 2), at the origin's altitude."""
        lat, lon, _ = pymap3d.enu2geodetic(points[:, 0], points[:, 1], 0.0, self.lat0, self.lon0, self.alt0)
        return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
