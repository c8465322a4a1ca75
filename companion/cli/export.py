"""`uavsearch export RUN_DIR`: a run's tracks, sectors and detections as GeoJSON, KML and a QGC plan."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.cli.options import Subparsers
from companion.contracts.arguments import names, natural

FORMATS = ("geojson", "kml", "plan")  # companion.app.operator_files.FORMATS, without importing it


def register(subparsers: Subparsers) -> None:
    """Add the `export` command to `uavsearch`'s subcommands."""
    parser = subparsers.add_parser(
        "export",
        help="write a run's tracks, sectors and detections for a GIS, Google Earth or QGroundControl",
        description="Write one run of the output of `uavsearch run` or `uavsearch mc --save-trajectories` "
        "as operator.geojson, operator.kml and sectors.plan (docs/companion.md, 'Files for the operator').",
    )
    parser.add_argument("directory", metavar="RUN_DIR", type=Path, help="the run's output directory")
    parser.add_argument(
        "--format",
        type=names(FORMATS),
        default=FORMATS,
        metavar="F[,F...]",
        help=f"what to write, any of {','.join(FORMATS)} (default: all)",
    )
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: RUN_DIR)")
    parser.add_argument("--algorithm", default=None, help="the run's algorithm (default: the first recorded)")
    parser.add_argument("--run", type=natural, default=None, help="which run (default: the first recorded)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the files, print their paths and notes; exit code 2 for a directory that cannot be read."""
    from companion.app.operator_files import export
    from companion.app.operator_run import ExportError, load_picture

    try:
        picture = load_picture(args.directory, args.algorithm, args.run)
    except ExportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    p = picture
    print(f"{args.directory}: {p.mission.name}, {p.algorithm} run {p.run}, seed {p.seed}")
    for path in export(picture, args.out or args.directory, args.format):
        print(f"wrote {path}")
    for note in picture.notes:
        print(f"note: {note}")
    return 0
