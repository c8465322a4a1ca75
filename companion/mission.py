"""Mission files: TOML validated into typed, immutable objects.

One mission file drives the batch engine, the simulator and the companions. Every user error
(syntax, a missing or mistyped field, an inconsistent value) is raised as `MissionError`, which
names the file, the field and the reason.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal, get_args

import msgspec
import msgspec.inspect
import numpy as np

if TYPE_CHECKING:
    from companion.core.geometry import ConvexPolygon

ALGORITHMS = ("proposed", "no-ta", "pheromone")

# Sizes a mission may ask for, so that no file makes a process hang or allocate what a machine cannot
# hold (docs/mission-files.md, "Limits"): 40 times the paper's 2,500 cells on a side-by-side
# lattice, a sensor footprint of at most ~1,000 cells, and the CVT's work bounded.
MAX_FILE_BYTES = 1 << 20
MAX_GRID_CELLS = 250_000  # the lattice over the region's bounding box
MAX_FOV_CELLS = 1_000  # the FOV stencil (eq. 3) in cells
MAX_FOV_TABLE = 20_000_000  # grid cells x FOV stencil: the per-cell FOV table's entries
MAX_CVT_WORK = 50_000_000  # grid cells x n_g: one Lloyd iteration's distances
MAX_VEHICLES = 64
MAX_VERTICES = 256
MAX_CENTRES = 1_000
MAX_STEPS = 1_000_000
# What the kinematics imply (checked before any trajectory is expanded): a loiter circle closes in at
# most MAX_LOITER_STEPS steps (the safety layer compares whole loiters, pairwise), the M-step turn
# lattice has at most MAX_LATTICE rows, a trajectory reaches at most MAX_REACH_M from where it starts
# (and a failsafe region or operating margin is no wider), and every UAV's recorded path fits.
MAX_SPEED = 1_000.0  # m/s
MAX_STEP_S = 3_600.0  # s per sampling step
MAX_LOITER_STEPS = 720  # continuous mode: turn_limit_deg >= 0.5
MAX_LATTICE = 9**6  # turn options ^ horizon: grid mode's largest (180 degrees, M = 6)
MAX_REACH_M = 100_000.0
MIN_STEP_M = 0.01  # continuous mode: the distance flown per step (a loiter of no size has no centre)
MAX_PHYSICS_HZ = 1_000.0
MAX_PATH_POINTS = 10_000_000  # steps x vehicles: the poses a run records
Mode = Literal["grid", "continuous"]  # the kinematics: the paper's 8-neighbour grid, or turn-rate limited
MODES: tuple[str, ...] = get_args(Mode)

Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]
Probability = Annotated[float, msgspec.Meta(ge=0, le=1)]
Port = Annotated[int, msgspec.Meta(ge=1, le=65535)]
# Altitude layers (docs/algorithm.md, "Separation in three dimensions"; the separation's evidence:
# docs/companion.md, "Altitude keeping")
DEFAULT_VERTICAL_SEPARATION = 20.0
DEFAULT_BAND = 60.0
ALTITUDE_KEEPING = 5.0  # m: the most one aircraft strays from its layer (measured at most 3.11 m)


class MissionError(ValueError):
    """A mission file is unusable: names the file, the field and the reason."""

    def __init__(self, source: str, field: str, reason: str) -> None:
        self.source, self.field, self.reason = source, field, reason
        super().__init__(f"{source}: {field}: {reason}")


class _Base(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    pass


class Origin(_Base, kw_only=True):
    """Geodetic origin of the local frame (x east, y north, metres)."""

    lat: Annotated[float, msgspec.Meta(ge=-90, le=90)]
    lon: Annotated[float, msgspec.Meta(ge=-180, le=180)]
    alt: float = 0.0


class Region(_Base, kw_only=True):
    """Convex search polygon in local metres and the cell size of the search grid."""

    polygon: Annotated[list[tuple[float, float]], msgspec.Meta(max_length=MAX_VERTICES)]
    cell_size: Positive
    origin: Origin


class Centre(_Base, kw_only=True):
    """A distribution centre of eq. 1; `peak` is Pr_{p,z} at the centre (K_z / (sqrt(2 pi) sigma));
    `sigma` is this centre's spread (default: the prior's `sigma`)."""

    x: float
    y: float
    peak: Annotated[float, msgspec.Meta(gt=0, le=1)]
    sigma: Positive | None = None


class Prior(_Base, kw_only=True):
    sigma: Positive
    centres: Annotated[list[Centre], msgspec.Meta(max_length=MAX_CENTRES)]
    targets: Annotated[int, msgspec.Meta(ge=0)]


class Sensor(_Base, kw_only=True):
    """Downward camera: FOV radius R_A (eq. 3) and detector error rates (simulator only)."""

    radius: Positive
    false_alarm: Probability = 0.0
    miss: Probability = 0.0


class Kinematics(_Base, kw_only=True):
    """Eq. 2: constant speed, turn limited to turn_limit_deg per sampling step dT.

    `altitude`: the lowest altitude layer, metres above the origin (`Layers` adds the others).
    """

    mode: Mode = "grid"
    speed: Positive
    step: Positive
    turn_limit_deg: Annotated[float, msgspec.Meta(gt=0, le=180)]
    altitude: float = 100.0


class Layers(_Base, kw_only=True):
    """Altitude layers (docs/algorithm.md, "Separation in three dimensions").

    The layers lie in the band [kinematics.altitude, kinematics.altitude + `band`], evenly spaced
    and at least `separation` metres apart: `count` of them (default: one a UAV, as many as fit).
    Two UAVs whose layers are `separation` or more apart cannot meet, so the failure cases of the
    safety layer (a dead companion, a partition, the hand-over) are guarded only between UAVs on
    closer layers. `count = 1` flies everyone on one layer.
    """

    band: NonNegative = DEFAULT_BAND
    separation: Positive = DEFAULT_VERTICAL_SEPARATION
    count: Annotated[int, msgspec.Meta(ge=1, le=MAX_VEHICLES)] | None = None


class Comms(_Base, kw_only=True):
    """Ranges of eqs. 5, 17, 28: R_s < R'_s < R'_c < R_c."""

    range: Positive
    attraction: Positive
    safety: Positive
    repulsion: Positive
    loss: Probability = 0.0
    peer_timeout_steps: Annotated[int, msgspec.Meta(ge=1)] = 5


class Safety(_Base, kw_only=True):
    """The safety layer (docs/algorithm.md, "Safety layer").

    `margin`: the operating margin (m): the fence is the region with every edge pushed out by it;
    UAVs search inside the region and may turn outside it, never beyond the fence.
    `buffer`: metres added to R_s (and taken from R_c) in every check, for tracking error.
    `failsafe_timeout`: seconds without the companion's HEARTBEAT before the autopilot's failsafe
    makes the aircraft circle the loiter of its trajectory in force (the companion sets ArduPlane's
    FS_LONG_TIMEOUT to it; `companion.node.failsafe`); default one step (at least 1 s,
    `Mission.failsafe_seconds`). Until it fires the aircraft holds its last command, off its plan:
    the contingency clause covers that (`companion.core.world.failsafe_stray`), so the longer it
    is, the farther apart the UAVs keep.
    `failsafe_reach`: how far (m) from the centre of that loiter the aircraft of a UAV whose
    companion fell silent may be once circling (default: `companion.core.world.failsafe_reach`).
    `contingency`: every trajectory in force keeps clear of every other UAV's failsafe disk (the
    contingency clause), so that a companion that dies leaves an aircraft nobody comes near.
    """

    margin: NonNegative = 100.0
    buffer: NonNegative = 5.0
    failsafe_timeout: Annotated[float, msgspec.Meta(ge=1, le=300)] | None = None
    failsafe_reach: NonNegative | None = None
    contingency: bool = True


class Uncertainty(_Base, kw_only=True):
    """Eqs. 10-11: initial uncertainty eta_0 and decay gamma per look."""

    eta0: Annotated[float, msgspec.Meta(gt=0, le=1)] = 1.0
    gamma: Annotated[float, msgspec.Meta(ge=0, lt=1)] = 0.1


class Pheromone(_Base, kw_only=True):
    """Pheromone baseline: deposit from importance, evaporation, diffusion, attraction weight."""

    deposit: NonNegative = 1.0
    evaporation: Probability = 0.1
    diffusion: Probability = 0.2
    weight: NonNegative = 1.0


class Algorithm(_Base, kw_only=True):
    """Algorithm name and every weight of eqs. 16-29 and Algorithm 1. The weights the paper does not
    give are those `uavsearch tune` chose on 12 training missions (docs/results.md, "Held-out
    missions"; the pheromone's stayed: no candidate beat them)."""

    name: Literal["proposed", "no-ta", "pheromone"] = "proposed"
    n_g: Annotated[int, msgspec.Meta(ge=1)] = 50
    horizon: Annotated[int, msgspec.Meta(ge=1, le=6)] = 3
    beta: tuple[Positive, Positive] = (1.0, 1.107)
    chi: tuple[Positive, Positive] = (1.0, 2.188)
    delta: tuple[Positive, Positive] = (1.0, 0.1752)
    kappa: Positive = 2.647
    v_max: Probability = 0.7643
    c_max: Positive = 87.51
    comm_cost_cap: Positive = 0.6644
    lloyd_tolerance: Positive = 1.0
    lloyd_max_iterations: Annotated[int, msgspec.Meta(ge=1, le=10_000)] = 200
    pheromone: Pheromone = Pheromone()


class Vehicle(_Base, kw_only=True):
    """Start pose (heading counter-clockwise from east, degrees) and MAVLink UDP port."""

    x: float
    y: float
    heading_deg: float = 90.0
    mavlink_port: Port | None = None
    layer: Annotated[int, msgspec.Meta(ge=0)] | None = None  # its altitude layer (default: `assign_layers`)


class Sim(_Base, kw_only=True):
    """Simulator options: autopilot flavour, flight model, base UDP port, integration and camera rates.

    `dynamics` (continuous kinematics only; grid mode always flies eq. 2 exactly): "arduplane",
    bank-limited coordinated turns with a roll lag and ArduPlane's guidance laws, or "kinematic",
    eq. 2 with instant turns (see docs/simulator.md).
    """

    flavour: Literal["ardupilot", "px4"] = "ardupilot"
    dynamics: Literal["arduplane", "kinematic"] = "arduplane"
    host: str = "127.0.0.1"
    base_port: Port = 14560
    physics_hz: Annotated[float, msgspec.Meta(ge=50)] = 50.0
    camera_hz: Positive = 2.0
    guided_timeout: Positive = 3.0


class Mesh(_Base, kw_only=True):
    """Zenoh mesh: mode, key prefix and loopback endpoints (see docs/mesh.md).

    `listen` is where a peer that could not claim `seed_endpoint` listens (port 0: the OS picks);
    `connect_timeout` is how long a client waits for its router at start (seconds);
    `max_bundle_bytes` is the largest bundle a companion sends or accepts.
    """

    mode: Literal["peer", "client"] = "peer"
    key_prefix: str = "uavsearch"
    router: str = "tcp/127.0.0.1:7447"
    seed_endpoint: str = "tcp/127.0.0.1:7450"
    listen: str = "tcp/127.0.0.1:0"
    connect_timeout: Positive = 10.0
    max_bundle_bytes: Annotated[int, msgspec.Meta(ge=1024)] = 1 << 20


class NetworkFault(_Base, kw_only=True):
    """Injected mesh faults over the steps [start, end): the companions drop the messages between
    UAVs of different `groups` (a partition: UAVs in no group hear only themselves), and any other
    message with probability `loss` (docs/reliability.md, "Fault matrix")."""

    start: Annotated[int, msgspec.Meta(ge=0)]
    end: Annotated[int, msgspec.Meta(ge=1)]
    groups: Annotated[
        list[Annotated[list[Annotated[int, msgspec.Meta(ge=0)]], msgspec.Meta(max_length=MAX_VEHICLES)]],
        msgspec.Meta(max_length=MAX_VEHICLES),
    ] = []
    loss: Probability = 0.0


class Faults(_Base, kw_only=True):
    """Faults the companions inject into themselves (for the fault matrix)."""

    network: Annotated[list[NetworkFault], msgspec.Meta(max_length=1_000)] = []


class Security(_Base, kw_only=True):
    """Authentication (docs/reliability.md): `keys` is the key directory written by `uavsearch keys`
    (relative to the mission file); empty, the default, runs an insecure mesh and MAVLink link, and
    every process says so. `mavlink_signing`: with keys, sign the companion-autopilot link with each
    vehicle's secret (the bundled simulator then rejects unsigned commands)."""

    keys: str = ""
    mavlink_signing: bool = True


class PassCriteria(_Base, kw_only=True):
    """What a scripted mission must achieve to pass."""

    min_targets_found: Annotated[int, msgspec.Meta(ge=0)] = 0
    require_connected: bool = True
    require_safe_distance: bool = True


class Mission(_Base, kw_only=True):
    name: str
    seed: int = 1
    steps: Annotated[int, msgspec.Meta(ge=1, le=MAX_STEPS)] = 1000
    region: Region
    prior: Prior
    sensor: Sensor
    kinematics: Kinematics
    layers: Layers = Layers()
    comms: Comms
    safety: Safety = Safety()
    uncertainty: Uncertainty = Uncertainty()
    algorithm: Algorithm = Algorithm()
    vehicles: Annotated[list[Vehicle], msgspec.Meta(max_length=MAX_VEHICLES)]
    sim: Sim = Sim()
    mesh: Mesh = Mesh()
    faults: Faults = Faults()
    security: Security = Security()
    pass_criteria: PassCriteria = PassCriteria()

    @property
    def n_uavs(self) -> int:
        return len(self.vehicles)

    @property
    def layer_count(self) -> int:
        """How many altitude layers the band holds: `layers.count`, else one a UAV, as many as fit."""
        lay = self.layers
        if lay.count is not None:
            return lay.count
        return max(1, min(self.n_uavs, int(lay.band / lay.separation + 1e-9) + 1))

    def layer_altitude(self, layer: int) -> float:
        """The altitude above the origin of layer `layer`: the band's layers evenly spaced."""
        count = self.layer_count
        spacing = self.layers.band / (count - 1) if count > 1 else 0.0
        return self.kinematics.altitude + layer * spacing

    def layer_assignment(self) -> tuple[int, ...]:
        """Every vehicle's layer (`assign_layers`)."""
        starts = [(v.x, v.y) for v in self.vehicles]
        return assign_layers(starts, [v.layer for v in self.vehicles], self.layer_count)

    def altitude_of(self, index: int) -> float:
        """Vehicle `index`'s flight altitude above the origin: the altitude of its layer."""
        return self.layer_altitude(self.layer_assignment()[index])

    @property
    def vertical_floor(self) -> float:
        """The vertical distance two aircraft on layers `layers.separation` apart keep in flight,
        each within `ALTITUDE_KEEPING` of its layer: below it, a pair horizontally within R_s has
        lost separation in three dimensions."""
        return self.layers.separation - 2 * ALTITUDE_KEEPING

    def near_layers(self) -> list[list[bool]]:
        """Whether each pair of vehicles flies layers closer than `layers.separation` (a UAV is near
        itself): only such pairs can meet, so only they guard against each other's failures."""
        alts = [self.layer_altitude(layer) for layer in self.layer_assignment()]
        gap = self.layers.separation - 1e-6
        return [[abs(a - b) < gap for b in alts] for a in alts]

    def vehicle_port(self, index: int) -> int:
        """The UDP port of vehicle `index`: explicit in the file, else base_port + 10 * index."""
        port = self.vehicles[index].mavlink_port
        return port if port is not None else self.sim.base_port + 10 * index

    def with_algorithm(self, name: str | None = None, **weights: object) -> Mission:
        """A copy with another algorithm name and/or weights."""
        changes: dict[str, object] = dict(weights)
        if name is not None:
            changes["name"] = name
        return msgspec.structs.replace(self, algorithm=msgspec.structs.replace(self.algorithm, **changes))

    def with_seed(self, seed: int) -> Mission:
        return msgspec.structs.replace(self, seed=seed)

    @property
    def failsafe_seconds(self) -> float:
        """`safety.failsafe_timeout`, by default one step (ArduPlane's FS_LONG_TIMEOUT is at least 1 s)."""
        t = self.safety.failsafe_timeout
        return t if t is not None else max(1.0, float(self.kinematics.step))

    @property
    def secured(self) -> bool:
        """True when the mission names a key directory (an authenticated mesh and MAVLink link)."""
        return bool(self.security.keys)


def assign_layers(
    starts: list[tuple[float, float]], pinned: list[int | None], count: int
) -> tuple[int, ...]:
    """Each UAV's layer: a pinned one keeps its own; the others, in id order, take the layer whose
    nearest UAV at the start is farthest away (an empty layer first, then the fewest UAVs, then the
    lowest), so that UAVs sharing a layer start as far apart as the greedy choice makes them."""
    layers: list[int] = [p if p is not None else -1 for p in pinned]
    for i, p in enumerate(pinned):
        if p is not None:
            continue

        def key(layer: int, i: int = i) -> tuple[float, int, int]:
            members = [j for j, lj in enumerate(layers) if lj == layer]
            nearest = min((math.dist(starts[i], starts[j]) for j in members), default=math.inf)
            return (-nearest, len(members), layer)

        layers[i] = min(range(count), key=key)
    return tuple(layers)


_PATH_RE = re.compile(r" - at `\$(?P<path>[^`]*)`$")


def _field_from_msgspec(message: str) -> tuple[str, str]:
    """Split msgspec's 'reason - at `$.a.b[0]`' into ('a.b[0]', 'reason'); a value not among a
    field's choices gets the valid ones listed."""
    match = _PATH_RE.search(message)
    if not match:
        return "(document)", message
    field, reason = match.group("path").lstrip(".") or "(document)", message[: match.start()]
    if reason.startswith("Invalid enum value"):
        choices = _choices(field)
        if choices:
            reason += f" (one of {', '.join(repr(c) for c in choices)})"
    return field, reason


def _choices(field: str) -> tuple[object, ...]:
    """The values the Mission field at `field` ('a.b[0].c') may take, if it is a choice of values."""
    mi = msgspec.inspect

    def bare(info: mi.Type) -> mi.Type:  # an optional value's type, a list's items' type
        while True:
            if isinstance(info, mi.UnionType):
                kinds = [t for t in info.types if not isinstance(t, mi.NoneType)]
                if len(kinds) != 1:
                    return next((t for t in kinds if isinstance(t, mi.LiteralType)), info)
                info = kinds[0]
            elif isinstance(info, mi.ListType):
                info = info.item_type
            else:
                return info

    info = bare(mi.type_info(Mission))
    for part in filter(None, re.split(r"\.|\[\d+\]", field)):
        fields = {f.encode_name: f.type for f in info.fields} if isinstance(info, mi.StructType) else {}
        if part not in fields:
            return ()
        info = bare(fields[part])
    return tuple(info.values) if isinstance(info, mi.LiteralType) else ()


def _non_finite(value: object, path: str) -> str | None:
    """The path of the first NaN or infinite number in a decoded mission, if any."""
    if isinstance(value, float):
        return None if math.isfinite(value) else path
    if isinstance(value, msgspec.Struct):
        for name in value.__struct_fields__:
            found = _non_finite(getattr(value, name), f"{path}.{name}" if path else name)
            if found:
                return found
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            found = _non_finite(item, f"{path}[{i}]")
            if found:
                return found
    return None


def _validate(m: Mission, source: str) -> None:
    def fail(field: str, reason: str) -> None:
        raise MissionError(source, field, reason)

    bad = _non_finite(m, "")
    if bad:
        fail(bad, "must be a finite number")

    poly = m.region.polygon
    if len(poly) < 3:
        fail("region.polygon", f"needs at least 3 vertices, got {len(poly)}")
    signs = set()
    for i in range(len(poly)):
        (x0, y0), (x1, y1), (x2, y2) = poly[i], poly[(i + 1) % len(poly)], poly[(i + 2) % len(poly)]
        cross = (x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1)
        if abs(cross) < 1e-9:
            fail("region.polygon", f"vertices {i}..{(i + 2) % len(poly)} are collinear or repeated")
        signs.add(cross > 0)
    n = len(poly)
    edges = [(poly[(i + 1) % n][0] - poly[i][0], poly[(i + 1) % n][1] - poly[i][1]) for i in range(n)]
    directions = [math.atan2(dy, dx) for dx, dy in edges]
    turning = sum(math.remainder(directions[(i + 1) % n] - directions[i], 2 * math.pi) for i in range(n))
    if len(signs) != 1 or not math.isclose(abs(turning), 2 * math.pi, abs_tol=1e-6):
        fail("region.polygon", "the polygon is not convex (or crosses itself)")
    c = m.comms
    if not c.safety < c.repulsion < c.attraction < c.range:
        fail(
            "comms",
            "ranges must satisfy safety (R_s) < repulsion (R'_s) < attraction (R'_c) < range (R_c); "
            f"got {c.safety} < {c.repulsion} < {c.attraction} < {c.range}",
        )
    if not m.vehicles:
        fail("vehicles", "at least one vehicle is required")
    if not m.prior.centres:
        fail("prior.centres", "at least one distribution centre is required")
    from companion.core.geometry import ConvexPolygon  # local: keep module import light

    region = ConvexPolygon.from_vertices(poly)
    for i, v in enumerate(m.vehicles):
        if not region.contains(v.x, v.y):
            fail(f"vehicles[{i}]", f"start position ({v.x}, {v.y}) is outside region.polygon")
    _validate_layers(m, fail)
    if m.kinematics.mode == "grid" and m.kinematics.turn_limit_deg < 45:
        fail("kinematics.turn_limit_deg", "grid mode turns in 45 degree steps: the limit must be >= 45")
    ports = [m.vehicle_port(i) for i in range(m.n_uavs)]
    if len(set(ports)) != len(ports):
        fail("vehicles", f"two vehicles share a MAVLink port: {ports}")
    if m.secured:
        for name in ("router", "seed_endpoint", "listen"):
            if not getattr(m.mesh, name).startswith(("tcp/", "tls/")):
                fail(f"mesh.{name}", "a secured mesh (security.keys) runs over TLS: use tcp/ or tls/")
    if math.isclose(m.region.cell_size, 0):
        fail("region.cell_size", "must be positive")
    _validate_bounds(m, fail)
    _validate_sizes(m, region, fail)
    for i, f in enumerate(m.faults.network):
        where = f"faults.network[{i}]"
        if f.end <= f.start:
            fail(f"{where}.end", f"must be after start ({f.start}), got {f.end}")
        members = [u for g in f.groups for u in g]
        if any(u >= m.n_uavs for u in members) or len(set(members)) != len(members):
            fail(f"{where}.groups", f"UAVs 0..{m.n_uavs - 1}, each in at most one group")
    _validate_start(m, fail)


def _validate_layers(m: Mission, fail: Callable[[str, str], None]) -> None:
    """The altitude band holds the layers asked for, and every pinned layer lies inside it."""
    lay = m.layers
    if m.kinematics.altitude <= 0:
        lowest = m.kinematics.altitude
        fail("kinematics.altitude", f"the lowest layer must be above the origin, got {lowest:g} m")
    if lay.separation <= 2 * ALTITUDE_KEEPING:
        fail(
            "layers.separation",
            f"{lay.separation:g} m: two aircraft each up to {ALTITUDE_KEEPING:g} m off their layers could "
            f"meet; it must exceed {2 * ALTITUDE_KEEPING:g} m (docs/companion.md, \"Altitude keeping\")",
        )
    fit = int(lay.band / lay.separation + 1e-9) + 1
    if lay.count != 1 and fit < 2 and m.n_uavs > 1:
        fail(
            "layers.band",
            f"{lay.band:g} m is too thin for two layers {lay.separation:g} m apart (layers.separation); "
            "widen it, or set layers.count = 1 to fly every UAV on one layer",
        )
    if lay.count is not None and lay.count > fit:
        fail(
            "layers.count",
            f"{lay.count} layers at least {lay.separation:g} m apart need a band of "
            f"{(lay.count - 1) * lay.separation:g} m; layers.band is {lay.band:g} m",
        )
    count = m.layer_count
    for i, v in enumerate(m.vehicles):
        if v.layer is not None and v.layer >= count:
            fail(
                f"vehicles[{i}].layer",
                f"layer {v.layer} is outside the band: it holds layers 0..{count - 1}",
            )


def _validate_sizes(m: Mission, region: ConvexPolygon, fail: Callable[[str, str], None]) -> None:
    """The grid, the sensor footprint, the CVT and the targets within the limits above (checked
    before anything of that size is built)."""
    from companion.core.geometry import Grid  # local: keep module import light

    bx0, by0, bx1, by1 = region.bounds
    cell = m.region.cell_size
    across = max(bx1 - bx0, by1 - by0) / cell  # first alone: a tiny cell overflows the product
    lattice = across * across
    if across <= MAX_GRID_CELLS:
        lattice = math.ceil((bx1 - bx0) / cell) * math.ceil((by1 - by0) / cell)
    if lattice > MAX_GRID_CELLS:
        fail(
            "region.cell_size",
            f"{cell:g} m makes a grid of about {lattice:.3g} cells over the region; at most "
            f"{MAX_GRID_CELLS:,} are allowed (a larger cell size)",
        )
    stencil = (2 * math.ceil(m.sensor.radius / cell + 0.5) + 1) ** 2
    if stencil > MAX_FOV_CELLS:
        fail(
            "sensor.radius",
            f"{m.sensor.radius:g} m covers about {stencil:,} cells of {cell:g} m; at most "
            f"{MAX_FOV_CELLS:,} are allowed",
        )
    if lattice * stencil > MAX_FOV_TABLE:
        fail("sensor.radius", f"grid cells x FOV cells = {lattice * stencil:,}, over {MAX_FOV_TABLE:,}")
    n_cells = Grid.build(region, cell, m.sensor.radius).n_cells
    if n_cells == 0:
        fail("region.cell_size", f"no cell of {cell:g} m has its centre inside region.polygon")
    if m.prior.targets > n_cells:
        fail("prior.targets", f"{m.prior.targets} targets, more than the grid's {n_cells} cells (one a cell)")
    a = m.algorithm
    if a.name == "proposed" and a.n_g > n_cells:
        fail("algorithm.n_g", f"{a.n_g} tasks, more than the grid's {n_cells} cells")
    if a.name == "proposed" and n_cells * a.n_g > MAX_CVT_WORK:
        fail("algorithm.n_g", f"grid cells x n_g = {n_cells * a.n_g:,}, over {MAX_CVT_WORK:,}")


def _validate_bounds(m: Mission, fail: Callable[[str, str], None]) -> None:
    """What the kinematics, the safety layer and the simulator imply, within the limits above
    (checked before anything is expanded or allocated; one line naming the field)."""
    k, cell = m.kinematics, m.region.cell_size
    if k.speed > MAX_SPEED:
        fail("kinematics.speed", f"{k.speed:g} m/s; at most {MAX_SPEED:g}")
    if k.step > MAX_STEP_S:
        fail("kinematics.step", f"{k.step:g} s per sampling step; at most {MAX_STEP_S:g}")
    if k.mode == "continuous":
        if k.turn_limit_deg < 360 / MAX_LOITER_STEPS:
            fail(
                "kinematics.turn_limit_deg",
                f"{k.turn_limit_deg:g} deg per step closes a loiter circle in {360 / k.turn_limit_deg:.3g} "
                f"steps; at most {MAX_LOITER_STEPS} (a limit of at least {360 / MAX_LOITER_STEPS:g} deg)",
            )
        options, step = 3, k.speed * k.step
        if step < MIN_STEP_M:
            fail("kinematics.step", f"speed x step = {step:.3g} m per step; at least {MIN_STEP_M:g}")
        turn = math.radians(k.turn_limit_deg)
        diameter = 2 * step / (2 * math.sin(turn / 2)) if turn < math.pi else step
    else:
        options, step = 2 * math.floor(k.turn_limit_deg / 45 + 1e-9) + 1, cell * math.sqrt(2.0)
        diameter = 3 * step  # the grid's octagon loiter, with room
    horizon = m.algorithm.horizon
    if options**horizon > MAX_LATTICE:
        fail("algorithm.horizon", f"{options}^{horizon} trajectories per UAV; at most {MAX_LATTICE:,}")
    reach = horizon * step + diameter
    if reach > MAX_REACH_M:
        field = "region.cell_size" if k.mode == "grid" else "kinematics.speed"
        fail(field, f"trajectories reach {reach:.3g} m ({horizon} steps, a loiter); at most {MAX_REACH_M:g}")
    s = m.safety
    for name, value in (("margin", s.margin), ("buffer", s.buffer), ("failsafe_reach", s.failsafe_reach)):
        if value is not None and value > MAX_REACH_M:
            fail(f"safety.{name}", f"{value:g} m; at most {MAX_REACH_M:g}")
    if m.sim.physics_hz > MAX_PHYSICS_HZ:
        fail("sim.physics_hz", f"{m.sim.physics_hz:g} Hz; at most {MAX_PHYSICS_HZ:g}")
    if m.steps * m.n_uavs > MAX_PATH_POINTS:
        poses = m.steps * m.n_uavs
        fail("steps", f"{m.steps:,} steps x {m.n_uavs} vehicles = {poses:,} poses, over {MAX_PATH_POINTS:,}")


def _validate_start(m: Mission, fail: Callable[[str, str], None]) -> None:
    """The safety layer's preconditions: a margin the UAVs can turn back in, and a start layout
    that is separated, connected and admits a contingency for every UAV (core.safety)."""
    from companion.core.safety.start import minimum_margin, tether_tree  # local: keep import light
    from companion.core.world import build_grid, build_kinematics, build_safety

    kin = build_kinematics(m)
    horizon = m.algorithm.horizon
    need = minimum_margin(kin, horizon)
    if m.safety.margin < need:
        fail(
            "safety.margin",
            f"{m.safety.margin:g} m is too small: a UAV at the region's edge needs {need:.1f} m beyond it "
            f"to turn back (turn limit {m.kinematics.turn_limit_deg:g} deg per {m.kinematics.step:g} s step)",
        )
    c, buffer = m.comms, m.safety.buffer
    poses = [(v.x, v.y) for v in m.vehicles]
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            d = math.dist(poses[i], poses[j])
            if d <= c.safety + buffer:
                fail(
                    "vehicles",
                    f"vehicles {i} and {j} start {d:.1f} m apart, within the safety distance "
                    f"R_s + safety.buffer = {c.safety + buffer:g} m",
                )
    link = c.range - buffer
    _, parents = tether_tree(np.array(poses, dtype=float), link)
    apart = [i for i, p in enumerate(parents) if p < 0 and i > 0]
    if apart:
        fail(
            "vehicles",
            f"the start layout is not connected: vehicles {apart} (and any linked to them) are not within "
            f"R_c - safety.buffer = {link:g} m of the others",
        )
    try:
        build_safety(m, kin, build_grid(m).region, kin.turn_sequences(horizon)[:0])
    except ValueError as exc:
        fail("vehicles", f"the start layout admits no safe start: {exc}")


def parse_mission(text: str, source: str = "<mission>") -> Mission:
    """Parse and validate mission TOML text; `source` names it in errors."""
    if len(text) > MAX_FILE_BYTES:
        raise MissionError(source, "(file)", f"{len(text):,} characters; at most {MAX_FILE_BYTES:,}")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MissionError(source, "(syntax)", str(exc)) from None
    except RecursionError:
        raise MissionError(source, "(syntax)", "arrays or tables nested too deeply") from None
    _refuse_replaced(raw, source)
    try:
        mission = msgspec.convert(raw, Mission)
    except msgspec.ValidationError as exc:
        field, reason = _field_from_msgspec(str(exc))
        raise MissionError(source, field, reason) from None
    _validate(mission, source)
    return mission


def _refuse_replaced(raw: dict, source: str) -> None:
    """A field that an earlier version of the format had, named with what replaced it."""
    kinematics = raw.get("kinematics")
    if isinstance(kinematics, dict) and "altitude_step" in kinematics:
        raise MissionError(
            source,
            "kinematics.altitude_step",
            "replaced by the [layers] table (band, separation, count; docs/mission-files.md): "
            "every UAV gets a layer of its own by default",
        )


def validate(mission: Mission | dict, source: str = "<mission>") -> Mission:
    """Check a mission built in code (a copy with other start poses or weights, say; as a Mission or
    as the tables of a mission file) exactly as a mission file is checked; returns it."""
    raw = mission if isinstance(mission, dict) else msgspec.to_builtins(mission)
    try:
        checked = msgspec.convert(raw, Mission)
    except msgspec.ValidationError as exc:
        field, reason = _field_from_msgspec(str(exc))
        raise MissionError(source, field, reason) from None
    _validate(checked, source)
    return checked


def load_mission(path: str | Path) -> Mission:
    """Read and validate a mission file."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_FILE_BYTES:
            raise MissionError(str(p), "(file)", f"larger than {MAX_FILE_BYTES:,} bytes")
        text = p.read_bytes().decode("utf-8")
    except OSError as exc:
        raise MissionError(str(p), "(file)", exc.strerror or str(exc)) from None
    except UnicodeDecodeError as exc:
        reason = f"not UTF-8 text: byte 0x{exc.object[exc.start]:02x} at offset {exc.start}"
        raise MissionError(str(p), "(file)", reason) from None
    mission = parse_mission(text, str(p))
    keys = mission.security.keys
    if keys and not Path(keys).is_absolute():  # relative to the mission file, wherever it is read from
        security = msgspec.structs.replace(mission.security, keys=str((p.parent / keys).absolute()))
        mission = msgspec.structs.replace(mission, security=security)
    return mission
