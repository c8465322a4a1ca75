"""The mission file's schema: typed, immutable objects and the limits on their sizes.

One mission file drives the batch engine, the simulator and the companions. `mission_file.py`
reads and checks a file against this schema; `companion.core.feasibility` checks what needs the
core's geometry. Every user error is a `MissionError` naming the file, the field and the reason.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, get_args

import msgspec

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
MAX_ZONES = 64
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


class Origin(_Base, frozen=True, kw_only=True):
    """Geodetic origin of the local frame (x east, y north, metres)."""

    lat: Annotated[float, msgspec.Meta(ge=-90, le=90)]
    lon: Annotated[float, msgspec.Meta(ge=-180, le=180)]
    alt: float = 0.0


class NoFlyPolygon(_Base, frozen=True, kw_only=True, tag="polygon"):
    """A no-fly polygon in local metres: a ring of (x, y), open or closed, either orientation."""

    ring: Annotated[list[tuple[float, float]], msgspec.Meta(max_length=MAX_VERTICES)]


class NoFlyCircle(_Base, frozen=True, kw_only=True, tag="circle"):
    """A no-fly circle in local metres: its centre and radius."""

    x: float
    y: float
    radius: Positive


NoFly = NoFlyPolygon | NoFlyCircle


class Region(_Base, frozen=True, kw_only=True):
    """The search polygon and no-fly zones in local metres, and the cell size of the search grid.

    `area`: an operator's file (.plan, GeoJSON or KML, relative to the mission file) that gives the
    polygon, the zones and, unless set here, the origin (`mission_file.resolve_area`). The polygon
    may be non-convex; cells inside a no-fly zone are not searched, and no trajectory comes within
    `safety.margin` of one (docs/algorithm.md, "No-fly zones").
    """

    polygon: Annotated[list[tuple[float, float]], msgspec.Meta(max_length=MAX_VERTICES)] = []
    cell_size: Positive
    origin: Origin
    area: str = ""
    nofly: Annotated[list[NoFly], msgspec.Meta(max_length=MAX_ZONES)] = []


class Centre(_Base, frozen=True, kw_only=True):
    """A distribution centre of eq. 1: its position, its peak probability and its spread.

    `peak` is Pr_{p,z} at the centre (K_z / (sqrt(2 pi) sigma)); `sigma` is this centre's spread
    (default: the prior's `sigma`).
    """

    x: float
    y: float
    peak: Annotated[float, msgspec.Meta(gt=0, le=1)]
    sigma: Positive | None = None


class Prior(_Base, frozen=True, kw_only=True):
    sigma: Positive
    centres: Annotated[list[Centre], msgspec.Meta(max_length=MAX_CENTRES)]
    targets: Annotated[int, msgspec.Meta(ge=0)]


class Sensor(_Base, frozen=True, kw_only=True):
    """Downward camera: FOV radius R_A (eq. 3) and its detector (docs/algorithm.md, "Imperfect sensing").

    A target in view is reported with probability Pd, falling linearly from `pd` under the UAV to
    `pd_edge` (default `pd`) at R_A; an empty cell in view is reported with probability `pf` per
    look. A cell is confirmed when its posterior reaches `confirm` and cleared below `clear`.
    """

    radius: Positive
    pd: Probability = 1.0
    pd_edge: Probability | None = None
    pf: Probability = 0.0
    confirm: Annotated[float, msgspec.Meta(gt=0, lt=1)] = 0.999
    clear: Annotated[float, msgspec.Meta(gt=0, lt=1)] = 0.01

    @property
    def perfect(self) -> bool:
        """Pd = 1 everywhere and Pf = 0: the paper's camera."""
        return self.pd == 1.0 and self.pd_edge in (None, 1.0) and self.pf == 0.0


class Kinematics(_Base, frozen=True, kw_only=True):
    """Eq. 2: constant speed, turn limited to turn_limit_deg per sampling step dT.

    `altitude`: the lowest altitude layer, metres above the origin (`Layers` adds the others).
    """

    mode: Mode = "grid"
    speed: Positive
    step: Positive
    turn_limit_deg: Annotated[float, msgspec.Meta(gt=0, le=180)]
    altitude: float = 100.0


class Layers(_Base, frozen=True, kw_only=True):
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


class Comms(_Base, frozen=True, kw_only=True):
    """Ranges of eqs. 5, 17, 28: R_s < R'_s < R'_c < R_c."""

    range: Positive
    attraction: Positive
    safety: Positive
    repulsion: Positive
    loss: Probability = 0.0
    peer_timeout_steps: Annotated[int, msgspec.Meta(ge=1)] = 5


class Safety(_Base, frozen=True, kw_only=True):
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


class Uncertainty(_Base, frozen=True, kw_only=True):
    """Eqs. 10-11: initial uncertainty eta_0 and decay gamma per look."""

    eta0: Annotated[float, msgspec.Meta(gt=0, le=1)] = 1.0
    gamma: Annotated[float, msgspec.Meta(ge=0, lt=1)] = 0.1


class Pheromone(_Base, frozen=True, kw_only=True):
    """Pheromone baseline: deposit from importance, evaporation, diffusion, attraction weight."""

    deposit: NonNegative = 1.0
    evaporation: Probability = 0.1
    diffusion: Probability = 0.2
    weight: NonNegative = 1.0


class Algorithm(_Base, frozen=True, kw_only=True):
    """Algorithm name and every weight of eqs. 16-29 and Algorithm 1.

    The weights the paper does not give are those `uavsearch tune` chose on 12 training missions
    (docs/results.md, "Held-out missions"; the pheromone's stayed: no candidate beat them).
    """

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


class Vehicle(_Base, frozen=True, kw_only=True):
    """Start pose (heading counter-clockwise from east, degrees) and MAVLink UDP port."""

    x: float
    y: float
    heading_deg: float = 90.0
    mavlink_port: Port | None = None
    layer: Annotated[int, msgspec.Meta(ge=0)] | None = None  # its altitude layer (default: `assign_layers`)


class Sim(_Base, frozen=True, kw_only=True):
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


class Mesh(_Base, frozen=True, kw_only=True):
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


class NetworkFault(_Base, frozen=True, kw_only=True):
    """Injected mesh faults over the steps [start, end): a partition into `groups`, and message loss.

    The companions drop the messages between UAVs of different `groups` (a partition: UAVs in no
    group hear only themselves), and any other message with probability `loss` (docs/reliability.md,
    "Fault matrix").
    """

    start: Annotated[int, msgspec.Meta(ge=0)]
    end: Annotated[int, msgspec.Meta(ge=1)]
    groups: Annotated[
        list[Annotated[list[Annotated[int, msgspec.Meta(ge=0)]], msgspec.Meta(max_length=MAX_VEHICLES)]],
        msgspec.Meta(max_length=MAX_VEHICLES),
    ] = []
    loss: Probability = 0.0


class Faults(_Base, frozen=True, kw_only=True):
    """Faults the companions inject into themselves (for the fault matrix)."""

    network: Annotated[list[NetworkFault], msgspec.Meta(max_length=1_000)] = []


class Security(_Base, frozen=True, kw_only=True):
    """Authentication (docs/reliability.md): the key directory, and whether MAVLink is signed.

    `keys` is the key directory written by `uavsearch keys` (relative to the mission file); empty, the
    default, runs an insecure mesh and MAVLink link, and every process says so. `mavlink_signing`:
    with keys, sign the companion-autopilot link with each vehicle's secret (the bundled simulator
    then rejects unsigned commands).
    """

    keys: str = ""
    mavlink_signing: bool = True


class PassCriteria(_Base, frozen=True, kw_only=True):
    """What a scripted mission must achieve to pass.

    Targets found are the true targets some UAV confirmed; `max_false_confirmations` (None: not
    judged) bounds the confirmed cells that hold no target."""

    min_targets_found: Annotated[int, msgspec.Meta(ge=0)] = 0
    require_connected: bool = True
    require_safe_distance: bool = True
    max_false_confirmations: Annotated[int, msgspec.Meta(ge=0)] | None = None


class Mission(_Base, frozen=True, kw_only=True):
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
        """The vertical distance two aircraft on layers `layers.separation` apart keep in flight.

        Each is within `ALTITUDE_KEEPING` of its layer. Below it, a pair horizontally within R_s has lost
        separation in three dimensions.
        """
        return self.layers.separation - 2 * ALTITUDE_KEEPING

    def near_layers(self) -> list[list[bool]]:
        """Whether each pair of vehicles flies layers closer than `layers.separation`.

        A UAV is near itself. Only such pairs can meet, so only they guard against each other's
        failures.
        """
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
    """Each UAV's altitude layer: a pinned one keeps its own; the others are spread greedily.

    The others, in id order, take the layer whose nearest UAV at the start is farthest away (an empty
    layer first, then the fewest UAVs, then the lowest), so that UAVs sharing a layer start as far
    apart as the greedy choice makes them.
    """
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
