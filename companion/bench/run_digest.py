"""A hash of every figure of seeded batch runs: whether a change keeps runs bit-identical.

Run as a script so that `companion` is imported from PYTHONPATH, once per checkout, and compare the
last lines (docs/performance.md gives the commands). It flies the checkout's scenario files (and
scenario 1 in continuous mode) with each algorithm, runs 0-2 (run 2 kills UAV 1's companion at step
100 and takes UAV 2's vehicle from its companion at step 150), with `--sensor PD,PF` also scenarios
1-continuous, 1 and 3 with that imperfect sensor (the candidates and confirmation bids' paths), and
with `--missions DIR` also every mission file in DIR (each of these run 0, UAV 1's companion killed
at step 120). Every field of each `RunResult` but its wall time and the figures it lacks (None) is
hashed: trajectories, tasks, the metric curves, target steps and the protocol's counters.
"""

from __future__ import annotations

import argparse
import hashlib
from pathlib import Path
from typing import TypedDict

import numpy as np

SCENARIOS = ("scenario1", "scenario2", "scenario3", "scenario1_continuous")
IMPERFECT = ("scenario1_continuous", "scenario1", "scenario3")  # `--sensor`: these, in this order
ALGORITHMS = ("proposed", "no-ta", "pheromone")


class Faults(TypedDict, total=False):
    """The faults of a run, as `simulate` takes them: companions killed, vehicles taken over."""

    kills: dict[int, int]
    takeovers: dict[int, int]


def main() -> None:
    import companion
    from companion.batch.engine import simulate
    from companion.batch.sensing_study import with_sensor
    from companion.contracts.arguments import sensor_pair
    from companion.contracts.mission import Mission
    from companion.core.feasibility import load_mission

    root = Path(companion.__file__).resolve().parents[1]  # the checkout hashed, its own mission files
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--sensor", type=sensor_pair, help=f"PD,PF: also {', '.join(IMPERFECT)} with this sensor"
    )
    parser.add_argument("--missions", type=Path, help="also every *.toml in this directory")
    args = parser.parse_args()
    faulty: Faults = {"kills": {1: 100}, "takeovers": {2: 150}}
    none: Faults = {}
    files = root / "mission_files"
    cases: list[tuple[str, Mission, int, Faults]] = [
        (name, load_mission(files / f"{name}.toml"), run, faulty if run == 2 else none)
        for name in SCENARIOS
        for run in (0, 1, 2)
    ]
    killed = Faults(kills={1: 120})
    if args.sensor is not None:
        pd, pf = args.sensor
        cases += [
            (
                f"{name}_pd{pd:g}_pf{pf:g}",
                with_sensor(load_mission(files / f"{name}.toml"), pd, pf),
                0,
                killed,
            )
            for name in IMPERFECT
        ]
    if args.missions is not None:
        cases += [(path.stem, load_mission(path), 0, killed) for path in sorted(args.missions.glob("*.toml"))]
    total = hashlib.sha256()
    for label, mission, run, faults in cases:
        for algorithm in ALGORITHMS:
            flown = mission.with_algorithm(algorithm)
            result = simulate(flown, args.seed, run, args.steps, record=True, **faults)
            one = hashlib.sha256()
            for name, value in sorted(vars(result).items()):
                if name != "seconds" and value is not None:  # a figure a run lacks adds nothing
                    one.update(name.encode())
                    one.update(value.tobytes() if isinstance(value, np.ndarray) else repr(value).encode())
            total.update(one.digest())
            print(f"{label} {algorithm} run {run}: {one.hexdigest()[:16]}", flush=True)
    print(f"all {total.hexdigest()}")


if __name__ == "__main__":
    main()
