"""The imperfect detector (`core.sensing`): its draws are a pure function of the look, at the rates
the mission names, and the batch engine's camera and the simulator's camera report the same."""

from __future__ import annotations

import math

import msgspec
import numpy as np
from scipy import stats

from companion.core.sensing import detection_probability, draw_reports, look_uniform
from companion.core.world import build_world
from sim_vehicles.camera import Camera


def test_draws_depend_only_on_the_look() -> None:
    a = [look_uniform(1, 0, u, k, c) for u in range(3) for k in range(50) for c in range(20)]
    b = [look_uniform(1, 0, u, k, c) for c in range(20) for k in range(50) for u in range(3)]
    assert sorted(a) == sorted(b) and len(set(a)) == len(a)
    assert look_uniform(2, 0, 0, 0, 0) != look_uniform(1, 0, 0, 0, 0)
    assert stats.kstest(a, "uniform").pvalue > 1e-4  # uniform on [0, 1)


def test_reports_come_at_pd_of_the_distance_and_pf() -> None:
    n = 20000
    cells = np.arange(n)
    holds = cells % 2 == 0
    distances = np.where(cells % 4 < 2, 0.0, 60.0)  # half under the UAV, half at the edge
    model = (0.9, 0.5, 0.03, 60.0)
    reported = draw_reports(7, 3, 1, 11, cells, distances, holds, model)
    for mask, p in (
        (holds & (distances == 0), 0.9),
        (holds & (distances == 60), 0.5),
        (~holds, 0.03),
    ):
        k = int(reported[mask].sum())
        assert stats.binomtest(k, int(mask.sum()), p).pvalue > 1e-4
    assert math.isclose(detection_probability(30.0, 0.9, 0.5, 60.0), 0.7)


def test_the_simulated_camera_reports_what_the_batch_engine_draws(scenario1) -> None:
    from companion.contracts.frames import LocalFrame
    from companion.core.sensing import reported_cells

    sensor = msgspec.structs.replace(scenario1.sensor, pd=0.7, pf=0.2)
    mission = msgspec.structs.replace(scenario1, sensor=sensor)
    world = build_world(mission, 5, 0)
    targets = np.array([10, 500, 1200])
    camera = Camera(mission, world.grid, targets, 5, LocalFrame(mission.region.origin))
    step_usec = round(mission.kinematics.step * 1e6)
    for k, (x, y) in enumerate([(-580.0, -940.0), (20.0, 20.0), (100.0, -300.0)] * 3):
        cells = world.grid.fov_cell_list((x, y))
        truth = camera.holds_target
        engine = reported_cells(world.grid.centres, cells, truth, world.sensor, (5, 0, 2, k), (x, y))
        sim = camera.detect(2, k * step_usec + step_usec // 3, x, y)
        assert sorted(engine.tolist()) == sorted(sim.tolist())
