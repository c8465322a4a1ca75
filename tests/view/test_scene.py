"""The map's static scene: the fence (the region's hull grown by the margin) and the no-fly zones."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from companion.app.view.scene import build_scene, fence_vertices
from companion.core.feasibility import load_mission
from companion.core.geometry import ConvexPolygon
from companion.core.search_area import zone_shape
from companion.core.world import build_world
from tests.view.conftest import SCENARIO1, nofly_mission


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


def test_the_scene_holds_every_no_fly_zone_and_its_keep_out(tmp_path: Path) -> None:
    mission = load_mission(nofly_mission(tmp_path))
    world = build_world(mission, 1, 0)
    scene = build_scene(world, "live", 1)
    margin = mission.safety.margin
    assert scene.region == [list(v) for v in mission.region.polygon]
    assert scene.fence == fence_vertices(world.grid.region, margin).round(3).tolist()
    assert len(scene.nofly) == len(mission.region.nofly) == 2
    for i, (zone, drawn) in enumerate(zip(mission.region.nofly, scene.nofly, strict=True)):
        shape = zone_shape(zone)
        assert Polygon(drawn.ring).hausdorff_distance(shape) < 0.01  # rounded to the millimetre
        assert drawn.label.startswith(f"no-fly {i} (") and shape.contains(Point(drawn.at))
        grown = Polygon(drawn.inflated[0], drawn.inflated[1:])
        assert grown.hausdorff_distance(shape.buffer(margin)) < 0.01
        assert grown.exterior.hausdorff_distance(shape.exterior) == pytest.approx(margin, abs=0.5)
    assert "circle r 120 m" in scene.nofly[1].label
    assert b'"nofly":[{"label":"no-fly 0 (polygon)"' in msgspec.json.encode(scene)


def test_a_non_convex_region_is_drawn_as_itself_inside_its_hull_s_fence(tmp_path: Path) -> None:
    ell = [[-1000.0, -1000.0], [1000.0, -1000.0], [1000.0, 0.0], [0.0, 0.0], [0.0, 1000.0], [-1000.0, 1000.0]]
    square = "[[-1000.0, -1000.0], [1000.0, -1000.0], [1000.0, 1000.0], [-1000.0, 1000.0]]"
    path = tmp_path / "ell.toml"
    path.write_text(SCENARIO1.read_text().replace(square, str(ell), 1))
    mission = load_mission(path)
    scene = build_scene(build_world(mission, 1, 0), "live", 1)
    assert scene.region == ell and scene.nofly == []
    fence = Polygon(scene.fence)  # the hull's five edges, each pushed out by the margin
    assert len(scene.fence) == 5 and fence.contains(Polygon(ell).convex_hull.buffer(99.0))
    assert not fence.contains(Polygon(ell).convex_hull.buffer(101.0))
