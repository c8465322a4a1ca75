"""`uavsearch area FILE`: an operator's area file (.plan, GeoJSON, KML) checked and shown in local metres."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import TYPE_CHECKING, Any

import msgspec

from companion.contracts.mission import MissionError, Origin

# shapely loads with the command, not with the command line: a Ctrl-C while numpy loads would
# surface from shapely's extension as an ImportError instead of a clean interrupt
if TYPE_CHECKING:
    from companion.contracts.areas import LocalArea


def register(subparsers: Any) -> None:
    """Add the `area` command to `uavsearch`'s subcommands."""
    parser = subparsers.add_parser(
        "area",
        help="check an area file (QGroundControl .plan, GeoJSON, KML) and show it in local metres",
        description="Read an area file (docs/mission-files.md, 'Areas from a ground station or GIS') and "
        "print its area and no-fly zones in local metres, or the one-line error (exit code 2).",
    )
    parser.add_argument("file", metavar="FILE", help="the area file")
    parser.add_argument(
        "--origin",
        type=origin,
        default=None,
        metavar="LAT,LON[,ALT]",
        help="the local frame's origin: degrees, metres above sea level (a southern latitude as "
        "--origin=-35.36,149.17; default: the area's own, its centroid at altitude 0)",
    )
    parser.set_defaults(func=run)


def origin(text: str) -> Origin:
    """`--origin LAT,LON[,ALT]` as an `Origin`."""
    try:
        values = [float(v) for v in text.split(",")]
        if len(values) not in (2, 3):
            raise ValueError("two or three numbers")
        return msgspec.convert(dict(zip(("lat", "lon", "alt"), values, strict=False)), Origin)
    except (ValueError, msgspec.ValidationError) as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not LAT,LON[,ALT] ({exc})") from None


def run(args: argparse.Namespace) -> int:
    """Print the area of `args.file` in local metres, or its error on one line (exit code 2)."""
    from companion.contracts.areas import local_area, read_area

    logging.getLogger("fastkml").addHandler(logging.NullHandler())  # its errors are ours to report
    try:
        area = read_area(args.file)
    except MissionError as exc:
        print(f"error: area file {exc}", file=sys.stderr)
        return 2
    local = local_area(area, args.origin)
    whence = "given" if args.origin else "the area's own: its centroid"
    print(f"{area.source}: {area.kind}")
    o = local.origin
    print(f"origin: latitude {o.lat:.7f}, longitude {o.lon:.7f}, altitude {o.alt:g} m ({whence})")
    print(_describe(local))
    for note in local.notes:
        print(f"note: {note}")
    return 0


def _describe(local: LocalArea) -> str:
    """The area's lines: its ring, each zone, and the areas in m^2 and km^2."""
    from companion.contracts.areas import LocalCircle

    ring = ", ".join(f"({x:.2f}, {y:.2f})" for x, y in local.inclusion)
    lines = [f"inclusion polygon: {len(local.inclusion)} vertices (x east, y north; m): {ring}"]
    for i, (zone, shape) in enumerate(zip(local.nofly, local.zone_shapes(), strict=True)):
        if isinstance(zone, LocalCircle):
            what = f"circle at ({zone.x:.2f}, {zone.y:.2f}), radius {zone.radius:.2f} m"
        else:
            what = f"{len(zone.ring)} vertices: " + ", ".join(f"({x:.2f}, {y:.2f})" for x, y in zone.ring)
        lines.append(f"no-fly zone {i}: {what}; {_size(shape.area)}")
    lines.append(f"area: {_size(local.polygon.area)}")
    lines.append(f"searchable (the area less its no-fly zones): {_size(local.free.area)}")
    return "\n".join(lines)


def _size(m2: float) -> str:
    """An area in m^2 and km^2."""
    return f"{m2:,.0f} m^2 ({m2 / 1e6:.3f} km^2)"
