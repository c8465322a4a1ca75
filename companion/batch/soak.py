"""The safety soak: generated missions, every algorithm, counting steps that lose separation or a link.

docs/algorithm.md, "Safety layer", describes the guarantees it checks. `uavsearch soak` runs it at
any size; the test suite runs a few dozen missions of it.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import msgspec
import numpy as np

from companion.batch.engine import RunResult
from companion.batch.executors import RunExecutor
from companion.batch.generate import Family, generate
from companion.batch.montecarlo import RunSpec, run_specs
from companion.contracts.mission import ALGORITHMS


@dataclass(frozen=True)
class SoakRow:
    """One run of the soak: its mission, algorithm, faults and safety figures."""

    mission: str
    mode: str
    uavs: int
    algorithm: str
    killed: tuple[tuple[int, int], ...]
    separation_losses: int
    link_losses: int
    keepout_entries: int
    closest_approach: float
    targets_found: int
    targets: int
    recovered: int  # trajectories in force replaced by a contingency: 0 where UAVs fly their plans exactly

    @property
    def clean(self) -> bool:
        """No separation loss, and no link loss unless a companion died.

        A dead UAV's radio is silent, and the live swarm may be split by its loss: connectivity is
        guaranteed without faults, separation always.
        """
        clean = self.separation_losses == 0 and self.keepout_entries == 0
        return clean and (self.link_losses == 0 or bool(self.killed))


def soak_specs(
    missions: int,
    seed: int,
    steps: int,
    algorithms: tuple[str, ...] = ALGORITHMS,
    loss: float = 0.0,
    kill: bool = False,
    family: Family | None = None,
) -> list[RunSpec]:
    """One spec per generated mission and algorithm, optionally with a companion that dies.

    With `kill`, one UAV of each mission (drawn from the seed) loses its companion at a step drawn
    from the first half of the run.
    """
    specs = []
    for i, (mission, _) in enumerate(generate(missions, seed, family)):
        if loss:
            mission = msgspec.structs.replace(
                mission, comms=msgspec.structs.replace(mission.comms, loss=loss)
            )
        kills: tuple[tuple[int, int], ...] = ()
        if kill:
            rng = np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(i, 1)))
            kills = ((int(rng.integers(mission.n_uavs)), int(rng.integers(1, max(2, steps // 2)))),)
        specs += [RunSpec(mission.with_algorithm(a), mission.seed, 0, steps, kills=kills) for a in algorithms]
    return specs


def soak(
    specs: list[RunSpec], workers: int | None = None, executor: RunExecutor | None = None
) -> Iterator[SoakRow]:
    """Run the specs and report each run's safety figures.

    The specs run in order, on `executor` (default: a local pool of `workers`).
    """
    for spec, r in zip(specs, run_specs(specs, workers, executor), strict=True):
        yield row_of(spec, r)


def row_of(spec: RunSpec, r: RunResult) -> SoakRow:
    m = spec.mission
    return SoakRow(
        m.name,
        m.kinematics.mode,
        m.n_uavs,
        m.algorithm.name,
        spec.kills,
        r.separation_losses,
        r.link_losses,
        r.keepout_entries or 0,
        float(r.approach.min()),
        int(np.count_nonzero(r.target_steps >= 0)),
        len(r.target_steps),
        int(r.extras.get("recovered", 0)),
    )
