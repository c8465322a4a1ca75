"""The simulated downward camera: ground truth, detections, and their publication over Zenoh.

Targets are drawn exactly as the batch engine draws them for run 0 of the seed, so a simulated
mission and its batch twin search for the same targets. Ground truth leaves the simulator only in
the evaluation record (`truth_record`).
"""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import numpy as np

from companion.contracts import detections
from companion.contracts.frames import LocalFrame
from companion.contracts.keys import SwarmKeys
from companion.contracts.mission import Mission
from companion.core.geometry import Grid
from companion.core.prior import draw_targets
from companion.core.sensing import reported_cells, sensor_model
from companion.core.world import Stream, build_grid, build_prior, instance_rng

LOOPBACK_PREFIXES = (
    "tcp/127.0.0.1:",
    "tls/127.0.0.1:",
    "udp/127.0.0.1:",
    "tcp/localhost:",
    "tls/localhost:",
    "unixsock-stream/",
)


def draw_truth(mission: Mission, seed: int) -> tuple[Grid, np.ndarray]:
    """The search grid and the ground-truth target cells of run 0 of `seed`."""
    grid = build_grid(mission)
    prior = build_prior(mission, grid)
    return grid, draw_targets(prior, mission.prior.targets, instance_rng(seed, 0, Stream.TARGETS))


class TruthTarget(msgspec.Struct, frozen=True):
    """One ground-truth target: its cell, local position (m) and lat/lon."""

    cell: int
    x: float
    y: float
    lat: float
    lon: float


class TruthRecord(msgspec.Struct, frozen=True):
    """truth.json: the ground-truth targets of run 0 of a mission and seed (what runs are scored on)."""

    mission: str
    seed: int
    run: int
    targets: list[TruthTarget]


def truth_record(
    mission: Mission, seed: int, grid: Grid, targets: np.ndarray, frame: LocalFrame
) -> TruthRecord:
    """The evaluation record: every target's cell, local position and lat/lon."""
    rows = []
    lat, lon = frame.cells_to_geodetic(grid.centres[targets])
    for k, cell in enumerate(targets.tolist()):
        x, y = grid.centres[cell].tolist()
        rows.append(TruthTarget(cell, x, y, float(lat[k]), float(lon[k])))
    return TruthRecord(mission.name, seed, 0, rows)


def write_truth(path: Path, record: TruthRecord) -> None:
    """Write truth.json atomically (a reader never sees half of it)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(msgspec.to_builtins(record), indent=1), encoding="utf-8")
    tmp.replace(path)


class Camera:
    """Detections of one exposure: the cells in view the detector reports (`core.sensing`).

    A perfect sensor (the paper's) reports every target cell whose centre is within the sensor
    radius. An imperfect one draws each look at each cell in view from (seed, run 0, vehicle,
    sampling step, cell), as the batch engine does (`sensing.reported_cells`): an exposure at
    simulated time t is the look of step floor(t / dT). `frame` builds the CameraFrame of an
    exposure (the bundled simulator's camera and the stand-alone camera both publish these).
    """

    def __init__(
        self, mission: Mission, grid: Grid, targets: np.ndarray, seed: int, frame: LocalFrame
    ) -> None:
        self.cell_lat, self.cell_lon = frame.cells_to_geodetic(grid.centres)
        self.grid, self.seed = grid, seed
        self.holds_target = np.zeros(grid.n_cells, dtype=bool)
        self.holds_target[targets] = True
        self.targets = targets
        self.target_xy = grid.centres[targets]
        self.r2 = grid.fov_radius2  # the batch engine's test
        s = mission.sensor
        self.model = sensor_model(s.pd, s.pd_edge, s.pf, s.radius)
        self.step_usec = round(mission.kinematics.step * 1e6)

    def detect(self, uav: int, time_usec: int, x: float, y: float) -> np.ndarray:
        """Indices of the cells reported as holding a target at vehicle `uav`'s exposure."""
        if self.model.perfect:
            d2 = np.sum((self.target_xy - (x, y)) ** 2, axis=1)
            return self.targets[d2 <= self.r2]
        cells = self.grid.fov_cell_list((x, y))
        look = (self.seed, 0, uav, time_usec // self.step_usec)
        return reported_cells(self.grid.centres, cells, self.holds_target, self.model, look, (x, y))

    def frame(
        self,
        uav: int,
        time_usec: int,
        xy: tuple[float, float],
        geo: tuple[float, float, float],
        heading: float,
    ) -> detections.CameraFrame:
        """The frame of vehicle `uav`'s exposure at local `xy` = geodetic `geo`.

        The frame of vehicle `uav`'s exposure at local `xy` = geodetic `geo` (lat, lon, alt AMSL)
        with `heading` (the core's convention)."""
        cells = self.detect(uav, time_usec, *xy)
        found = tuple(zip(self.cell_lat[cells].tolist(), self.cell_lon[cells].tolist(), strict=True))
        lat, lon, alt = geo
        return detections.CameraFrame(
            uav=uav, time_usec=time_usec, lat=lat, lon=lon, alt=alt, heading=heading, detections=found
        )


def check_loopback(endpoint: str) -> str:
    """The endpoint itself if it is a loopback Zenoh endpoint, else ValueError."""
    if not endpoint.startswith(LOOPBACK_PREFIXES):
        raise ValueError(f"not a loopback Zenoh endpoint: {endpoint}")
    return endpoint


class CameraBus:
    """A Zenoh session publishing every vehicle's camera frames on its key."""

    def __init__(
        self, mission: Mission, listen: list[str], connect: list[str], keys: SwarmKeys | None = None
    ) -> None:
        """`keys`: the camera's own (`keys.for_mission(mission, "camera")`) for a secured mesh."""
        import zenoh  # only simulations with a camera pay for it

        from companion.contracts.zenoh_config import MeshSecurity, client_config, peer_config

        security = None if keys is None else MeshSecurity.of(keys, mission)
        connect_to = tuple(check_loopback(e) for e in connect)
        if mission.mesh.mode == "peer":
            cfg = peer_config(tuple(check_loopback(e) for e in listen), connect_to, security)
        else:
            cfg = client_config(connect_to, mission.mesh.connect_timeout, security)
        self.session = zenoh.open(cfg)
        prefix, name = mission.mesh.key_prefix, mission.name
        self.publishers = [
            self.session.declare_publisher(detections.camera_key(prefix, name, i))
            for i in range(mission.n_uavs)
        ]

    def publish(self, frame: detections.CameraFrame) -> None:
        """Put `frame` on its UAV's camera key."""
        self.publishers[frame.uav].put(detections.encode(frame))

    def close(self) -> None:
        """Undeclare the publishers and close the session."""
        for p in self.publishers:
            p.undeclare()
        self.session.close()
