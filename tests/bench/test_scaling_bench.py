"""`uavsearch scaling-bench`: CPU per step against the swarm's size, as docs/performance.md runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.bench.swarm_scaling import ScalingPoint, growth, swarm_of
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]


def _point(n: int, ms: float) -> ScalingPoint:
    return ScalingPoint("proposed", n, 10, ms * 10 / 1e3, ms, ms / n, 0)


@pytest.mark.parametrize("power", [1.0, 1.5, 2.0])
def test_growth_is_the_log_log_slope(power: float) -> None:
    assert growth([_point(n, 0.3 * n**power) for n in (4, 8, 16, 32)]) == pytest.approx(power)


def test_every_size_is_a_valid_swarm() -> None:
    base = load_mission(ROOT / "mission_files" / "scenario1.toml")
    for n in (4, 8, 16, 32):
        assert swarm_of(base, n).n_uavs == n


def test_the_command_prints_writes_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "scaling"
    argv = [sys.executable, "-m", "companion.cli", "scaling-bench", "--sizes", "2,4", "--steps", "10",
            "--algorithms", "proposed,no-ta", "--out", str(out)]  # fmt: skip
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "proposed: CPU per step grows as N^" in proc.stdout
    figures = json.loads((out / "scaling.json").read_text())
    assert [(p["algorithm"], p["uavs"]) for p in figures["points"]] == [
        ("proposed", 2),
        ("proposed", 4),
        ("no-ta", 2),
        ("no-ta", 4),
    ]
    assert all(p["cpu_s"] > 0 and p["steps"] == 10 for p in figures["points"])
    assert set(figures["exponents"]) == {"proposed", "no-ta"}
    assert (out / "scaling.png").read_bytes()[:4] == b"\x89PNG"
