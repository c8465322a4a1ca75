"""`uavsearch bench --against CHECKOUT`: CPU seconds per batch run of this checkout against another's.

Each round runs `cpu_per_run.py` (one 1,000-step run of each scenario file and algorithm, CPU time)
once with the other checkout's `companion` on PYTHONPATH and once with this one's, in fresh
processes, interleaved so that the machine's drift hits both alike, or with `concurrent` both at the
same time, one per core (the drift then hits both within the same seconds); a cell's figure is its
minimum over the rounds; with `sensor` (Pd, Pf) both fly the scenarios with that imperfect sensor.
CPU time, not wall time: other work on the machine slows a run's wall time much more than its CPU
time (docs/performance.md).
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

SCRIPT = Path(__file__).with_name("cpu_per_run.py")
HERE = Path(__file__).resolve().parents[2]  # this checkout
CELLS = [f"s{s} {a}" for s in (1, 2, 3) for a in ("proposed", "no-ta", "pheromone")]


@dataclass(frozen=True)
class Against:
    other: Path
    rounds: int
    old: list[float]  # per cell, CPU seconds (minimum over the rounds)
    new: list[float]
    concurrent: bool = False  # both checkouts timed at the same time, else one after the other
    sensor: tuple[float, float] | None = None  # (Pd, Pf) given to every scenario; None: the files'

    @property
    def ratio(self) -> float:
        """Old total over new total: how many times fewer CPU seconds this checkout takes."""
        return sum(self.old) / sum(self.new)


def checkout(path: Path) -> Path:
    """`path` resolved, if it holds a `companion` package and its scenario files; else ValueError."""
    root = path.resolve()
    if not (root / "companion" / "__init__.py").is_file():
        raise ValueError(f"--against {path}: not a checkout of this project (no companion/__init__.py)")
    if not (root / "mission_files" / "scenario1.toml").is_file():
        raise ValueError(f"--against {path}: no mission_files/scenario1.toml there")
    return root


def _start(root: Path, steps: int, sensor: tuple[float, float] | None) -> subprocess.Popen[str]:
    extra = [] if sensor is None else ["--sensor", f"{sensor[0]!r},{sensor[1]!r}"]
    return subprocess.Popen(
        [sys.executable, str(SCRIPT), "--steps", str(steps), *extra],
        env={**os.environ, "PYTHONPATH": str(root)},
        cwd=root,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _cells(proc: subprocess.Popen[str], root: Path) -> list[float]:
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"timing {root} failed: {err.strip().splitlines()[-1:]}")
    *cells, _, _, _ = out.split()
    return [float(c) for c in cells]


def cpu_against(
    other: Path,
    rounds: int = 2,
    steps: int = 1000,
    concurrent: bool = False,
    sensor: tuple[float, float] | None = None,
) -> Against:
    """Time both checkouts `rounds` times each (`steps` per run): interleaved, or side by side."""
    if rounds < 1 or steps < 1:
        raise ValueError(f"--rounds and --steps must be at least 1 (got {rounds} and {steps})")
    root = checkout(other)
    olds, news = [], []
    for _ in range(rounds):
        if concurrent:
            both = _start(root, steps, sensor), _start(HERE, steps, sensor)
            try:
                olds.append(_cells(both[0], root))
                news.append(_cells(both[1], HERE))
            finally:  # one failed: the other is not left running
                for proc in both:
                    if proc.poll() is None:
                        proc.kill()
                        proc.wait()
        else:
            olds.append(_cells(_start(root, steps, sensor), root))
            news.append(_cells(_start(HERE, steps, sensor), HERE))
    return Against(
        root,
        rounds,
        [min(c) for c in zip(*olds, strict=True)],
        [min(c) for c in zip(*news, strict=True)],
        concurrent,
        sensor,
    )


def format_against(result: Against) -> str:
    kind = "concurrent" if result.concurrent else "interleaved"
    lines = [
        f"CPU seconds per run, minimum of {result.rounds} {kind} rounds"
        + ("" if result.sensor is None else f", sensor Pd {result.sensor[0]:g}, Pf {result.sensor[1]:g}"),
        "cell               other    this   ratio",
    ]
    for cell, old, new in zip(CELLS, result.old, result.new, strict=True):
        lines.append(f"{cell:<16} {old:7.3f} {new:7.3f} {old / new:6.2f}x")
    lines.append(
        f"{'total':<16} {sum(result.old):7.3f} {sum(result.new):7.3f} {result.ratio:6.2f}x"
        f"  (other: {result.other}; this: {HERE})"
    )
    return "\n".join(lines)
