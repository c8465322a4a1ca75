"""The companion's journal on a real file: recovery is exact, a torn or corrupt tail is ignored and
cut off, and another mission's journal is refused."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest

from companion.core.agent import Agent, Observation
from companion.core.feasibility import load_mission
from companion.core.world import build_world
from companion.node.journal import CHECKPOINT_STEPS, Journal, JournalError, header_of, read_records

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module", params=["perfect", "imperfect"])
def world(request):
    mission = load_mission(ROOT / "mission_files" / "scenario1.toml")
    if request.param == "imperfect":  # the journal carries the target map's evidence records too
        sensor = msgspec.structs.replace(mission.sensor, pd=0.8, pf=0.05)
        mission = msgspec.structs.replace(mission, sensor=sensor)
    return build_world(mission, 1, 0)


def _fly(agent: Agent, journal: Journal, steps: range) -> None:
    """Steps of a lone UAV, journaled, over a target in every 13th cell (each seen while in view)."""
    x, y, h = -620.0, -980.0, math.pi / 2
    if agent.last is not None:
        c = agent.commitments.inforce
        x, y, h = c.x, c.y, c.heading
    grid = agent.world.grid
    for k in steps:
        targets = [c for c in grid.fov_cell_list((x, y)).tolist() if c % 13 == 0]
        seen = tuple((float(px), float(py)) for px, py in grid.centres[targets].tolist())
        command, _ = agent.step(Observation(step=k, x=x, y=y, heading=h, detections=seen), [])
        journal.append(agent)
        x, y, h = command.waypoint[0], command.waypoint[1], command.heading


def _same(a: Agent, b: Agent) -> None:
    assert np.array_equal(a.eta, b.eta) and np.array_equal(a.seen, b.seen)
    assert np.array_equal(a.covered, b.covered)
    assert a.found == b.found and a.found
    assert np.array_equal(a.belief.logodds, b.belief.logodds) and np.array_equal(a.candidates, b.candidates)
    assert (a.task, a.task_reward) == (b.task, b.task_reward)
    assert a.commitments.inforce == b.commitments.inforce
    assert a.commitments.parents == b.commitments.parents


def test_recovery_is_exact_across_checkpoints(world, tmp_path: Path) -> None:
    path, header = tmp_path / "uav0.journal", header_of(world.mission, 0, 1)
    agent = Agent(world, 0)
    journal, recovered = Journal.open(path, header, agent)
    assert recovered is None
    _fly(agent, journal, range(CHECKPOINT_STEPS + 30))
    journal.close()
    records, good = read_records(path.read_bytes())
    assert good == path.stat().st_size and len(records) == 1 + CHECKPOINT_STEPS + 30

    again = Agent(world, 0)
    journal, recovered = Journal.open(path, header, again)
    journal.close()
    assert recovered is not None and recovered.step == CHECKPOINT_STEPS + 29
    assert recovered.steps == CHECKPOINT_STEPS + 30 and recovered.torn_bytes == 0
    _same(agent, again)
    assert again.eta.mean() < 1.0


def test_torn_and_corrupt_tails_are_ignored_and_cut(world, tmp_path: Path) -> None:
    path, header = tmp_path / "uav0.journal", header_of(world.mission, 0, 1)
    agent = Agent(world, 0)
    journal, _ = Journal.open(path, header, agent)
    _fly(agent, journal, range(20))
    journal.close()
    whole = path.read_bytes()

    # a kill in the middle of the last record: that step is ignored, the file cut back
    path.write_bytes(whole[:-5])
    torn = Agent(world, 0)
    journal, recovered = Journal.open(path, header, torn)
    assert recovered is not None and recovered.step == 18 and recovered.torn_bytes > 0
    # appending goes on after the last whole record
    _fly(torn, journal, range(19, 25))
    journal.close()
    records, good = read_records(path.read_bytes())
    assert good == path.stat().st_size and len(records) == 1 + 19 + 6

    # a flipped byte in the last record's payload fails its CRC: ignored likewise
    data = bytearray(whole)
    data[-3] ^= 0xFF
    path.write_bytes(bytes(data))
    flipped = Agent(world, 0)
    journal, recovered = Journal.open(path, header, flipped)
    journal.close()
    assert recovered is not None and recovered.step == 18


def test_another_missions_journal_is_refused(world, tmp_path: Path) -> None:
    path = tmp_path / "uav0.journal"
    journal, _ = Journal.open(path, header_of(world.mission, 0, 1), Agent(world, 0))
    journal.close()
    for header in (header_of(world.mission, 0, 2), header_of(world.mission.with_seed(5), 0, 1)):
        with pytest.raises(JournalError, match="not for this companion"):
            Journal.open(path, header, Agent(world, 0))
    path.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(JournalError, match="not a journal"):
        Journal.open(path, header_of(world.mission, 0, 1), Agent(world, 0))
