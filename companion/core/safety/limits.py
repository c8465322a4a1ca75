"""What compatibility means for one mission (`Limits`): clearances, the fence, the candidates' shapes."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from companion.core.geometry import ConvexPolygon, FloatArray
from companion.core.kinematics import Kinematics
from companion.core.safety.expansion import expand_rows, loiter_centre
from companion.core.search_area import NO_KEEPOUT
from companion.core.trajectory import HEAD, Reach, Trajectory, expand, step_pose

TURN_SIDES = (1, -1)
KERNEL_CACHE = 512  # trajectories whose kernel rows a `Limits` keeps (`Limits.kernel_row`)


@dataclass(frozen=True)
class Limits:
    """What compatibility means for one mission.

    `separation`: the clearance two trajectories' chords must keep (R_s + buffer + both sagittas);
    `disk_separation`: the clearance a chord keeps from a disk (R_s + buffer + one sagitta);
    `link`: the largest tether length at a sampling moment (R_c - buffer);
    `fence_normals`, `fence_offsets`: the fence's half-planes, pulled in by the sagitta;
    `keepout`: the triangles inside the fence no trajectory enters (`search_area.keepout_pieces`);
    `fan_keepout`: those no spoke of a failsafe region's fan enters (`search_area.spokes_clear`).
    """

    reach: Reach
    horizon: int
    grid: bool
    speed: float
    dt: float
    cell: float
    separation: float
    disk_separation: float
    link: float
    fence_normals: FloatArray
    fence_offsets: FloatArray
    keepout: FloatArray
    fan_keepout: FloatArray
    # `kernel_row`'s cache, shared by the UAVs of a world (one trajectory is read by all of them):
    # by the object's id, its row and loiter entry, and the object itself
    _kernels: dict[int, tuple[tuple[float, ...], int]] = field(
        init=False, repr=False, compare=False, default_factory=dict
    )
    _kept: dict[int, Trajectory] = field(init=False, repr=False, compare=False, default_factory=dict)

    @classmethod
    def build(
        cls,
        kin: Kinematics,
        horizon: int,
        region: ConvexPolygon,
        r_s: float,
        r_c: float,
        margin: float,
        buffer: float,
    ) -> Limits:
        """The limits of a mission's kinematics, horizon, region, R_s, R_c, margin and buffer.

        With no keep-out: `build_safety` adds the mission's (`with_keepout`)."""
        reach = Reach.of(kin, horizon)
        sag = reach.sagitta
        return cls(
            reach,
            horizon,
            kin.mode == "grid",
            kin.speed,
            kin.dt,
            kin.cell_size,
            r_s + buffer + 2 * sag,
            r_s + buffer + sag,
            r_c - buffer,
            np.ascontiguousarray(region.normals),
            region.offsets + margin - sag,
            NO_KEEPOUT,
            NO_KEEPOUT,
        )

    def with_keepout(self, keepout: FloatArray, fan_keepout: FloatArray) -> Limits:
        """A copy with the keep-out of paths and of fans' spokes (`search_area.keepout_pieces`)."""
        return replace(self, keepout=keepout, fan_keepout=fan_keepout)

    def expand(self, rows: FloatArray, first: int) -> FloatArray:
        """Positions of every trajectory row at steps first..first + window: (n, window + 1, 2)."""
        r = self.reach
        return expand_rows(rows, first, r.window, r.loiter_turn, self.grid, self.speed, self.dt, self.cell)

    def shapes(self, sequences: FloatArray) -> FloatArray:
        """Every candidate trajectory relative to its anchor, for each heading and loiter side.

        Every candidate trajectory relative to its anchor, for each loiter side (+1, -1):
        (headings, n_paths, 2, window + 1, 2). Grid mode keeps one table per 45-degree heading;
        continuous mode one for heading 0, which `feasible_sides` turns (eq. 2 turns with the
        heading it starts from)."""
        r = self.reach
        headings = np.arange(8) * math.pi / 4 if self.grid else np.zeros(1)
        out = np.empty((len(headings), len(sequences), 2, r.window + 1, 2))
        row = np.empty(HEAD + self.horizon)
        for h, heading in enumerate(headings):
            for i, seq in enumerate(sequences):
                for s, side in enumerate(TURN_SIDES):
                    row[:HEAD] = (0, 0.0, 0.0, heading, side)
                    row[HEAD:] = seq
                    out[h, i, s] = expand(row, 0, r.window, *self.kinematics_args)
        return out

    def rows(self, trajectories: list[Trajectory]) -> FloatArray:
        """The kernel rows of `trajectories` (`Trajectory.fields`)."""
        flat: list[float] = []
        for t in trajectories:
            flat += self.kernel_row(t)[0]
        return np.array(flat, dtype=float).reshape(-1, HEAD + self.horizon)

    def kernel_row(self, trajectory: Trajectory) -> tuple[tuple[float, ...], int]:
        """A trajectory's kernel row (`Trajectory.fields`) and loiter entry step, computed once.

        Kept by the object's id with the object itself, so that no other object can take the id
        while the entry lasts; the UAVs of a batch run share their messages' trajectories."""
        hit = self._kernels.get(id(trajectory))
        if hit is None:
            if len(self._kernels) >= KERNEL_CACHE:
                self._kernels.clear()
                self._kept.clear()
            hit = (trajectory.fields(self.horizon), trajectory.loiter_entry(self.reach.loiter_turn))
            self._kernels[id(trajectory)] = hit
            self._kept[id(trajectory)] = trajectory
        return hit

    def planned_path(self, trajectory: Trajectory) -> FloatArray:
        """Its positions from its anchor to the end of its M planned steps: (horizon + 1, 2)."""
        return self.expand(self.rows([trajectory]), trajectory.start)[0, : self.horizon + 1]

    def loiter_circle(self, trajectory: Trajectory) -> tuple[float, float, float]:
        """The circle (centre x, centre y, radius) of a trajectory's loiter.

        The circle (centre x, centre y, radius) of `trajectory`'s loiter: through its sampling points
        in continuous mode; in grid mode the loiter octagon's circumscribed circle (its vertices are
        concyclic: equal angles, alternating sides). The centre is the circumcentre of three
        consecutive loiter points, the radius the farthest of a whole loop's points from it."""
        r = self.reach
        row = self.rows([trajectory])[0]
        pts = expand(row, trajectory.start + self.horizon, r.period, *self.kinematics_args)
        ux, uy = loiter_centre(pts, 0)
        return ux, uy, float(np.max(np.hypot(pts[:, 0] - ux, pts[:, 1] - uy)))

    def shape_centres(self, shapes: FloatArray) -> FloatArray:
        """The loiter centre of every candidate of `shapes`, relative to its anchor.

        The loiter centre of every candidate of `shapes` (`Limits.shapes`) relative to its anchor:
        (headings, n_paths, 2 sides, 2)."""
        out = np.empty((*shapes.shape[:3], 2))
        for index in np.ndindex(*shapes.shape[:3]):
            out[index] = loiter_centre(shapes[index], self.horizon)
        return out

    def track(self, trajectory: Trajectory) -> tuple[tuple[tuple[float, float], ...], tuple[float, ...]]:
        """The first M points of `trajectory` (from its anchor on) and the heading at each (eq. 2)."""
        x, y, h = trajectory.x, trajectory.y, trajectory.heading
        points, headings = [], []
        for i in range(self.horizon):
            points.append((x, y))
            headings.append(h)
            turn = trajectory.turn_at(trajectory.start + i, self.reach.loiter_turn)
            x, y, h = step_pose(x, y, h, turn, self.grid, self.speed, self.dt, self.cell)
        return tuple(points), tuple(headings)

    @property
    def kinematics_args(self) -> tuple[float, bool, float, float, float]:
        """The kinematics arguments of eq. 2 (loiter turn, grid, speed, dt, cell)."""
        return self.reach.loiter_turn, self.grid, self.speed, self.dt, self.cell

    @property
    def clearances(self) -> tuple[float, float, float]:
        """(separation, disk_separation, link), the trailing arguments of `compatible`."""
        return self.separation, self.disk_separation, self.link
