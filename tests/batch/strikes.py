"""Generated missions with one or two UAVs struck by a fault at a step of the run's first half:
the property tests' shared draw (`test_dead_uav`, `test_unsteered_uav`)."""

from __future__ import annotations

from hypothesis import strategies as st

from companion.batch.generate import Family, generate
from companion.contracts.mission import ALGORITHMS, Mission

MISSION_ARGS = {
    "seed": st.integers(0, 2**31 - 1),
    "mode": st.sampled_from(["grid", "continuous"]),
    "algorithm": st.sampled_from(ALGORITHMS),
    "data": st.data(),
}


def struck_mission(
    seed: int, mode: str, algorithm: str, data: st.DataObject, steps: int, what: str
) -> tuple[Mission, dict[int, int]]:
    """A generated mission (any convex region, 3-10 UAVs, `mode` kinematics) flown by `algorithm`,
    and the step at which `what` strikes each of one or two of its UAVs."""
    [(mission, _)] = generate(1, seed, Family(uavs=(3, 10), modes=(mode,), steps=steps))
    m = mission.with_algorithm(algorithm)
    uavs = data.draw(st.lists(st.integers(0, m.n_uavs - 1), min_size=1, max_size=2, unique=True), label=what)
    return m, {j: data.draw(st.integers(1, steps // 2), label=f"uav {j}: {what} at") for j in uavs}
