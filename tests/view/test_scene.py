"""The map's fence (`scene.fence_vertices`): the region with every edge pushed out by the margin."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.app.view.scene import fence_vertices
from companion.core.geometry import ConvexPolygon


@pytest.mark.parametrize("sides", [3, 4, 6, 8])
def test_the_fence_is_the_region_grown_by_the_margin(sides: int) -> None:
    angles = np.arange(sides) * 2 * math.pi / sides + 0.3
    region = ConvexPolygon.from_vertices(np.column_stack([800 * np.cos(angles), 500 * np.sin(angles)]))
    fence = fence_vertices(region, 100.0)
    assert fence.shape == (sides, 2)
    # every corner of the fence lies on two edge lines pushed out by 100 m, and inside all the others
    slack = fence @ region.normals.T - region.offsets
    assert np.all(slack <= 100.0 + 1e-6)
    assert np.all(np.sum(np.isclose(slack, 100.0), axis=1) >= 2)
    # the corners go round in the region's order: each is on the far side of the region's corner
    for corner, vertex in zip(fence, region.vertices, strict=True):
        assert np.linalg.norm(corner - vertex) >= 100.0 - 1e-6
