"""Reading a mission file: TOML checked against the schema of `mission.py` and for consistency.

Every user error (syntax, a missing or mistyped field, an inconsistent value) is raised as
`MissionError`, naming the file, the field and the reason. What needs the core's geometry is
checked by `companion.core.feasibility`, which loads every mission the processes run.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable
from pathlib import Path

import msgspec
import msgspec.inspect
from shapely.geometry import Polygon
from shapely.validation import explain_validity

from companion.contracts.areas import LocalPolygon, local_area, read_area
from companion.contracts.mission import (
    ALTITUDE_KEEPING,
    MAX_FILE_BYTES,
    MAX_LATTICE,
    MAX_LOITER_STEPS,
    MAX_PATH_POINTS,
    MAX_PHYSICS_HZ,
    MAX_REACH_M,
    MAX_SPEED,
    MAX_STEP_S,
    MIN_STEP_M,
    Mission,
    MissionError,
    NoFlyPolygon,
    Origin,
)

_PATH_RE = re.compile(r" - at `\$(?P<path>[^`]*)`$")


def _field_from_msgspec(message: str) -> tuple[str, str]:
    """Split msgspec's 'reason - at `$.a.b[0]`' into ('a.b[0]', 'reason').

    A value not among a field's choices gets the valid ones listed.
    """
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

    _validate_region(m, fail)
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
    _validate_layers(m, fail)
    _validate_sensor(m, fail)
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
    for i, f in enumerate(m.faults.network):
        where = f"faults.network[{i}]"
        if f.end <= f.start:
            fail(f"{where}.end", f"must be after start ({f.start}), got {f.end}")
        members = [u for g in f.groups for u in g]
        if any(u >= m.n_uavs for u in members) or len(set(members)) != len(members):
            fail(f"{where}.groups", f"UAVs 0..{m.n_uavs - 1}, each in at most one group")


def _validate_sensor(m: Mission, fail: Callable[[str, str], None]) -> None:
    """A report must be evidence for a target, and the clearing floor below the threshold."""
    s = m.sensor
    pd_edge = s.pd if s.pd_edge is None else s.pd_edge
    if min(s.pd, pd_edge) <= s.pf:
        fail("sensor.pf", f"must be below pd ({s.pd}) and pd_edge ({pd_edge}), got {s.pf}")
    if s.clear >= s.confirm:
        fail("sensor.clear", f"must be below sensor.confirm ({s.confirm}), got {s.clear}")


def _validate_region(m: Mission, fail: Callable[[str, str], None]) -> None:
    """The region is one simple polygon (convex or not) and every no-fly zone a simple shape."""
    poly = m.region.polygon
    if len(poly) < 3:
        fail("region.polygon", f"needs at least 3 vertices (or give region.area), got {len(poly)}")
    reason = ring_problem(poly, closed=False)
    if reason:
        fail("region.polygon", reason)
    for i, zone in enumerate(m.region.nofly):
        if isinstance(zone, NoFlyPolygon):
            enough = len(zone.ring) >= 3
            reason = ring_problem(zone.ring, closed=True) if enough else "needs at least 3 vertices"
            if reason:
                fail(f"region.nofly[{i}].ring", reason)


def ring_problem(ring: list[tuple[float, float]], closed: bool) -> str | None:
    """Why a ring of (x, y) is no simple polygon, or None.

    It may cross itself, enclose no area, or repeat a vertex (its first as its last only if `closed`
    rings are allowed)."""
    last = len(ring) - 1
    for i in range(len(ring)):
        j = (i + 1) % len(ring)
        if ring[i] == ring[j] and not (closed and i == last):
            return f"vertices {i} and {j} are the same point {tuple(ring[i])}"
    shape = Polygon(ring)
    if shape.convex_hull.area < 1e-6:
        return "the polygon encloses no area (its vertices are collinear)"
    if not shape.is_valid:
        where = re.search(r"\[(\S+) (\S+)\]", explain_validity(shape))
        near = f" near ({float(where[1]):.2f}, {float(where[2]):.2f})" if where else ""
        return f"the polygon crosses itself{near}"
    return None


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
            f'meet; it must exceed {2 * ALTITUDE_KEEPING:g} m (docs/companion.md, "Altitude keeping")',
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


def _validate_bounds(m: Mission, fail: Callable[[str, str], None]) -> None:
    """What the kinematics, the safety layer and the simulator imply, within the limits above.

    Checked before anything is expanded or allocated; an error is one line naming the field.
    """
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


def parse_schema(text: str, source: str = "<mission>", base: Path | None = None) -> Mission:
    """Mission TOML text checked against the format and for consistency; `source` names it in errors.

    `base` is the directory a relative `region.area` is read from (default: the working directory).

    What needs the core's geometry (the grid's size, a safe start) is checked by
    `companion.core.feasibility.parse_mission`.
    """
    if len(text) > MAX_FILE_BYTES:
        raise MissionError(source, "(file)", f"{len(text):,} characters; at most {MAX_FILE_BYTES:,}")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MissionError(source, "(syntax)", str(exc)) from None
    except RecursionError:
        raise MissionError(source, "(syntax)", "arrays or tables nested too deeply") from None
    _refuse_replaced(raw, source)
    resolve_area(raw, source, base)
    try:
        mission = msgspec.convert(raw, Mission)
    except msgspec.ValidationError as exc:
        field, reason = _field_from_msgspec(str(exc))
        raise MissionError(source, field, reason) from None
    _validate(mission, source)
    return mission


def resolve_area(raw: dict, source: str, base: Path | None) -> None:
    """Fill `region` from the operator's file named by `region.area`: polygon, zones, origin.

    The file's inclusion polygon becomes `region.polygon`, its no-fly zones go before any typed in
    `region.nofly`, and its own origin (`Area.origin`) is used unless the mission sets one. An
    error in the area file names that file.
    """
    region = raw.get("region")
    if not isinstance(region, dict) or not region.get("area"):
        return
    name = region["area"]
    if not isinstance(name, str):
        raise MissionError(source, "region.area", f"a file name, got {name!r}")
    if region.get("polygon"):
        raise MissionError(source, "region.area", "give region.polygon or region.area, not both")
    path = Path(name) if Path(name).is_absolute() else (base or Path.cwd()) / name
    try:
        area = read_area(path)
    except MissionError as exc:  # named by both files: the mission's field, then the area file's
        raise MissionError(source, "region.area", str(exc)) from None
    origin = None
    if "origin" in region:
        try:
            origin = msgspec.convert(region["origin"], Origin)
        except msgspec.ValidationError as exc:
            field, reason = _field_from_msgspec(str(exc))
            raise MissionError(source, f"region.origin.{field}".rstrip("."), reason) from None
    local = local_area(area, origin)
    zones = [
        {"type": "polygon", "ring": [list(p) for p in z.ring]}
        if isinstance(z, LocalPolygon)
        else {"type": "circle", "x": z.x, "y": z.y, "radius": z.radius}
        for z in local.nofly
    ]
    region["polygon"] = [list(p) for p in local.inclusion]
    region["nofly"] = zones + list(region.get("nofly", []))
    region["origin"] = msgspec.to_builtins(local.origin)


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


def convert_schema(mission: Mission | dict, source: str = "<mission>") -> Mission:
    """A mission built in code, checked as `parse_schema` checks a file's text; returns it.

    The mission is a Mission, or the tables of a mission file.
    """
    raw = mission if isinstance(mission, dict) else msgspec.to_builtins(mission)
    try:
        checked = msgspec.convert(raw, Mission)
    except msgspec.ValidationError as exc:
        field, reason = _field_from_msgspec(str(exc))
        raise MissionError(source, field, reason) from None
    _validate(checked, source)
    return checked


def read_schema(path: str | Path) -> Mission:
    """A mission file read and checked by `parse_schema`; a relative key directory made absolute."""
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
    mission = parse_schema(text, str(p), p.parent)
    keys = mission.security.keys
    if keys and not Path(keys).is_absolute():  # relative to the mission file, wherever it is read from
        security = msgspec.structs.replace(mission.security, keys=str((p.parent / keys).absolute()))
        mission = msgspec.structs.replace(mission, security=security)
    return mission
