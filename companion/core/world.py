"""Everything an agent derives from the mission before the first step: grid, prior, tasks, weights.

A `World` is immutable and a pure function of (mission, seed, run index): every companion of a
mission computes the same one, and the batch engine builds it once per run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import IntEnum

import numpy as np

from companion.contracts.mission import Mission
from companion.core.cvt import Tessellation, lloyd_cvt, onto_flyable
from companion.core.geometry import BoolArray, ConvexPolygon, FloatArray, Grid
from companion.core.kinematics import Kinematics, PathTree
from companion.core.prior import prior_map
from companion.core.routes import open_nodes, route_table
from companion.core.safety.limits import Limits
from companion.core.safety.start import initial_trajectories, tether_tree
from companion.core.search_area import cell_mask, flyable_cells, keepout_pieces, plain, region_hull
from companion.core.sensing import SensorModel, sensor_model
from companion.core.tasks import CostWeights
from companion.core.trajectory import Trajectory


class Stream(IntEnum):
    """Independent random streams of one mission instance."""

    CVT = 0
    TARGETS = 1
    RADIO = 2


def instance_rng(seed: int, run: int, stream: Stream) -> np.random.Generator:
    """The generator of one random stream of run `run` of seed `seed` (independent of any batch)."""
    return np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(run, int(stream))))


@dataclass(frozen=True)
class World:
    mission: Mission
    grid: Grid
    prior: FloatArray
    kinematics: Kinematics
    paths: PathTree
    tessellation: Tessellation | None
    costs: CostWeights
    safety: SafetyPlan
    sensor: SensorModel

    @property
    def n_uavs(self) -> int:
        return self.mission.n_uavs


def build_grid(mission: Mission) -> Grid:
    """The grid's cells over the region's hull: those in the region and outside every no-fly zone."""
    return Grid.build(
        region_hull(mission),
        mission.region.cell_size,
        mission.sensor.radius,
        lambda x, y: cell_mask(mission, x, y),
    )


def build_prior(mission: Mission, grid: Grid) -> FloatArray:
    centres = [(c.x, c.y, c.peak, c.sigma) for c in mission.prior.centres]
    return prior_map(grid.centres, centres, mission.prior.sigma)


def build_kinematics(mission: Mission) -> Kinematics:
    k = mission.kinematics
    cell = float(mission.region.cell_size)
    return Kinematics(k.mode, k.speed, k.step, math.radians(k.turn_limit_deg), cell)


@dataclass(frozen=True)
class SafetyPlan:
    """The safety layer's common knowledge (core.safety).

    What compatibility means, every UAV's start contingency, the tether tree of the start layout, how
    far a silent UAV's aircraft may stray from the centre of its committed loiter once its failsafe
    circles it, and from its path before the failsafe fires.
    """

    limits: Limits
    start: tuple[Trajectory, ...]
    ranks: tuple[int, ...]
    parents: tuple[int, ...]
    failsafe_reach: float
    failsafe_stray: float
    shapes: FloatArray  # `Limits.shapes` of the mission's paths (eq. 23)
    centres: FloatArray  # their loiter centres (`Limits.shape_centres`)
    near: BoolArray  # (n, n): the pairs whose layers are closer than the vertical separation

    @property
    def loiter_radius(self) -> float:
        """The radius of every trajectory's loiter circle (`Limits.loiter_circle`)."""
        return self.limits.loiter_circle(self.start[0])[2]


FAILSAFE_WIDE = 1.4  # ArduPlane flies a loiter circle this much wider than asked, at most (measured)


def failsafe_reach(mission: Mission, limits: Limits) -> float:
    """Default `safety.failsafe_reach`: how far a silent UAV's aircraft may be from its loiter's centre.

    That is, how far from the centre of its committed loiter the aircraft of a UAV whose companion fell
    silent can be once its failsafe circles that loiter (companion.node.failsafe): the circle flown up
    to `FAILSAFE_WIDE` times wider than asked (ArduPlane SITL flew 93 m for 76 m asked, 69 m for 51
    m), plus a turn radius for arriving on it off its tangent.
    """
    k = mission.kinematics
    turn_radius = k.speed * k.step / math.radians(k.turn_limit_deg)
    radius = limits.loiter_circle(Trajectory(0, 0.0, 0.0, 0.0, (), 1))[2]
    return FAILSAFE_WIDE * radius + turn_radius


FAILSAFE_CHECK_S = 1 / 3  # ArduPlane checks its GCS failsafe at 3 Hz (ArduPlane/events.cpp)


