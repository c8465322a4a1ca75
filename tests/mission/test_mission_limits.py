"""Mission files that would make a process allocate what a machine cannot hold, or that are not
text, get `error: mission file FILE: FIELD: REASON` and exit 2 (never a traceback, never a
MemoryError)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from companion.contracts.mission import MissionError
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]
BASE = (ROOT / "mission_files" / "scenario1.toml").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("cell_size = 40.0", "cell_size = 0.001", "region.cell_size"),
        ("targets = 9", "targets = 2501", "prior.targets"),
        ("radius = 60.0", "radius = 4000.0", "sensor.radius"),
        ("n_g = 50", "n_g = 3000", "algorithm.n_g"),
        ("steps = 1000", "steps = 1000000000", "steps"),
    ],
)
def test_sizes_are_bounded(tmp_path: Path, old: str, new: str, field: str) -> None:
    path = tmp_path / "big.toml"
    path.write_text(BASE.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(MissionError) as err:
        load_mission(path)
    assert err.value.source == str(path) and err.value.field == field


def test_bytes_that_are_not_utf8_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes(BASE.replace("Scenario 1", "Sc\xe9nario 1").encode("latin-1"))
    with pytest.raises(MissionError) as err:
        load_mission(path)
    assert err.value.source == str(path) and err.value.field == "(file)" and "UTF-8" in err.value.reason


@pytest.mark.parametrize("command", [["mc", "--runs", "1", "--mission"], ["sim", "--mission"]])
def test_command_line_error_format(tmp_path: Path, command: list[str]) -> None:
    path = tmp_path / "tiny_cells.toml"
    path.write_text(BASE.replace("cell_size = 40.0", "cell_size = 0.001", 1), encoding="utf-8")
    r = subprocess.run(
        [sys.executable, "-m", "companion.cli", *command, str(path)],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "MemoryError" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(f"error: mission file {path}: region.cell_size: ")


CONTINUOUS = (ROOT / "mission_files" / "scenario1_continuous.toml").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("base", "old", "new", "field"),
    [
        # a loiter closing in 360,000 steps: the safety layer's pairwise loiter table needed 1.89 TiB
        (CONTINUOUS, "turn_limit_deg = 45.0", "turn_limit_deg = 0.001", "kinematics.turn_limit_deg"),
        (CONTINUOUS, "step = 2.0", "step = 1e200", "kinematics.step"),  # an OverflowError
        (BASE, "step = 2.0", "step = 1e200", "kinematics.step"),
        (CONTINUOUS, "speed = 20.0", "speed = 1e-300", "kinematics.step"),  # a loiter of no size
        (CONTINUOUS, "speed = 20.0", "speed = 1000.5", "kinematics.speed"),
        (CONTINUOUS, "step = 2.0", "step = 3000.0", "kinematics.speed"),  # 60 km a step: the reach
        (BASE, "cell_size = 40.0", "cell_size = 1e-300", "region.cell_size"),  # an OverflowError
        (BASE, "[pass_criteria]", "[safety]\nmargin = 1e12\n\n[pass_criteria]", "safety.margin"),
        (BASE, "[pass_criteria]", "[sim]\nphysics_hz = 1e9\n\n[pass_criteria]", "sim.physics_hz"),
    ],
    ids=lambda v: v if isinstance(v, str) and len(v) < 40 else "",
)
def test_what_the_kinematics_imply_is_bounded(
    tmp_path: Path, base: str, old: str, new: str, field: str
) -> None:
    assert old in base
    path = tmp_path / "implied.toml"
    path.write_text(base.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(MissionError) as err:
        load_mission(path)
    assert err.value.source == str(path) and err.value.field == field, err.value


def test_the_turn_limit_crash_is_one_line_from_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "slow_turn.toml"
    text = CONTINUOUS.replace("turn_limit_deg = 45.0", "turn_limit_deg = 0.001", 1)
    path.write_text(text, encoding="utf-8")
    r = subprocess.run(
        [sys.executable, "-m", "companion.cli", "mc", "--runs", "1", "--mission", str(path)],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "MemoryError" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[-1].startswith(f"error: mission file {path}: kinematics.turn_limit_deg: "), r.stderr
