"""The subprocesses a launcher starts: started in their own sessions, stopped by PID, never left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

from companion.contracts.lifeline import launcher_env

START_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 30.0  # a companion flies out its trajectory in force first (horizon + 1 steps)


class Interrupted(RuntimeError):
    """A signal stopped the launcher while it waited for a child to start."""


class Children:
    """The subprocesses this launcher started, stopped by PID and never left behind.

    `stop` (set by SIGINT/SIGTERM) cuts any wait for one of them short.
    """

    def __init__(self, stop: threading.Event | None = None) -> None:
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.signals: dict[str, int] = {}
        self.env: dict[str, str] = {}  # added to every child's environment (the run identity)
        self._stop = stop if stop is not None else threading.Event()

    def start(
        self,
        name: str,
        argv: list[str],
        log: Path,
        cwd: Path | None = None,
        extra: dict[str, str] | None = None,
        stop_signal: int = signal.SIGTERM,
    ) -> subprocess.Popen:
        """Start `argv` in its own session, output to `log`, with `extra` added to the environment.

        `stop` sends it `stop_signal`: SIGTERM, which our processes handle as they do SIGINT but
        which, unlike SIGINT, ends one still loading its modules with no traceback. Our own
        processes end with this one (`lifeline`).
        """
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **launcher_env(), **self.env, **(extra or {})}
        with log.open("w") as f:
            proc = subprocess.Popen(
                argv, stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True, cwd=cwd
            )
        self.procs[name], self.logs[name], self.signals[name] = proc, log, stop_signal
        return proc

    def wait_for_line(self, name: str, text: str, timeout: float = START_TIMEOUT_S) -> str:
        """The first line of child `name`'s log holding `text`, once it is there.

        It raises RuntimeError if the child exits first or `timeout` seconds pass, Interrupted if a
        signal comes first.
        """
        log, proc = self.logs[name], self.procs[name]
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if log.exists():
                for line in log.read_text(errors="replace").splitlines():
                    if text in line:
                        return line
            if proc.poll() is not None:
                raise RuntimeError(
                    f"{log.name}: exited with {proc.returncode}:\n{log.read_text(errors='replace')}"
                )
            if self._stop.wait(0.1):
                raise Interrupted(f"stopped by a signal while waiting for '{text}' from {name}")
        raise RuntimeError(f"{log.name}: '{text}' not seen within {timeout:.0f} s")

    def stop(self) -> None:
        """Send each child its stop signal (SIGTERM unless started otherwise), the companions first.

        A companion ends its step and writes its report while its vehicle, camera and router still
        answer. Whatever has not exited `STOP_TIMEOUT_S` after its signal is killed.
        """
        companions = [n for n in self.procs if n.startswith("companion")]
        for group in (companions, [n for n in self.procs if n not in companions]):
            for name in group:
                if self.procs[name].poll() is None:
                    self.procs[name].send_signal(self.signals[name])
            deadline = time.monotonic() + STOP_TIMEOUT_S
            for name in group:
                try:
                    self.procs[name].wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    self.procs[name].kill()
                    self.procs[name].wait()
