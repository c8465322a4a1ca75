"""A stand-alone simulated camera for vehicles the simulator does not host (ArduPlane SITL, ...).

It reads each vehicle's position over MAVLink (one link per vehicle, e.g. SITL's SERIAL0) and, at
`sim.camera_hz` of each vehicle's own time, publishes that vehicle's CameraFrame on its Zenoh camera
key with the detections of the mission's ground truth, built by the bundled simulator's camera
(`camera.Camera.frame`): a flight on external vehicles is searched and scored like a bundled one.
The ground truth leaves only through `--truth FILE`. Usage: docs/companion.md, "The stand-alone camera".

With `--approach FILE` it also keeps the simulator's separation record (`sim_vehicles.approach`)
for these vehicles: every position sample (GLOBAL_POSITION_INT, POSITION_HZ per vehicle) updates
every pair's closest approach with each vehicle's latest position (once it has a 3D GPS fix), at
the newest vehicle time seen.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.arguments import mission_argument, natural
from companion.contracts.frames import LocalFrame
from companion.contracts.keys import for_mission, mavlink_secrets
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.node.vehicle_link import LinkError, VehicleLink, open_link
from sim_vehicles import camera as cam
from sim_vehicles.approach import ApproachRecorder

log = logging.getLogger("camera")

CONNECT_TIMEOUT_S = 120.0
POSITION_HZ = 10.0
# The main thread wakes this often while it waits: a SIGTERM that the kernel hands to another thread
# (Zenoh's or a vehicle's) only flags Python's handler, which runs when the main thread runs Python.
SIGNAL_POLL_S = 0.2


class LatestPositions:
    """Every vehicle's latest position (and height above home), fed by the per-vehicle threads.

    Each sample updates the closest-approach record with all of them, once every vehicle has a
    position.

    The vehicles' clocks (separate autopilots) need not agree: the record's steps follow the newest
    vehicle time seen, and a pair's distance is that of the two latest samples, which are at most
    1 / POSITION_HZ apart (plus the links' latencies).
    """

    def __init__(self, recorder: ApproachRecorder, n: int) -> None:
        self.recorder = recorder
        self.x, self.y, self.z = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
        self.t = -np.inf
        self._lock = threading.Lock()

    def sample(self, uav: int, t: float, x: float, y: float, z: float = math.nan) -> None:
        """Vehicle `uav`'s position at its time `t`: local x, y and height above home z (m).

        Homes are at the origin's altitude, so heights compare.
        """
        with self._lock:
            self.x[uav], self.y[uav], self.z[uav], self.t = x, y, z, max(self.t, t)
            if np.isfinite(self.x).all():
                z_all = self.z if np.isfinite(self.z).all() else None
                self.recorder.update(self.t, self.x, self.y, z_all)


class CameraNode:
    """Every vehicle's camera, one thread per vehicle link."""

    def __init__(
        self,
        mission: Mission,
        urls: list[str],
        seed: int,
        bus: cam.CameraBus,
        signing_secrets: list[bytes] | None = None,
        positions: LatestPositions | None = None,
    ) -> None:
        """The camera for `mission`'s vehicles at `urls`, with its own seeded truth and detector.

        `signing_secrets`: give each vehicle its MAVLink signing secret once connected
        (`--setup-signing`: SITL on loopback, whose SERIAL0 is its USB port); `positions`: where the
        position streams go for the separation record.
        """
        if len(urls) != mission.n_uavs:
            raise ValueError(f"--vehicles: {len(urls)} links for the mission's {mission.n_uavs} vehicles")
        self.mission, self.urls, self.bus = mission, urls, bus
        self.signing_secrets, self.positions = signing_secrets, positions
        self.frame = LocalFrame(mission.region.origin)
        self.grid, self.targets = cam.draw_truth(mission, seed)
        self.camera = cam.Camera(mission, self.grid, self.targets, seed, self.frame)
        self.published = 0
        self.errors: list[str] = []
        self._lock = threading.Lock()

    def run(self, stop: threading.Event) -> None:
        threads = [
            threading.Thread(target=self._vehicle, args=(i, url, stop), daemon=True)
            for i, url in enumerate(self.urls)
        ]
        for t in threads:
            t.start()
        for t in threads:
            while t.is_alive():
                t.join(SIGNAL_POLL_S)

    def _vehicle(self, uav: int, url: str, stop: threading.Event) -> None:
        try:  # retried while the vehicle is not listening yet (SITL starting up)
            link = open_link(
                url, self.frame, CONNECT_TIMEOUT_S, stop.is_set, component=mavlink.MAV_COMP_ID_CAMERA
            )
        except LinkError as exc:
            self._failed(uav, url, exc, stop)
            return
        if link is None:
            return
        try:
            try:
                heard = link.wait_heartbeat(CONNECT_TIMEOUT_S, stop.is_set)
            except (OSError, LinkError) as exc:
                self._failed(uav, url, exc, stop)
                return
            if heard:
                self._frames(uav, url, link, stop)
        finally:
            link.close()

    def _failed(self, uav: int, url: str, exc: Exception, stop: threading.Event) -> None:
        self.errors.append(f"vehicle {uav} at {url}: {exc}")
        stop.set()

    def _frames(self, uav: int, url: str, link: VehicleLink, stop: threading.Event) -> None:
        """Publish the camera's frames of vehicle `uav` until `stop`."""
        if self.signing_secrets is not None:
            link.signing.provision(self.signing_secrets[uav])
        link.request_streams({mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: POSITION_HZ})
        signed = ", MAVLink signing set up" if self.signing_secrets is not None else ""
        print(f"camera: vehicle {uav} up at {url}{signed}", flush=True)
        period = 1.0 / self.mission.sim.camera_hz
        s, alt0 = link.state, self.mission.region.origin.alt
        next_t, beat, sampled = -1.0, 0.0, -1.0
        while not stop.is_set():
            link.poll(0.1)
            if time.monotonic() - beat >= 1.0:
                link.send_heartbeat()
                beat = time.monotonic()
            if self.positions is not None and s.has_pose and s.gps_fix >= 3 and s.time_s != sampled:
                self.positions.sample(uav, s.time_s, s.x, s.y, s.up)
                sampled = s.time_s
            if not s.has_pose or s.time_s < next_t:
                continue
            lat, lon, _ = self.frame.to_geodetic(s.x, s.y)
            usec, geo = round(s.time_s * 1e6), (lat, lon, alt0 + s.up)
            with self._lock:
                self.bus.publish(self.camera.frame(uav, usec, (s.x, s.y), geo, s.heading))
                self.published += 1
            next_t = (int(s.time_s / period) + 1) * period


def add_arguments(parser: argparse.ArgumentParser) -> None:
    mission_argument(parser, type=Path)
    parser.add_argument(
        "--vehicles", required=True, help="pymavlink URLs of the vehicles, comma-separated (required)"
    )
    parser.add_argument("--seed", type=natural, default=None, help="target seed (default: the mission's)")
    parser.add_argument(
        "--truth", type=Path, default=None, help="write the ground truth (JSON) here (default: not written)"
    )
    parser.add_argument(
        "--approach",
        type=Path,
        default=None,
        help="write every pair's closest approach per step, from the position streams (CSV; default: not "
        "written)",
    )
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="loopback Zenoh listen endpoint (default: tcp/127.0.0.1:0)",
    )
    parser.add_argument(
        "--zenoh-connect", action="append", default=None, metavar="ENDPOINT",
        help="loopback Zenoh endpoint to connect to (default: the mission's mesh)",
    )  # fmt: skip
    parser.add_argument(
        "--setup-signing",
        action="store_true",
        help="give each vehicle its MAVLink signing secret from the mission's keys (SETUP_SIGNING: "
        "only over links that cannot be overheard, e.g. SITL's SERIAL0 on loopback)",
    )


