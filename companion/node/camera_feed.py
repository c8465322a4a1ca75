"""The companion's view of its own camera: CameraFrames from the vehicle's Zenoh key.

Frames come from the bundled simulator's camera or from a real detector publishing the same
message (`companion.contracts.detections`). Malformed frames, and frames of another vehicle, are dropped and
counted. The companion learns about targets only from here, never from ground truth.
"""

from __future__ import annotations

import threading
from collections import deque

import zenoh

from companion.contracts import detections
from companion.contracts.frames import LocalFrame


class CameraFeed:
    """Subscribes to one vehicle's camera key and hands out detections by vehicle time."""

    def __init__(self, session: zenoh.Session, key: str, uav: int, n_uavs: int, frame: LocalFrame) -> None:
        self.uav, self.n_uavs, self.frame = uav, n_uavs, frame
        self.rejected = 0
        self.latest_usec = -1
        self._frames: deque[detections.CameraFrame] = deque(maxlen=4096)
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            frame = detections.decode(sample.payload.to_bytes())
            detections.check(frame, self.n_uavs)
        except detections.DetectionError:
            with self._cond:
                self.rejected += 1
            return
        if frame.uav != self.uav:
            with self._cond:
                self.rejected += 1
            return
        with self._cond:
            self._frames.append(frame)
            self.latest_usec = max(self.latest_usec, frame.time_usec)
            self._cond.notify_all()

    def wait_until(self, time_usec: int, timeout: float) -> bool:
        """Block until a frame at or after `time_usec` has arrived (lockstep); False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self.latest_usec >= time_usec, timeout)

    def take(self, until_usec: int) -> tuple[tuple[tuple[float, float], ...], int]:
        """Local (x, y) of every detection in the frames up to `until_usec`, and how many frames.

        Each frame is consumed once; no frame means the camera took no picture over the step."""
        out: list[tuple[float, float]] = []
        frames = 0
        with self._cond:
            while self._frames and self._frames[0].time_usec <= until_usec:
                frame = self._frames.popleft()
                out.extend(self.frame.to_local(lat, lon) for lat, lon in frame.detections)
                frames += 1
        return tuple(out), frames

    def close(self) -> None:
        self._sub.undeclare()
