"""The fault matrix's vehicle side: a lockstep driver in a companion's place, a link that can be cut."""

from __future__ import annotations

import contextlib
import os
import selectors
import socket
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

LOCKSTEP_COMMAND = 31010


class LockstepDriver(threading.Thread):
    """Releases one vehicle's lockstep steps in place of its companion, whose link is cut.

    It releases them up to `until`, and at least `span` steps past the step it takes over at (the
    companion may have stepped once more before its link was cut): the vehicle flies on with the
    guidance it last had (then its autopilot's failsafe).
    """

    def __init__(self, port: int, sysid: int, dt: float, until: int, span: int = 0) -> None:
        super().__init__(daemon=True)
        self.port, self.sysid, self.dt, self.until, self.span = port, sysid, dt, until, span
        self.step = -1  # the vehicle's latest step seen
        self.first = -1  # the step it was at when the driver took over
        self.started = threading.Event()  # `first` and the final `until` are known
        self.stopped = threading.Event()

    def run(self) -> None:
        conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{self.port}", source_system=249, dialect="ardupilotmega"
        )
        try:
            said = 0.0
            while not self.stopped.is_set():
                now = time.monotonic()
                if now - said >= 0.5:  # hello, and ask for the current step's state
                    conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # GCS, invalid autopilot
                    self._report(conn, 0)
                    if 0 <= self.step < self.until:
                        self._report(conn, self.step + 1)
                    said = now
                msg = conn.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=0.2)
                if msg is None or msg.get_srcSystem() != self.sysid:
                    continue
                k = msg.time_boot_ms / (self.dt * 1000)
                if abs(k - round(k)) > 1e-6 or round(k) <= self.step:
                    continue
                self.step = round(k)
                if self.first < 0:
                    self.until = max(self.until, self.step + self.span)
                    self.first = self.step
                    self.started.set()
                if self.step < self.until:
                    self._report(conn, self.step + 1)
        finally:
            conn.close()

    def _report(self, conn: mavutil.mavfile, step: int) -> None:
        conn.mav.command_long_send(self.sysid, 1, LOCKSTEP_COMMAND, 0, step, 0, 0, 0, 0, 0, 0)

    def stop(self) -> None:
        self.stopped.set()
        self.join(timeout=10)


class LinkProxy(threading.Thread):
    """A UDP relay between a companion (`port`, where it sends) and its vehicle (`vehicle_port`).

    `cut()` drops everything both ways until `restore()`.
    """

    def __init__(self, vehicle_port: int) -> None:
        super().__init__(daemon=True)
        self.inner = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.inner.bind(("127.0.0.1", 0))
        self.outer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.outer.bind(("127.0.0.1", 0))
        self.port = self.inner.getsockname()[1]
        self.vehicle = ("127.0.0.1", vehicle_port)
        self.companion: tuple[str, int] | None = None
        self.is_cut = threading.Event()
        self.stopped = threading.Event()
        self.dropped = 0

    def run(self) -> None:
        with selectors.DefaultSelector() as sel:
            sel.register(self.inner, selectors.EVENT_READ)
            sel.register(self.outer, selectors.EVENT_READ)
            while not self.stopped.is_set():
                for key, _ in sel.select(0.2):
                    sock = key.fileobj
                    assert isinstance(sock, socket.socket)
                    try:
                        data, addr = sock.recvfrom(65535)
                    except OSError:
                        continue
                    if sock is self.inner:
                        self.companion = addr
                    if self.is_cut.is_set():
                        self.dropped += 1
                        continue
                    with contextlib.suppress(OSError):
                        if sock is self.inner:
                            self.outer.sendto(data, self.vehicle)
                        elif self.companion is not None:
                            self.inner.sendto(data, self.companion)

    def cut(self) -> None:
        self.is_cut.set()

    def restore(self) -> None:
        self.is_cut.clear()

    def stop(self) -> None:
        self.stopped.set()
        self.join(timeout=5)
        self.inner.close()
        self.outer.close()