def run(args: argparse.Namespace) -> int:
    """Publish frames until SIGINT/SIGTERM; 0 on a clean stop, 1 if a vehicle failed, 2 on bad input."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    mission = load_mission(args.mission)
    seed = mission.seed if args.seed is None else args.seed
    mesh = mission.mesh
    connect = args.zenoh_connect or [mesh.seed_endpoint if mesh.mode == "peer" else mesh.router]
    urls = [u.strip() for u in args.vehicles.split(",") if u.strip()]
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        keys = for_mission(mission, "camera")
        bus = cam.CameraBus(mission, args.zenoh_listen or ["tcp/127.0.0.1:0"], connect, keys)
    except ValueError as exc:  # KeyDirectoryError too
        print(f"error: {exc}", file=sys.stderr)
        return 2
    recorder = None
    try:
        signing = mavlink_secrets(mission) if args.setup_signing else None
        positions = None
        if args.approach is not None:
            k = mission.kinematics
            recorder = ApproachRecorder(
                args.approach, mission.n_uavs, k.step, 3 * mission.comms.safety, mission.comms.safety
            )
            positions = LatestPositions(recorder, mission.n_uavs)
        node = CameraNode(mission, urls, seed, bus, signing, positions)
        if args.truth is not None:
            cam.write_truth(args.truth, cam.truth_record(mission, seed, node.grid, node.targets, node.frame))
        print(f"camera: mission {mission.name}, {len(urls)} vehicles, seed {seed}", flush=True)
        node.run(stop)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        bus.close()
        if recorder is not None:
            recorder.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    for error in node.errors:
        print(f"error: {error}", file=sys.stderr)
    print(f"camera: {node.published} frames published", flush=True)
    return 1 if node.errors else 0
