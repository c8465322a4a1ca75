"""The benchmark's child processes: UAV workers (a reusable pool), a router and a viewer.

All are started with `subprocess` (never forked after Zenoh is opened) and stopped by PID.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import msgspec

from companion.app.view.live import ListenerStatus
from companion.bench.cpu_usage import proc_cpu_s, tree_cpu_s
from companion.bench.uav_worker import TAG

# Fewer Zenoh runtime threads per process: many sessions share 2 cores (../shared/notes/zenoh.md).
LEAN_ZENOH_RUNTIME = (
    "(rx: (handover: app), net: (handover: app), acc: (handover: app), "
    "app: (worker_threads: 1), tx: (worker_threads: 1))"
)
STARTUP_S = 300.0  # a loaded 2-core machine imports numpy, numba and zenoh slowly, 50 times over
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


class ViewerStatus(ListenerStatus, frozen=True):
    """The view server's /api/status: its listener's counters and the number of pages connected."""

    pages: int


class Viewer:
    """A viewer on a trial's mesh: the view server and a headless Chromium.

    A viewer on a trial's mesh: the view server, and a headless Chromium on its page (when
    /usr/bin/chromium exists). Both stopped by PID."""

    def __init__(self, mission_json: Path, log: Path) -> None:
        self.log = log
        with log.open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "companion.bench", "viewer", str(mission_json)],
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
            )
        assert self.proc.stdout is not None
        self.url = ""
        for line in self.proc.stdout:
            if line.startswith(TAG):
                self.url = json.loads(line[len(TAG) :])["url"]
                break
        if not self.url:
            self.stop()
            raise RuntimeError(f"the view server did not start: {log.read_text(errors='replace')[-500:]}")
        self.browser: subprocess.Popen | None = None
        self._profile = tempfile.TemporaryDirectory(prefix="companion-bench-chromium-")
        if CHROMIUM.exists():
            self.browser = subprocess.Popen(
                [str(CHROMIUM), *CHROMIUM_FLAGS, f"--user-data-dir={self._profile.name}", self.url],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )

    def status(self) -> ViewerStatus:
        """The view server's counters (/api/status)."""
        with urllib.request.urlopen(self.url + "api/status", timeout=10) as r:
            return msgspec.json.decode(r.read(), type=ViewerStatus)

    def wait_attached(self, n: int, timeout: float) -> ViewerStatus:
        """Until the server sees all n UAVs alive and (with a browser) the page is connected."""
        deadline = time.monotonic() + timeout
        while True:
            s = self.status()
            if len(s.alive) == n and (self.browser is None or s.pages >= 1):
                return s
            if time.monotonic() > deadline:
                raise RuntimeError(f"viewer not attached within {timeout:.0f} s: {s}")
            time.sleep(0.2)

    def cpu_s(self) -> float:
        """CPU seconds of the view server and of the browser with all its processes."""
        browser = tree_cpu_s(self.browser.pid) if self.browser else 0.0
        return proc_cpu_s(self.proc.pid) + browser

    def stop(self) -> None:
        if self.browser is not None:
            self.browser.terminate()
            reap(self.browser)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        reap(self.proc)
        self._profile.cleanup()


class Worker:
    """A worker subprocess; a thread turns its protocol lines into a queue."""

    def __init__(self, env: dict[str, str], log: Path) -> None:
        self.log = log
        with log.open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "companion.bench", "worker"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                env=env,
            )
        self.lines: queue.Queue[dict | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith(TAG):
                self.lines.put(json.loads(line[len(TAG) :]))
        self.lines.put(None)

    def send(self, **cmd: object) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()

    def recv(self, op: str, timeout: float) -> dict:
        try:
            msg = self.lines.get(timeout=timeout)
        except queue.Empty:
            raise RuntimeError(f"worker {self.proc.pid}: no {op!r} within {timeout:.0f} s") from None
        if msg is None:
            self.proc.wait(timeout=15)
            tail = self.log.read_text(errors="replace").strip().splitlines()[-3:]
            raise RuntimeError(f"worker {self.proc.pid} exited (code {self.proc.poll()}): {' | '.join(tail)}")
        if msg.get("op") != op:
            raise RuntimeError(f"worker {self.proc.pid}: expected {op!r}, got {msg.get('op')!r}")
        return msg

    def stop(self) -> None:
        """Close stdin (the worker closes its session and exits); kill by PID if it lingers."""
        try:
            if self.proc.stdin is not None:
                self.proc.stdin.close()
        except OSError:
            pass
        reap(self.proc)


def reap(proc: subprocess.Popen) -> None:
    """Wait for a process we asked to stop; kill it by PID if it lingers; close its pipe."""
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=15)
    if proc.stdout is not None:
        proc.stdout.close()


class Pool:
    """Workers started on demand and reused across trials."""

    def __init__(self, lean_runtime: bool) -> None:
        self.env = dict(os.environ)
        if lean_runtime:
            self.env["ZENOH_RUNTIME"] = LEAN_ZENOH_RUNTIME
        self.workers: list[Worker] = []
        self._logs = tempfile.TemporaryDirectory(prefix="companion-bench-logs-")

    def take(self, n: int) -> list[Worker]:
        logs = Path(self._logs.name)
        new = [Worker(self.env, logs / f"worker{i}.log") for i in range(len(self.workers), n)]
        self.workers.extend(new)
        for w in new:
            w.recv("hello", STARTUP_S)
        return self.workers[:n]

    def close(self) -> None:
        for w in self.workers:
            w.stop()
        self.workers.clear()
        self._logs.cleanup()


class Router:
    """`python -m companion.node.mesh router --endpoint E` in its own process, stopped with SIGTERM."""

    def __init__(self, endpoint: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "companion.node.mesh", "router", "--endpoint", endpoint],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()  # "router listening on E"
        if "listening" not in line:
            self.stop()
            raise RuntimeError(f"router did not start on {endpoint}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        reap(self.proc)

