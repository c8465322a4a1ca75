"""The stand-alone camera (`uavsearch camera`) as a process beside the bundled simulator."""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.e2e.conftest import Proc
from tests.sim.conftest import SimProcess, write_mission

pytestmark = pytest.mark.timeout(120)


def test_camera_exits_0_when_sigterm_reaches_one_of_its_other_threads(
    tmp_path: Path, start_sim: Callable[..., SimProcess]
) -> None:
    """The kernel hands a process's SIGTERM to any thread that does not block it (the camera runs a
    thread per vehicle and Zenoh's); its main thread must still see it and stop them all."""
    path, ports, _ = write_mission(tmp_path, n=2)
    start_sim(path, "--no-camera", n=2)
    links = ",".join(f"udpout:127.0.0.1:{p}" for p in ports)
    argv = [sys.executable, "-m", "companion.cli", "camera", "--mission", str(path), "--vehicles", links]
    camera = Proc("camera", argv, tmp_path / "camera.log", stop_signal=signal.SIGTERM)
    try:
        camera.wait_for_text("camera: vehicle 1 up")
        assert camera.stop(timeout=15, through_a_thread=True) == 0, camera.text()
    finally:
        camera.stop()
