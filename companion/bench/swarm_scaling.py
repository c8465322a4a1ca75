"""The batch engine's cost as the swarm grows: CPU per step against the number of UAVs (issue 38).

Each size flies scenario 1's region and prior with N UAVs spread on a grid at its centre
(`swarm_missions.spread_vehicles`), checked like a mission file, after a short run that loads the
kernels. The growth exponent is the slope of log CPU per step against log N over the sizes.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path

import msgspec
import numpy as np

from companion.batch.engine import simulate
from companion.bench.swarm_missions import spread_vehicles
from companion.contracts.mission import Mission
from companion.core.feasibility import validate


class ScalingPoint(msgspec.Struct, frozen=True):
    """One swarm size's cost: CPU seconds per step and per UAV-step, and what the run found."""

    algorithm: str
    uavs: int
    steps: int
    cpu_s: float
    ms_per_step: float
    ms_per_uav_step: float
    targets_found: int


class Scaling(msgspec.Struct, frozen=True):
    """Every size's point and, per algorithm, the growth exponent of CPU per step against N."""

    mission: str
    points: list[ScalingPoint]
    exponents: dict[str, float]


def swarm_of(base: Mission, n: int) -> Mission:
    """`base` flown by `n` UAVs spread on a grid at the region's centre, checked as a mission file is."""
    swarm = msgspec.structs.replace(base, vehicles=spread_vehicles(base, n))
    return validate(swarm, f"{base.name}, {n} UAVs")


def measure(base: Mission, sizes: Sequence[int], algorithms: Sequence[str], steps: int) -> Scaling:
    """Time one seeded run of `steps` steps for every size and algorithm (CPU time, one core)."""
    points = []
    for name in algorithms:
        for n in sizes:
            mission = swarm_of(base.with_algorithm(name), n)
            simulate(mission, mission.seed, 0, 3)  # the kernels for this size and algorithm
            start = time.process_time()
            result = simulate(mission, mission.seed, 0, steps)
            cpu = time.process_time() - start
            found = int(np.count_nonzero(result.target_steps >= 0))
            points.append(ScalingPoint(name, n, steps, cpu, 1e3 * cpu / steps, 1e3 * cpu / steps / n, found))
    exponents = {a: growth([p for p in points if p.algorithm == a]) for a in algorithms}
    return Scaling(base.name, points, exponents)


def growth(points: Sequence[ScalingPoint]) -> float:
    """The least-squares slope of log(ms per step) against log(N): 1 is linear in N, 2 quadratic."""
    if len(points) < 2:
        return math.nan
    x = np.log([p.uavs for p in points])
    y = np.log([p.ms_per_step for p in points])
    return float(np.polyfit(x, y, 1)[0])


def format_scaling(s: Scaling) -> str:
    """The table `uavsearch scaling-bench` prints."""
    lines = [f"{s.mission}: CPU per step against swarm size (one core)"]
    lines.append("algorithm   UAVs  ms/step  ms/UAV-step  found")
    for p in s.points:
        figures = f"{p.ms_per_step:>8.2f} {p.ms_per_uav_step:>12.3f} {p.targets_found:>6}"
        lines.append(f"{p.algorithm:<10} {p.uavs:>5} {figures}")
    for name, k in s.exponents.items():
        lines.append(f"{name}: CPU per step grows as N^{k:.2f}")
    return "\n".join(lines)


def plot_scaling(s: Scaling, path: Path) -> None:
    """CPU per step against N on log-log axes, one line per algorithm, with N and N^2 for reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name in s.exponents:
        pts = [p for p in s.points if p.algorithm == name]
        label = f"{name} (N^{s.exponents[name]:.2f})"
        ax.loglog([p.uavs for p in pts], [p.ms_per_step for p in pts], "o-", label=label)
    first = s.points[0]
    ns = np.array(sorted({p.uavs for p in s.points}), dtype=float)
    for power, style in ((1, ":"), (2, "--")):
        ax.loglog(ns, first.ms_per_step * (ns / first.uavs) ** power, "k" + style, lw=0.8, label=f"N^{power}")
    ax.set_xticks(ns, [str(int(n)) for n in ns])
    ax.minorticks_off()
    ax.set_xlabel("UAVs (N)")
    ax.set_ylabel("CPU ms per step (one core)")
    ax.set_title(f"{s.mission}: the batch engine's cost as the swarm grows")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
