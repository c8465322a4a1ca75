"""README's commands: the shell blocks' command lines, and a clean copy of the checkout to run them in."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FENCE = re.compile(r"^```sh\n(.*?)^```", re.M | re.S)


def readme_commands() -> list[str]:
    """Every command line of README's ```sh blocks (continuations joined, comments dropped)."""
    commands = []
    for block in FENCE.findall((ROOT / "README.md").read_text(encoding="utf-8")):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #", 1)[0].strip()
            if line and not line.startswith("#"):
                commands.append(" ".join(line.split()))
    return commands


def clean_copy(directory: Path) -> Path:
    """The checkout's files as a fresh clone has them (`git ls-files`: no out/, no numba cache), in
    `directory`, with this checkout's virtual environment linked in as `.venv` and the Makefile's
    install step already done (pyproject.toml dated before it), so `make` runs there as on a fresh
    machine after its install. Run it with PYTHONPATH=directory: the environment's editable install
    points at this checkout, while the processes `uavsearch run` starts there (`python -m`) import
    the copy's sources."""
    files = (
        subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True)
        .stdout.decode()
        .split("\0")
    )
    for name in filter(None, files):
        source = ROOT / name
        if source.is_file():
            (directory / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, directory / name)
    (directory / ".venv").symlink_to(ROOT / ".venv")
    os.utime(directory / "pyproject.toml", (0, 0))
    return directory


def progress_steps(stdout: str) -> list[int]:
    return [int(line.split()[1]) for line in stdout.splitlines() if line.startswith("step ")]


def summary_steps(stdout: str, mission: str) -> int:
    line = next(line for line in stdout.splitlines() if line.startswith(f"{mission}: "))
    return int(line.split(": ", 1)[1].split(" steps")[0])
