"""The stand-alone camera (`uavsearch camera`) as a process beside the bundled simulator."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.sim.conftest import ROOT, SimProcess, write_mission
from tests.thread_signal import signal_another_thread

pytestmark = pytest.mark.timeout(120)
STARTUP_S = 60.0


def _until_line(proc: subprocess.Popen[str], text: str) -> list[str]:
    """Lines of `proc`'s output up to the first that contains `text`."""
    assert proc.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + STARTUP_S
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.rstrip())
        if text in line:
            return lines
    raise AssertionError(f"no {text!r} from the camera: {lines}")


def test_camera_exits_0_when_sigterm_reaches_one_of_its_other_threads(
    tmp_path: Path, start_sim: Callable[..., SimProcess]
) -> None:
    """The kernel hands a process's SIGTERM to any thread that does not block it (the camera runs a
    thread per vehicle and Zenoh's); its main thread must still see it and stop them all."""
    path, ports, _ = write_mission(tmp_path, n=2)
    start_sim(path, "--no-camera", n=2)
    links = ",".join(f"udpout:127.0.0.1:{p}" for p in ports)
    camera = subprocess.Popen(
        [sys.executable, "-m", "companion.app.cli", "camera", "--mission", str(path), "--vehicles", links],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        _until_line(camera, "camera: vehicle 1 up")
        signal_another_thread(camera.pid, signal.SIGTERM)
        assert camera.wait(timeout=15) == 0
    finally:
        if camera.poll() is None:
            camera.kill()
            camera.wait()
