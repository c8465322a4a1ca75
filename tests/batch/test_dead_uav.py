"""A UAV whose companion dies stays an obstacle (docs/algorithm.md, "A silent UAV stays an
obstacle"), in the batch engine: generated missions (any convex region, 3-10 UAVs, grid and
continuous kinematics, all three algorithms, one layer or several), one or two companions dying at
random steps; their vehicles fly on along their trajectories in force. No pair that can meet (live,
or on near layers: docs/algorithm.md, "Separation in three dimensions") ever comes within R_s
(closest approach between sampling moments), and no trajectory in force had to be
replaced. The survivors' new proposals are checked against the dead UAVs' frozen commitments and
must clear their failsafe loiter disks (`Commitments.failsafe_loiters`), or, boxed in by the
fence and the neighbours, keep farther from them than flying on would (`safety.leaves_loiters`):
every survivor on a near layer is, and stays, farther than R_s from the circle a real aircraft would
fly there at a phase of its own (ArduPlane circles at up to FAILSAFE_WIDE loiter radii): from the death on if
the pair cleared the contingency clause then (`tests/batch/contingency.py`), else soon after it
takes the UAV as gone (a death in a start-up closer than the clause; measured: at most 15 steps
after the death in 30 generated missions; `LEAVE_STEPS` is a generous bound)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.batch.engine import simulate
from companion.core.world import FAILSAFE_WIDE, build_world
from tests.batch.contingency import clause_probe
from tests.batch.strikes import MISSION_ARGS, struck_mission

STEPS = 1000
LEAVE_STEPS = 60  # after a death (and the peer timeout), by when every survivor is out of its disk


def loiter_centre(track: np.ndarray) -> tuple[float, float]:
    """The circumcentre of the last three sampling points of a vehicle that loiters."""
    (ax, ay), (bx, by), (cx, cy) = track[-3:]
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    return (
        (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d,
        (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d,
    )


@pytest.mark.slow
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**MISSION_ARGS)
def test_no_uav_comes_within_r_s_of_a_dead_one(
    seed: int, mode: str, algorithm: str, data: st.DataObject
) -> None:
    m, kills = struck_mission(seed, mode, algorithm, data, STEPS, "dies")
    n, dead = m.n_uavs, sorted(kills)
    world = build_world(m, m.seed, 0)
    rows: list[np.ndarray] = []
    r = simulate(m, m.seed, 0, STEPS, record=True, world=world, kills=kills, probe=clause_probe(world, rows))
    assert r.separation_losses == 0, f"closest approach {float(r.approach.min()):.1f} m"
    assert float(r.approach.min()) > m.comms.safety
    assert r.extras["recovered"] == 0  # the invariant held: no trajectory in force was replaced
    # the dead vehicles end circling their loiters (the circles their failsafes would fly)
    assert r.trajectory is not None
    wide = FAILSAFE_WIDE * world.safety.loiter_radius + m.comms.safety
    for j in dead:
        cx, cy = loiter_centre(r.trajectory[:, j, :2])
        ring = np.hypot(r.trajectory[-10:, j, 0] - cx, r.trajectory[-10:, j, 1] - cy)
        assert np.allclose(ring, world.safety.loiter_radius, atol=1e-6)
        for i in set(range(n)) - set(dead):
            if not world.safety.near[i, j]:  # a layer the vertical separation away: apart vertically
                continue
            cleared = rows[kills[j] - 1][min(i, j), max(i, j)] > 0  # the last step j's companion took
            by = kills[j] if cleared else kills[j] + m.comms.peer_timeout_steps + LEAVE_STEPS
            near = np.hypot(r.trajectory[by:, i, 0] - cx, r.trajectory[by:, i, 1] - cy) <= wide
            assert not near.any(), f"uav {i} within {wide:.0f} m of dead uav {j}'s loiter after step {by}"
