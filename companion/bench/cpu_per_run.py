"""CPU seconds of one 1,000-step batch run of each scenario file and algorithm, in this process.

Run as a script so that `companion` is imported from PYTHONPATH: the same measurement then times
another checkout, interleaved with this one so that the machine's drift hits both alike
(`uavsearch bench --against`; docs/performance.md, "Against an older commit", gives the loop).
CPU time (`time.process_time`), not wall time: other processes on the machine slow a run's wall
time, much less its CPU time. It uses only `load_mission`, `Mission.with_algorithm` and `simulate`,
and the timed checkout's own mission files; `load_mission` is looked up where the timed checkout
keeps it. `--sensor PD,PF` replaces each file's sensor (a checkout without one cannot take it).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import msgspec


def main() -> None:
    import companion
    from companion.batch.engine import simulate

    try:
        from companion.core.feasibility import load_mission
    except ImportError:  # a checkout from before the layers (e1523f9, the issue 38 baseline)
        from companion.mission import load_mission  # type: ignore[no-redef]

    root = Path(companion.__file__).resolve().parents[1]  # the checkout timed, its own mission files
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label", default="", help="printed first on the line")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--run", type=int, default=0)
    parser.add_argument("--sensor", help="PD,PF: every scenario with this sensor, Pd flat")
    args = parser.parse_args()
    cells = []
    for s in (1, 2, 3):
        mission = load_mission(root / "mission_files" / f"scenario{s}.toml")
        if args.sensor is not None:
            if not hasattr(mission, "sensor"):
                raise SystemExit(f"{root}: its missions have no sensor (a checkout before imperfect sensing)")
            pd, pf = (float(v) for v in args.sensor.split(","))
            sensor = msgspec.structs.replace(mission.sensor, pd=pd, pf=pf, pd_edge=None)
            mission = msgspec.structs.replace(mission, sensor=sensor)
        simulate(mission, args.seed, args.run, steps=20)  # numba's kernels loaded before timing
        for algorithm in ("proposed", "no-ta", "pheromone"):
            flown = mission.with_algorithm(algorithm)
            started = time.process_time()
            simulate(flown, args.seed, args.run, steps=args.steps)
            cells.append(time.process_time() - started)
    print(args.label, " ".join(f"{c:.3f}" for c in cells), f"total {sum(cells):.2f} s")


if __name__ == "__main__":
    main()
