"""`uavsearch companion`: wires the MAVLink link, the Zenoh mesh and the camera feed to the Agent."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path

import zenoh

from companion.contracts.frames import LocalFrame
from companion.contracts.keys import (
    RUN_ENV,
    KeyDirectoryError,
    SwarmKeys,
    for_mission,
    mavlink_secret,
    run_id,
    uav_identity,
    warn_if_insecure,
)
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.core.world import Stream, build_world, instance_rng
from companion.node.camera_feed import CameraFeed
from companion.node.journal import JournalError, journal_run
from companion.node.mesh import Mesh
from companion.node.pilot import CompanionOptions
from companion.node.preflight import Refused
from companion.node.process import Companion, camera_key_of, default_vehicle_url
from companion.node.vehicle_link import (
    COMPANION_SYSTEM,
    VEHICLE_WAIT_S,
    LinkError,
    LinkNotOpen,
    VehicleLink,
    open_link,
)

log = logging.getLogger("companion")


NO_RUN_WARNING = (
    "WARNING: no run identity (--run, or $UAVSEARCH_RUN; `uavsearch run` issues one): what this companion "
    "signs is bound to no run, so bundles and MAVLink frames recorded in an earlier run can be replayed"
)


def run_of(explicit: str | None, journal: Path | None) -> str:
    """The companion's run identity: `--run`, else $UAVSEARCH_RUN, else its journal's, else none.

    The journal's run lets a restart rejoin its run. KeyDirectoryError for a malformed one.
    """
    if explicit is None and RUN_ENV not in os.environ and journal is not None:
        kept = journal_run(journal)
        if kept is not None:
            return run_id(kept)
    return run_id(explicit)


def run_companion(args: argparse.Namespace) -> int:
    """Run one companion until its step budget is spent or SIGINT/SIGTERM; 0 on a clean stop."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zenoh.try_init_log_from_env()  # Zenoh's own log on stderr when RUST_LOG is set (docs/mesh.md)
    mission = load_mission(args.mission)
    if not 0 <= args.uav < mission.n_uavs:
        print(f"error: --uav {args.uav}: the mission has UAVs 0..{mission.n_uavs - 1}", file=sys.stderr)
        return 2
    warn_if_insecure(mission)
    try:
        opts, keys, secret = _options(args, mission)
    except KeyDirectoryError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    stop, abort = _on_signals()
    frame = LocalFrame(mission.region.origin)
    try:
        link = _open_vehicle(opts, frame, secret, stop)
    except LinkError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if link is None:
        return 0  # stopped before the link could be opened: nothing flown
    try:
        return _fly(opts, keys, link, frame, stop, abort)
    finally:
        link.close()


def _options(
    args: argparse.Namespace, mission: Mission
) -> tuple[CompanionOptions, SwarmKeys | None, bytes | None]:
    """The companion's options, its keys and the MAVLink signing secret.

    KeyDirectoryError for a malformed run identity or key directory.
    """
    journal = Path(args.journal) if args.journal else None
    run = run_of(args.run, journal)
    keys = for_mission(mission, uav_identity(args.uav), run)
    secret = mavlink_secret(args.mavlink_key) if args.mavlink_key else None  # as the autopilot holds it
    if mission.secured and not run:
        print(NO_RUN_WARNING, file=sys.stderr, flush=True)
    log.info("uav %d: run %r", args.uav, run)
    if secret is None and keys is not None and mission.security.mavlink_signing:
        secret = keys.mavlink_secret
    opts = CompanionOptions(
        mission=mission,
        uav=args.uav,
        vehicle_url=args.vehicle or default_vehicle_url(mission, args.uav),
        command_mode=args.command_mode,
        takeover=args.takeover,
        fence=args.fence,
        failsafe=args.failsafe,
        lockstep=args.lockstep,
        seed=args.seed,
        steps=args.steps,
        out=Path(args.out) if args.out else None,
        journal=journal,
        run=run,
        gcs_reports=args.gcs_reports,
    )
    return opts, keys, secret


def _on_signals() -> tuple[threading.Event, threading.Event]:
    """(stop, abort): the first SIGINT/SIGTERM closes the mission (`flyout`), a second cuts it short."""
    stop, abort = threading.Event(), threading.Event()

    def on_signal(*_: object) -> None:
        (abort if stop.is_set() else stop).set()

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, on_signal)
    return stop, abort


def _open_vehicle(
    opts: CompanionOptions, frame: LocalFrame, secret: bytes | None, stop: threading.Event
) -> VehicleLink | None:
    """The link to the vehicle, tried until it opens (None: stopped first; LinkError: never)."""
    url, uav = opts.vehicle_url, opts.uav

    def retrying(exc: LinkNotOpen) -> None:
        log.warning("uav %d: cannot open %s yet (%s): trying again for %.0f s", uav, url, exc, VEHICLE_WAIT_S)

    tlog = opts.out / f"uav{uav}.tlog" if opts.out else None
    link = open_link(
        url, frame, VEHICLE_WAIT_S, stop.is_set, retrying,
        tlog=tlog, signing_secret=secret, system=COMPANION_SYSTEM, heartbeat=True,
    )  # fmt: skip
    if link is not None and link.local_address is not None:
        log.info("uav %d: MAVLink link %s on %s:%d", uav, url, *link.local_address)
    return link


def _fly(
    opts: CompanionOptions,
    keys: SwarmKeys | None,
    link: VehicleLink,
    frame: LocalFrame,
    stop: threading.Event,
    abort: threading.Event,
) -> int:
    """Join the mesh, take the camera's feed and run the companion; its exit code."""
    mission, uav = opts.mission, opts.uav
    seed = mission.seed if opts.seed is None else opts.seed
    world = build_world(mission, seed, 0)
    n_tasks = world.tessellation.n_tasks if world.tessellation else 0
    loss_rng = instance_rng(seed, 1000 + uav, Stream.RADIO)
    restarting = opts.journal is not None and opts.journal.exists() and opts.journal.stat().st_size > 0
    with Mesh(mission, uav, world.grid.n_cells, n_tasks, loss_rng, join=not restarting, keys=keys) as mesh:
        camera = CameraFeed(mesh.session, camera_key_of(mission, uav), uav, mission.n_uavs, frame)
        try:
            companion = Companion(opts, link, mesh, camera)
        except JournalError as exc:
            camera.close()
            print(f"error: {exc}", file=sys.stderr)
            return 2
        try:
            return companion.run(stop, abort)
        except LinkError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        except Refused as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        finally:
            if stop.is_set():
                log.info("uav %d: stopped by a signal", uav)
            companion.close()
            camera.close()
