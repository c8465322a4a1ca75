"""A Dask scheduler and workers on 127.0.0.1, as subprocesses: for the cluster benchmark and tests.

Every process binds to loopback only (its dashboard too, on a free port), logs to a file in
`directory`, and is stopped by PID on `close`. Workers run one thread each and no nanny, so a
killed worker stays dead (as a machine that fails would).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from types import TracebackType

from distributed import Client

LOOPBACK = ("--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0")
STARTUP_S = 120.0  # a busy 2-core machine starts Python, Dask and numpy slowly


class LoopbackCluster:
    """`dask scheduler` on a free loopback port; `start_worker` adds `dask worker`s to it."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        self.procs: list[subprocess.Popen] = []  # everything started, the scheduler first
        self.workers: dict[str, subprocess.Popen] = {}  # by worker address
        self.scheduler_file = directory / "scheduler.json"
        self._spawn("scheduler", "scheduler", "--port", "0", "--scheduler-file", str(self.scheduler_file))
        try:
            deadline = time.monotonic() + STARTUP_S
            while not self.scheduler_file.exists() and time.monotonic() < deadline:
                time.sleep(0.1)
            self.client = Client(
                scheduler_file=str(self.scheduler_file), timeout=STARTUP_S, set_as_default=False
            )
        except BaseException:
            self._stop_all()
            raise

    @property
    def address(self) -> str:
        """The scheduler's address (tcp://127.0.0.1:PORT)."""
        scheduler = self.client.scheduler
        assert scheduler is not None and scheduler.address is not None, "the client is connected"
        return scheduler.address

    def start_worker(self, name: str, env: dict[str, str] | None = None) -> str:
        """One more worker (named `name`, with `env` if given); its address once it has joined."""
        known = set(self.client.nthreads())
        proc = self._spawn(
            name,
            "worker",
            "--scheduler-file",
            str(self.scheduler_file),
            "--nthreads",
            "1",
            "--no-nanny",
            "--name",
            name,
            "--local-directory",
            str(self.directory / name),
            env=env,
        )
        deadline = time.monotonic() + STARTUP_S
        while not (new := set(self.client.nthreads()) - known):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"dask worker {name} did not join (see {self.directory / name}.log)")
            time.sleep(0.1)
        (address,) = new
        self.workers[address] = proc
        return address

    def _spawn(self, name: str, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        with (self.directory / f"{name}.log").open("w") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "dask", *args, *LOOPBACK],
                cwd=self.directory,
                stdout=log,
                stderr=subprocess.STDOUT,
                env=env,
            )
        self.procs.append(proc)
        return proc

    def close(self) -> None:
        """Stop every process (SIGTERM, then SIGKILL after 30 s), workers first."""
        self.client.close()
        self._stop_all()

    def _stop_all(self) -> None:
        for proc in reversed(self.procs):
            stop(proc)

    def __enter__(self) -> LoopbackCluster:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def stop(proc: subprocess.Popen) -> None:
    """Terminate one process and wait for it (killed if it takes more than 30 s)."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
