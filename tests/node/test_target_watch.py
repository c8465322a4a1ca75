"""The companion tells candidates, confirmations and retractions apart (companion.node.target_watch)."""

from __future__ import annotations

import logging
from pathlib import Path

import msgspec
import numpy as np
import pytest

from companion.contracts.frames import LocalFrame
from companion.core.agent import Agent, Observation
from companion.core.feasibility import load_mission
from companion.core.world import build_world
from companion.node.target_watch import TargetEvent, TargetWatch

ROOT = Path(__file__).resolve().parents[2]


def test_a_detection_is_a_candidate_until_confirmed_and_misses_retract_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Hits on one cell raise it as a candidate, then confirm it; looks without a report retract it.
    Cells only ever missed raise nothing."""
    m = load_mission(ROOT / "mission_files" / "scenario1.toml")
    m = msgspec.structs.replace(m, sensor=msgspec.structs.replace(m.sensor, pd=0.9, pf=0.05, confirm=0.9))
    world = build_world(m, m.seed, 0)
    agent, frame = Agent(world, 0), LocalFrame(m.region.origin)
    watch = TargetWatch(0, frame, agent)
    v = m.vehicles[0]
    cell = int(world.grid.cell_at(np.array([[v.x, v.y + 40.0]]))[0])
    spot = tuple(float(c) for c in world.grid.centres[cell])
    events: list[TargetEvent] = []
    caplog.set_level(logging.INFO, logger="companion")
    for k in range(30):
        hit = not any(e.event == "confirmed" for e in events)
        detections = (spot,) if hit else ()
        agent.step(Observation(step=k, x=v.x, y=v.y, heading=1.5708, detections=detections), [])
        events += watch.step(k, agent)
        if events and events[-1].event == "retracted":
            break
    assert [e.event for e in events] == ["candidate", "confirmed", "retracted"], events
    assert {e.cell for e in events} == {cell}
    candidate, confirmed, retracted = events
    assert candidate.posterior < m.sensor.confirm <= confirmed.posterior
    assert retracted.posterior < m.sensor.confirm
    assert (confirmed.x, confirmed.y) == spot
    assert (confirmed.lat, confirmed.lon) == pytest.approx(frame.to_geodetic(*spot)[:2])
    assert watch.counts == {"candidate": 1, "confirmed": 1, "retracted": 1}
    assert f"step {confirmed.step}: confirmed target, cell {cell} at" in caplog.text
    assert f"step {retracted.step}: retracted target, cell {cell} at" in caplog.text
