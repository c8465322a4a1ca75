"""How a batch run's time splits between the compiled kernels and the Python around them.

Every numba dispatcher that the core modules and the batch engine call from Python is wrapped in
a timer (after a warm-up run has compiled or loaded every kernel, so that no kernel is compiled
against a wrapper); the rest of the run's wall time is Python glue. This bounds what compiling
the remaining glue could give (docs/performance.md, "Where the time goes"):

    python -m companion.bench.kernel_share --scenario 3 --algorithm proposed --runs 3

Calls from one kernel to another are compiled and are counted in the caller's time.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from numba.core.registry import CPUDispatcher


@dataclass(frozen=True)
class Share:
    total: float  # wall seconds of the timed runs
    kernels: dict[str, tuple[int, float]]  # kernel name -> (calls, seconds)

    @property
    def in_kernels(self) -> float:
        return sum(seconds for _, seconds in self.kernels.values())


def _modules() -> list[ModuleType]:
    import companion.core

    names = [m.name for m in pkgutil.walk_packages(companion.core.__path__, "companion.core.")]
    return [importlib.import_module(n) for n in (*names, "companion.batch.engine")]


def _timed(name: str, kernel: Callable[..., Any], into: dict[str, list[float]]) -> Callable[..., Any]:
    tally = into.setdefault(name, [0, 0.0])

    def timed(*args: Any) -> Any:
        started = time.perf_counter()
        try:
            return kernel(*args)
        finally:
            tally[0] += 1
            tally[1] += time.perf_counter() - started

    return timed


def measure(mission_path: Path, algorithm: str, runs: int, steps: int, seed: int = 1) -> Share:
    """Time `runs` batch runs of `steps` steps, with every kernel call from Python timed.

    It patches the core modules' kernels for the rest of this process: run it in a process of its
    own.
    """
    from companion.batch.engine import simulate
    from companion.core.feasibility import load_mission

    mission = load_mission(mission_path).with_algorithm(algorithm)
    simulate(mission, seed, runs, steps=min(steps, 200))  # every kernel compiled or loaded
    tallies: dict[str, list[float]] = {}
    for module in _modules():
        for name, value in list(vars(module).items()):
            if isinstance(value, CPUDispatcher):
                setattr(module, name, _timed(name, value, tallies))
    started = time.perf_counter()
    for run in range(runs):
        simulate(mission, seed, run, steps=steps)
    total = time.perf_counter() - started
    kernels = {name: (int(calls), seconds) for name, (calls, seconds) in tallies.items() if calls}
    return Share(total, kernels)


def format_share(share: Share) -> str:
    lines = [
        f"wall {share.total:.3f} s: compiled kernels {share.in_kernels:.3f} s "
        f"({share.in_kernels / share.total:.0%}), Python around them "
        f"{share.total - share.in_kernels:.3f} s ({1 - share.in_kernels / share.total:.0%})",
        "kernel                           calls   seconds  us/call",
    ]
    ranked = sorted(share.kernels.items(), key=lambda kv: -kv[1][1])
    for name, (calls, seconds) in ranked:
        lines.append(f"{name:<30} {calls:7d} {seconds:9.3f} {seconds / calls * 1e6:8.1f}")
    return "\n".join(lines)


def main() -> None:
    import companion

    root = Path(companion.__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", type=int, choices=(1, 2, 3), default=3)
    parser.add_argument("--algorithm", choices=("proposed", "no-ta", "pheromone"), default="proposed")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args()
    path = root / "mission_files" / f"scenario{args.scenario}.toml"
    print(format_share(measure(path, args.algorithm, args.runs, args.steps)))


if __name__ == "__main__":
    main()
