"""The listener's model of the swarm against real agents: the batch engine's loop, each outbox
sent as the mesh bundle a companion would put, in shuffled arrival order."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest

from companion.app.view.swarm_model import Report, SwarmModel
from companion.batch.engine import Radio, Scorer, initial_poses
from companion.contracts.mission import Mission
from companion.core.agent import Agent, Observation
from companion.core.feasibility import load_mission
from companion.core.prior import draw_targets
from companion.core.uncertainty import global_average_uncertainty
from companion.core.world import Stream, build_world, instance_rng
from companion.node.mesh import Bundle, check_bundle, decode_bundle, encode_bundle
from tests.view.conftest import SCENARIO1

STEPS = 60


@pytest.fixture(scope="module")
def mission() -> Mission:
    return load_mission(SCENARIO1)


def _fly(
    mission: Mission, steps: int, unsteered: tuple[int, int] = (-1, 0)
) -> tuple[list[list[Bundle]], list[float], list[int]]:
    """Per step: every UAV's bundle (through the wire), the agents' eq. 30 and the targets found.
    `unsteered`: (UAV, step) from which that UAV's agent is told its vehicle is not steered."""
    world = build_world(mission, mission.seed, 0)
    n = mission.n_uavs
    agents = [Agent(world, i) for i in range(n)]
    targets = draw_targets(world.prior, mission.prior.targets, instance_rng(mission.seed, 0, Stream.TARGETS))
    scorer = Scorer(world, targets, steps)
    radio = Radio(mission.comms.range, 0.0, np.random.default_rng(0), wire=True)
    poses = initial_poses(mission)
    inboxes: list[list] = [[] for _ in range(n)]
    bundles, eq30, found = [], [], []
    n_tasks = world.tessellation.n_tasks if world.tessellation else 0
    for k in range(steps):
        sees = scorer.record(k, poses[:, :2])
        outs = []
        for i, agent in enumerate(agents):
            x, y, h = poses[i].tolist()
            seen = tuple(map(tuple, scorer.target_xy[sees[i]].tolist()))
            steered = i != unsteered[0] or k < unsteered[1]
            obs = Observation(step=k, x=x, y=y, heading=h, detections=seen, steered=steered)
            outs.append(agent.step(obs, inboxes[i]))
        step_bundles = []
        for i, (_, outbox) in enumerate(outs):
            x, y = float(poses[i, 0]), float(poses[i, 1])
            b = Bundle(sender=i, stamp=k, x=x, y=y, messages=tuple(outbox))
            b = decode_bundle(encode_bundle(b))
            check_bundle(b, n, world.grid.n_cells, n_tasks)
            step_bundles.append(b)
        bundles.append(step_bundles)
        eq30.append(global_average_uncertainty([a.eta for a in agents]))
        found.append(int(scorer.found[k]))
        inboxes = radio.deliver(poses[:, :2], [o for _, o in outs])
        poses = world.kinematics.advance_poses(poses, np.array([c.turn for c, _ in outs]))
    return bundles, eq30, found


def _model(mission: Mission) -> SwarmModel:
    world = build_world(mission, mission.seed, 0)
    m = mission
    return SwarmModel(
        m.n_uavs, world.grid.n_cells, m.uncertainty.eta0, m.uncertainty.gamma, m.comms.range,
        m.comms.peer_timeout_steps,
    )  # fmt: skip


def test_frames_match_the_agents_step_by_step(mission: Mission) -> None:
    bundles, eq30, found = _fly(mission, STEPS)
    model = _model(mission)
    for i in range(mission.n_uavs):
        model.set_alive(i, True)
    rng = random.Random(1)
    frames = []
    for k, step in enumerate(bundles):
        order = list(step)
        rng.shuffle(order)  # bundles of one step arrive in any order
        for b in order:
            model.add(Report.of(b), now=float(k))
        frames += [json.loads(f) for f in model.close_ready(now=float(k))]
    assert [f["k"] for f in frames] == list(range(STEPS)), "each step closes once all its UAVs reported"
    for f, b, unc, n_found in zip(frames, bundles, eq30, found, strict=True):
        assert f["m"][1] == pytest.approx(unc, abs=1e-7), "eq. 30 as the agents' own maps give it"
        assert f["m"][0] == n_found
        for i, u in enumerate(f["u"]):
            state = b[i].messages[0].state
            assert u[:4] == [round(state.x, 3), round(state.y, 3), round(state.heading, 5), state.task]
            assert u[4] == 0
        assert len(f["t"]) == mission.n_uavs - 1
    assert found[-1] > 0, "the test flies long enough to find targets"


def test_a_departed_uav_is_silent_and_no_step_waits_for_it(mission: Mission) -> None:
    bundles, _, _ = _fly(mission, 12)
    model = _model(mission)
    for i in range(mission.n_uavs):
        model.set_alive(i, True)
    frames = []
    for k, step in enumerate(bundles):
        if k == 6:
            model.set_alive(3, False)  # its liveliness token went
        for b in step:
            if not (b.sender == 3 and k >= 6):
                model.add(Report.of(b), now=0.0)
        frames += [json.loads(f) for f in model.close_ready(now=0.0)]
    assert [f["k"] for f in frames] == list(range(12))
    last = bundles[5][3].messages[0].state
    for f in frames[6:]:
        assert f["u"][3][4] == 1, "drawn as silent"
        assert f["u"][3][:2] == [round(last.x, 3), round(last.y, 3)], "at its last reported position"
    assert all(f["u"][3][4] == 0 for f in frames[:6])


def test_a_uav_its_companion_does_not_steer_is_drawn_so(mission: Mission) -> None:
    bundles, _, _ = _fly(mission, 10, unsteered=(2, 4))
    model = _model(mission)
    for i in range(mission.n_uavs):
        model.set_alive(i, True)
    frames = []
    for k, step in enumerate(bundles):
        for b in step:
            model.add(Report.of(b), now=float(k))
        frames += [json.loads(f) for f in model.close_ready(now=float(k))]
    assert [f["k"] for f in frames] == list(range(10))
    for f in frames:
        assert [u[5] for u in f["u"]] == [1, 1, int(f["k"] < 4), 1], f["k"]
        assert all(u[4] == 0 for u in f["u"]), "not steered is not silent"


def test_late_and_lonely_steps_close_by_time_and_lag(mission: Mission) -> None:
    bundles, _, _ = _fly(mission, 8)
    model = _model(mission)
    model.add(Report.of(bundles[0][0]), now=0.0)
    assert model.close_ready(now=1.0) == [], "the first step waits for the others a while"
    assert len(model.close_ready(now=10.0)) == 1, "... but not for ever"
    model.add(Report.of(bundles[0][1]), now=10.0)
    assert model.late == 1, "a report for a closed step is counted, not drawn"
    for k in (1, 2, 3):  # UAV 0 fell quiet without its token going: UAV 1 goes on
        model.add(Report.of(bundles[k][1]), now=10.0)
    assert model.close_ready(now=10.5) == [], "step 1 waits for UAV 0"
    model.add(Report.of(bundles[4][1]), now=10.5)
    closed = [json.loads(f)["k"] for f in model.close_ready(now=10.5)]
    assert closed == [1, 2, 3, 4], "... until a report LAG_STEPS later is in; then UAV 1 alone is expected"
