"""Mission files that would make a process allocate what a machine cannot hold, or that are not
text, get `error: mission file FILE: FIELD: REASON` and exit 2 (never a traceback, never a
MemoryError)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from companion.mission import MissionError, load_mission

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
        [sys.executable, "-m", "companion.app.cli", *command, str(path)],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "MemoryError" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(f"error: mission file {path}: region.cell_size: ")
