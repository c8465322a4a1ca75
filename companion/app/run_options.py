"""`uavsearch run`'s options, and whether a mission can be flown with them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from companion.contracts.mission import Mission
from companion.node.airframe import Airframe, refusal

SITL_FLAVOURS = {"ardupilot-sitl": "ardupilot", "px4-sitl": "px4"}


@dataclass(frozen=True)
class RunOptions:
    """What `uavsearch run` flies, on which vehicles, and how (its command line's options)."""

    mission_file: Path
    out: Path
    speedup: float = 10.0
    lockstep: bool = False
    steps: int | None = None
    seed: int | None = None
    command_mode: str | None = None  # None: turn-rate on the bundled simulator, heading otherwise
    flavour: str | None = None
    progress: bool = True
    keep_going: bool = False  # fly all the steps even when every target is found
    view: bool = False  # serve the live map (`uavsearch view`) while the swarm flies
    view_port: int = 0
    autopilot: str = "bundled"  # or "ardupilot-sitl", "px4-sitl"
    vehicles: tuple[str, ...] = ()  # external vehicles, one pymavlink URL per UAV
    camera_links: tuple[str, ...] = ()  # the stand-alone camera's links to the external vehicles
    sitl_binary: str | None = None
    sitl_defaults: str | None = None
    sitl_instance: int = 0  # PX4: the first instance number tried

    @property
    def external(self) -> bool:
        """Whether the vehicles are not the bundled simulator (SITL, or vehicles that exist)."""
        return self.autopilot != "bundled" or bool(self.vehicles)

    @property
    def mode(self) -> str:
        """How the companions send the plan: `command_mode`, else the vehicles' default."""
        if self.command_mode:
            return self.command_mode
        if self.autopilot == "px4-sitl":
            return "position-target"
        return "heading" if self.external else "turn-rate"


def check_options(opts: RunOptions, mission: Mission) -> str | None:
    """Why the run cannot start (None: it can)."""
    if opts.vehicles and len(opts.vehicles) != mission.n_uavs:
        return f"--vehicles: {len(opts.vehicles)} links for the mission's {mission.n_uavs} UAVs"
    if opts.camera_links and len(opts.camera_links) != mission.n_uavs:
        return f"--camera-links: {len(opts.camera_links)} links for the mission's {mission.n_uavs} UAVs"
    if opts.autopilot in SITL_FLAVOURS:
        if opts.vehicles:
            return f"--vehicles and --autopilot {opts.autopilot} exclude each other"
        airframe = Airframe(SITL_FLAVOURS[opts.autopilot], {}, simulator=False)
        problem = refusal(mission, airframe, opts.mode)
        if problem:
            return f"--autopilot {opts.autopilot}: {problem}"
        if opts.autopilot == "px4-sitl" and mission.secured and mission.security.mavlink_signing:
            return (
                "--autopilot px4-sitl: the PX4 SITL links are not MAVLink2-signed (PX4 is given no secret): "
                "set [security] mavlink_signing = false for it"
            )
    return None
