"""Fixtures: meshes closed after each test, and subprocesses stopped by PID."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
from mesh_helpers import N_CELLS, N_TASKS

from companion.contracts.mission import Mission
from companion.node.mesh import Mesh

HERE = Path(__file__).resolve().parent


@pytest.fixture
def open_mesh() -> Iterator[Callable[..., Mesh]]:
    """`open_mesh(mission, uav, **kwargs)`: a Mesh closed at teardown."""
    with ExitStack() as stack:

        def factory(mission: Mission, uav: int, **kwargs: object) -> Mesh:
            return stack.enter_context(Mesh(mission, uav, N_CELLS, N_TASKS, **kwargs))

        yield factory


@pytest.fixture
def spawn() -> Iterator[Callable[..., subprocess.Popen[str]]]:
    """Start `python -m companion.node.mesh router ...` or a peer_proc.py peer; stop leftovers by PID."""
    procs: list[subprocess.Popen[str]] = []

    def start(*args: str) -> subprocess.Popen[str]:
        proc = subprocess.Popen(
            [sys.executable, *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=HERE,
        )
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                stream.close()