def failsafe_stray(mission: Mission, limits: Limits) -> float:
    """How far from its trajectory's path a silent UAV's aircraft may be when its failsafe fires.

    The aircraft of a UAV whose companion fell silent holds its last command for up to tau =
    `Mission.failsafe_seconds` plus one failsafe check instead of the plan's next turns. Two eq. 2
    paths from one pose whose turn rates differ by up to 2 omega_max part by at most
    2 R (1 - cos omega_max tau) <= v omega_max tau^2 (R = v / omega_max), and neither leaves v tau of
    that pose.
    """
    tau = mission.failsafe_seconds + FAILSAFE_CHECK_S
    dt = float(mission.kinematics.step)
    speed, rate = limits.reach.step / dt, limits.reach.loiter_turn / dt
    return min(speed * rate * tau**2, speed * tau)


def with_keepout(
    mission: Mission, limits: Limits, region: ConvexPolygon, reach: float, stray: float
) -> Limits:
    """`limits` with the mission's keep-out (docs/algorithm.md, "No-fly zones").

    Paths keep out of the region's notches beyond the margin and of every zone inflated by the
    margin, the sagitta and the failsafe's stray; the spokes of their fans (`spokes_clear`) keep out
    of every zone inflated by the margin, the stray and the failsafe's reach, so that a silent UAV's
    aircraft, anywhere in its failsafe region, stays out of the zone inflated by the margin.
    """
    margin, sag = mission.safety.margin, limits.reach.sagitta
    paths = keepout_pieces(mission, region, margin - sag, margin + sag + stray)
    fans = keepout_pieces(mission, region, margin - sag, margin + stray + reach, notches=False)
    return limits.with_keepout(paths, fans)


def build_safety(
    mission: Mission, kin: Kinematics, region: ConvexPolygon, sequences: FloatArray
) -> SafetyPlan:
    c, s = mission.comms, mission.safety
    limits = Limits.build(
        kin,
        mission.algorithm.horizon,
        region,
        c.safety,
        c.range,
        s.margin,
        s.buffer,
    )
    reach = s.failsafe_reach if s.failsafe_reach is not None else failsafe_reach(mission, limits)
    stray = failsafe_stray(mission, limits)
    limits = with_keepout(mission, limits, region, reach, stray)
    poses = np.array([(v.x, v.y, math.radians(v.heading_deg)) for v in mission.vehicles], dtype=float)
    ranks, parents = tether_tree(poses[:, :2], limits.link)
    start = tuple(initial_trajectories(poses, parents, ranks, limits))  # ValueError: no contingency
    shapes = limits.shapes(sequences)
    near = np.array(mission.near_layers(), dtype=bool).reshape(len(poses), len(poses))
    return SafetyPlan(
        limits, start, ranks, parents, reach, stray, shapes, limits.shape_centres(shapes), near
    )


def build_world(mission: Mission, seed: int | None = None, run: int = 0) -> World:
    """Grid, prior (eq. 1), kinematics (eq. 2), and for the proposed algorithm the CVT (Alg. 1)."""
    seed = mission.seed if seed is None else seed
    grid = build_grid(mission)
    prior = build_prior(mission, grid)
    kin = build_kinematics(mission)
    a = mission.algorithm
    c = mission.comms
    costs = CostWeights(
        beta1=a.beta[0],
        beta2=a.beta[1],
        kappa=a.kappa,
        fov_area=math.pi * mission.sensor.radius**2,
        diagonal=grid.diagonal,
        r_c=c.range,
        r_c_attr=c.attraction,
        comm_cap=a.comm_cost_cap,
    )
    paths = PathTree.build(kin, a.horizon)
    safety = build_safety(mission, kin, grid.region, paths.sequences)
    tess = None
    if a.name == "proposed":
        tess = lloyd_cvt(
            grid.centres,
            prior,
            a.n_g,
            instance_rng(seed, run, Stream.CVT),
            grid.cell_area,
            a.lloyd_tolerance,
            a.lloyd_max_iterations,
        )
        if not plain(mission):
            lim = safety.limits
            flyable = flyable_cells(grid, (lim.keepout, lim.fan_keepout))
            tess = onto_flyable(tess, grid.centres, flyable, mission.sensor.radius)
            open_ = open_nodes(grid, lim.fence_normals, lim.fence_offsets, lim.keepout)
            tess = replace(tess, routes=route_table(grid, tess.generators, open_))
    sensor = sensor_model(mission.sensor.pd, mission.sensor.pd_edge, mission.sensor.pf, mission.sensor.radius)
    return World(mission, grid, prior, kin, paths, tess, costs, safety, sensor)
