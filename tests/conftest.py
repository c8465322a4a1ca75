"""Hypothesis draws the same examples on every run (profile "ci", the default): a test that passes
here passes in CI, and a counterexample is fixed, not met at random. `HYPOTHESIS_PROFILE=explore`
draws fresh examples (with the example database) to look for new counterexamples."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# -- running on two cores (`make test`: pytest -n 2 --dist loadgroup) ------------------------------
# A test that flies real autopilots (SITL, PX4) in real time shares the machine with at most one
# test that flies a swarm of companions on the bundled simulator in real time, and with nothing of
# its own kind: each group runs in order on one worker. Both groups are handed out first (they are
# the longest), then the other tests, those marked `slow` first, so that no long test starts last.
REAL_TIME_GROUPS = {
    "autopilot": ("sitl/", "px4/", "trust/test_sitl_signing.py", "deploy/test_readme.py"),
    "swarm": ("e2e/", "mission/test_swarm.py", "view/test_view_browser.py"),
}


def _group(item: pytest.Item) -> str | None:
    where = item.path.relative_to(Path(__file__).parent).as_posix()
    return next((g for g, prefixes in REAL_TIME_GROUPS.items() if where.startswith(prefixes)), None)


@pytest.hookimpl(tryfirst=True)  # before xdist's worker reads the groups from the marks
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    order = list(REAL_TIME_GROUPS)

    def rank(item: pytest.Item) -> tuple[int, bool]:
        group = _group(item)
        return (order.index(group) if group else len(order), item.get_closest_marker("slow") is None)

    items.sort(key=rank)  # stable: otherwise in collection order
    for item in items:
        if (group := _group(item)) is not None:
            item.add_marker(pytest.mark.xdist_group(group))


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the numba kernels into numba's disk cache once, before xdist starts its workers.

    As `uavsearch run` does before its companions: on a fresh checkout every process would
    otherwise compile them at once, for tens of seconds each. The agents' kernels come from the
    core's warm-up, the batch engine's scoring kernels from a few steps of the engine.
    """
    if hasattr(session.config, "workerinput"):
        return  # an xdist worker: the controller has done it
    from companion.batch.engine import simulate
    from companion.core.feasibility import load_mission
    from companion.core.warm import warm_up

    mission = load_mission(Path(__file__).parents[1] / "mission_files" / "scenario1.toml")
    warm_up(mission)
    simulate(mission, mission.seed, 0, 5)
