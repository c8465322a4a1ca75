"""The contingency clause of the safety layer, read off the agents of a batch run (a `simulate`
probe): for every pair of UAVs, how far each one's trajectory in force keeps from the region where
the other's aircraft may fly if its companion falls silent (`safety.contingency_clearance`: its
path's fan about its loiter's centre, inflated), beyond the disk separation."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from companion.core.agent import Agent
from companion.core.safety.contingency import contingency_clearance
from companion.core.safety.expansion import expand_with_centres
from companion.core.world import World


def clause_probe(world: World, rows: list[np.ndarray]) -> Callable[[int, list[Agent]], None]:
    """A `simulate` probe appending, at every step k, the (n, n) matrix of the pairs' contingency
    clearances (upper triangle, pairs on near layers: the clause guards only those; +inf elsewhere):
    positive where the pair clears both regions."""
    plan = world.safety
    lim, reach = plan.limits, plan.failsafe_reach + plan.failsafe_stray

    def probe(k: int, agents: list[Agent]) -> None:
        trajs = [a.commitments.inforce for a in agents]
        # covers all later time (the loiters repeat)
        pts, centres = expand_with_centres(lim.rows(trajs), k, lim.reach.window, lim.kinematics_args)
        entries = [t.loiter_entry(lim.reach.loiter_turn) - k for t in trajs]
        out = np.full((len(trajs), len(trajs)), np.inf)
        for i in range(len(trajs)):
            for j in range(i + 1, len(trajs)):
                if not plan.near[i, j]:
                    continue
                c = contingency_clearance(
                    pts[i], entries[i], *centres[i], pts[j], entries[j], *centres[j], reach
                )
                out[i, j] = c - lim.disk_separation
        rows.append(out)

    return probe


def clear_pairs(rows: list[np.ndarray]) -> np.ndarray:
    """(steps, pairs) booleans: the pair clears the clause at that step."""
    c = np.array(rows)
    iu = np.triu_indices(c.shape[1], 1)
    return c[:, iu[0], iu[1]] > 0
