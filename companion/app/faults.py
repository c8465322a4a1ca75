"""`uavsearch faults`: the fault matrix, flown by real processes on loopback (docs/reliability.md).

Each row flies a mission in lockstep (the simulator and one companion per UAV, each with its
journal), injects one fault at a chosen step (`restart`, `sim-restart`, `link-loss`, `partition`,
`loss`) and checks what the swarm must keep: the mission completed and flown out, no detection
lost, no separation lost, knowledge converged (`measure`). Every trigger is a step number; while a
vehicle has no companion the harness releases its lockstep steps itself
(`companion.app.fault_links.LockstepDriver`), as the autopilot flying on would.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import msgspec
import tomli_w

from companion.app.children import Children
from companion.app.evaluation import CompanionLogs, losses_3d, mission_rows, read_approach, read_vertical
from companion.app.fault_links import LinkProxy, LockstepDriver
from companion.app.loopback import free_ports
from companion.contracts.keys import RUN_ENV, new_run_id
from companion.contracts.mission import Mission, NetworkFault
from companion.core.feasibility import load_mission
from companion.node.journal import Checkpoint, Delta, read_records

ROWS = ("restart", "sim-restart", "link-loss", "partition", "loss")
REWIND_STEPS = 2  # sim-restart: how many steps before the kill the state it restarts on was saved
START_S = 180.0  # generous: a busy 2-core machine starts five Python processes slowly
STEP_S = 120.0  # longest wait for the swarm to fly one more step
PY = sys.executable


# -- the mission, on loopback ----------------------------------------------------------------------
def _no_none(value: object) -> object:
    """A TOML-ready copy of builtins: tables without their None entries."""
    if isinstance(value, dict):
        return {k: _no_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_no_none(v) for v in value]
    return value


def loopback_mission(
    base: Mission, directory: Path, steps: int, network: list[NetworkFault] | None = None
) -> tuple[Path, Mission]:
    """`base` on free loopback ports and its own mesh key space, written into `directory`.

    The mission has `steps` steps and the injected mesh faults.
    """
    *ports, seed, router = free_ports(base.n_uavs + 2)
    s = msgspec.structs.replace
    mission = s(
        base,
        steps=steps,
        vehicles=[s(v, mavlink_port=p) for v, p in zip(base.vehicles, ports, strict=True)],
        sim=s(base.sim, host="127.0.0.1"),
        mesh=s(
            base.mesh,
            key_prefix=f"faults{uuid.uuid4().hex[:12]}",
            seed_endpoint=f"tcp/127.0.0.1:{seed}",
            router=f"tcp/127.0.0.1:{router}",
        ),
        faults=s(base.faults, network=list(network or [])),
    )
    path = directory / f"{mission.name}-faults.toml"
    table = _no_none(msgspec.to_builtins(mission))
    assert isinstance(table, dict)  # a Struct's builtins are a table
    path.write_text(tomli_w.dumps(table), encoding="utf-8")
    return path, load_mission(path)


# -- the swarm ---------------------------------------------------------------------------------------
def last_step(path: Path) -> int:
    """The last step in a companion's step log (-1: none yet)."""
    if not path.exists():
        return -1
    lines = path.read_text(errors="replace").splitlines()
    for line in reversed(lines[1:]):
        head = line.split(",", 1)[0]
        if head.isdigit() and line.count(",") >= 13:
            return int(head)
    return -1


def journal_found(path: Path, until: int | None = None) -> set[int]:
    """The target cells a companion's journal holds, as of step `until` (default: its last)."""
    records, _ = read_records(path.read_bytes()) if path.exists() else ([], 0)
    found: set[int] = set()
    for r in records:
        if isinstance(r, Checkpoint) and (until is None or r.state.step <= until):
            found |= set(r.state.found)
        elif isinstance(r, Delta) and (until is None or r.delta.step <= until):
            found |= set(r.delta.found)
    return found


class Swarm:
    """The simulator and the companions of one row, as subprocesses (stopped by PID)."""

    def __init__(self, mission_path: Path, mission: Mission, out: Path) -> None:
        self.path, self.mission, self.out = mission_path, mission, out
        self.children = Children()
        self.children.env[RUN_ENV] = new_run_id()  # one run: a restarted companion rejoins it
        self.urls: dict[int, str] = {}
        self.starts: dict[str, int] = {}

    def log(self, name: str) -> str:
        path = self.children.logs.get(name)
        return path.read_text(errors="replace") if path is not None and path.exists() else ""

    def _start(self, name: str, argv: list[str]) -> subprocess.Popen:
        count = self.starts[name] = self.starts.get(name, 0) + 1
        log = self.out / (f"{name}.log" if count == 1 else f"{name}.{count}.log")
        return self.children.start(name if count == 1 else f"{name}.{count}", argv, log)

    def companion(self, i: int) -> subprocess.Popen:
        argv = [
            PY, "-m", "companion.cli", "companion", "--mission", str(self.path), "--uav", str(i),
            "--takeover", "--lockstep", "--out", str(self.out),
            "--journal", str(self.out / f"uav{i}.journal"),
        ]  # fmt: skip
        if i in self.urls:
            argv += ["--vehicle", self.urls[i]]
        return self._start(f"companion{i}", argv)

    def sim(self) -> subprocess.Popen:
        argv = [
            PY, "-m", "sim_vehicles", "--mission", str(self.path), "--lockstep",
            "--truth", str(self.out / "truth.json"), "--state", str(self.out / "sim.state"),
            "--approach", str(self.out / "approach.csv"),
        ]  # fmt: skip
        return self._start("sim", argv)

    def current(self, name: str) -> str:
        count = self.starts[name]
        return name if count == 1 else f"{name}.{count}"

    def wait_text(self, name: str, text: str, timeout: float = START_S) -> None:
        key = self.current(name)
        proc, log = self.children.procs[key], self.children.logs[key]
        deadline = time.monotonic() + timeout
        while text not in (log.read_text(errors="replace") if log.exists() else ""):
            if proc.poll() is not None:
                raise RuntimeError(f"{key} exited with {proc.returncode}:\n{log.read_text(errors='replace')}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"{key}: no {text!r} within {timeout:.0f} s")
            time.sleep(0.1)

    def start(self) -> None:
        """Companions first (each waits for its vehicle), then the simulator."""
        for i in range(self.mission.n_uavs):
            self.companion(i)
        for i in range(self.mission.n_uavs):
            self.wait_text(f"companion{i}", "waiting for the vehicle")
        self.sim()
        self.wait_text("sim", f"vehicle {self.mission.n_uavs - 1} sysid")

    def wait_steps(self, uavs: list[int], step: int, timeout: float = STEP_S) -> None:
        """Until each of `uavs` has logged `step` (its companion still running)."""
        deadline = time.monotonic() + timeout
        for i in uavs:
            while last_step(self.out / f"uav{i}.csv") < step:
                proc = self.children.procs[self.current(f"companion{i}")]
                if proc.poll() is not None:
                    raise RuntimeError(f"companion {i} exited with {proc.returncode} before step {step}")
                if time.monotonic() > deadline:
                    raise RuntimeError(f"uav {i} did not reach step {step} within {timeout:.0f} s")
                time.sleep(0.05)

    def kill(self, name: str) -> None:
        proc = self.children.procs[self.current(name)]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()

    def finish(self, timeout: float) -> dict[str, int | None]:
        """Wait for every companion to exit by itself, then stop the rest; return each process's exit code.

        A companion exits by itself once its step budget is spent.
        """
        deadline = time.monotonic() + timeout
        for i in range(self.mission.n_uavs):
            proc = self.children.procs[self.current(f"companion{i}")]
            with contextlib.suppress(Exception):
                proc.wait(max(0.1, deadline - time.monotonic()))
        codes = {name: p.poll() for name, p in self.children.procs.items()}
        self.children.stop()
        return codes


# -- rows --------------------------------------------------------------------------------------------
@dataclass
class RowOutcome:
    """What one row measured; `failures` is empty when the swarm kept everything it must."""

    row: str
    uavs: int
    steps: int
    seconds: float = 0.0
    completed: bool = False
    exit_codes: dict[str, int | None] = field(default_factory=dict)
    targets_known: list[int] = field(default_factory=list)
    detections: int = 0
    lost_detections: list[int] = field(default_factory=list)
    closest_approach_m: float = math.inf
    separation_losses: int = 0
    closest_vertical_within_rs_m: float = math.inf  # 3D: a pair's vertical separation while within R_s
    converged: bool = False
    notes: dict[str, object] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Plan:
    """When the fault strikes (`at`, a step), how long it lasts (steps) and whom (`victim`)."""

    steps: int
    at: int
    outage: int
    victim: int = 1


def _restart(swarm: Swarm, plan: Plan, outcome: RowOutcome) -> set[int]:
    """Companion `victim` killed, its vehicle flown alone, then the companion restarted on its journal."""
    m, v = swarm.mission, plan.victim
    swarm.wait_steps([v], plan.at)
    swarm.kill(f"companion{v}")
    killed_at = last_step(swarm.out / f"uav{v}.csv")
    before = journal_found(swarm.out / f"uav{v}.journal")
    driver = LockstepDriver(m.vehicle_port(v), v + 1, m.kinematics.step, killed_at + plan.outage)
    driver.start()
    others = [i for i in range(m.n_uavs) if i != v]
    try:
        swarm.wait_steps(others, killed_at + plan.outage)
    finally:
        driver.stop()
    swarm.companion(v)
    swarm.wait_text(f"companion{v}", "restarted from journal")
    outcome.notes.update(killed_after_step=killed_at, vehicle_alone_steps=[driver.first, driver.step])
    outcome.notes["victim_knew_at_kill"] = sorted(before)
    return before


def _sim_restart(swarm: Swarm, plan: Plan, outcome: RowOutcome) -> set[int]:
    """The simulator killed after step `at` and started again on a state it saved a few steps earlier.

    This is what happens when it dies between its telemetry of a step and saving that step: the
    restarted simulator is behind its companions, and they must let it catch up.
    """
    everyone = list(range(swarm.mission.n_uavs))
    state = swarm.out / "sim.state"
    swarm.wait_steps(everyone, max(plan.at - REWIND_STEPS, 0))
    earlier = state.read_bytes()  # written atomically (a renamed temporary file): always whole
    swarm.wait_steps(everyone, plan.at)
    swarm.kill("sim")
    for i in everyone:
        swarm.wait_text(f"companion{i}", "vehicle link lost")
    state.write_bytes(earlier)
    swarm.sim()
    swarm.wait_text("sim", "resumed from")
    outcome.notes["killed_after_step"] = plan.at
    return set()


def _link_loss(swarm: Swarm, plan: Plan, outcome: RowOutcome, proxy: LinkProxy | None) -> set[int]:
    """The victim's MAVLink link cut (`proxy`, its relay) for 10 s of simulated time; its vehicle flies on."""
    assert proxy is not None, "the link-loss row relays the victim's link through a LinkProxy"
    m, v = swarm.mission, plan.victim
    swarm.wait_steps([v], plan.at)
    proxy.cut()
    lost_steps = math.ceil(10.0 / m.kinematics.step)  # 10 s of simulated time
    driver = LockstepDriver(
        m.vehicle_port(v), v + 1, m.kinematics.step, plan.at + 1 + lost_steps, span=lost_steps
    )
    driver.start()
    others = [i for i in range(m.n_uavs) if i != v]
    try:
        swarm.wait_text(f"companion{v}", "vehicle link lost")
        if not driver.started.wait(STEP_S):
            raise RuntimeError(f"the vehicle of UAV {v} sent no step after its link was cut")
        swarm.wait_steps(others, driver.until)
    finally:
        driver.stop()
    proxy.restore()
    swarm.wait_text(f"companion{v}", "vehicle link restored")
    outcome.notes.update(cut_after_step=plan.at, vehicle_alone_steps=[driver.first, driver.step])
    outcome.notes["proxy_dropped_datagrams"] = proxy.dropped
    return set()


def _network(swarm: Swarm, plan: Plan, outcome: RowOutcome) -> set[int]:
    """The mesh faults of the mission file (partition, loss): nothing to do but note them."""
    outcome.notes["network_faults"] = [msgspec.to_builtins(f) for f in swarm.mission.faults.network]
    return set()


def network_faults(row: str, plan: Plan, n_uavs: int) -> list[NetworkFault]:
    """The mesh faults a row injects: a split into two halves, or 30 % loss, over the outage."""
    end = plan.at + plan.outage
    if row == "partition":
        half = n_uavs // 2
        return [NetworkFault(start=plan.at, end=end, groups=[list(range(half)), list(range(half, n_uavs))])]
    if row == "loss":
        return [NetworkFault(start=plan.at, end=end, loss=0.3)]
    return []


def run_row(row: str, base: Mission, out: Path, plan: Plan) -> RowOutcome:
    """Fly one row of the fault matrix into `out` and measure it."""
    if row not in ROWS:
        raise ValueError(f"unknown fault row {row!r}: one of {', '.join(ROWS)}")
    out.mkdir(parents=True, exist_ok=True)
    path, mission = loopback_mission(base, out, plan.steps, network_faults(row, plan, base.n_uavs))
    swarm = Swarm(path, mission, out)
    outcome = RowOutcome(row, mission.n_uavs, plan.steps)
    started = time.monotonic()
    proxy = None
    before: set[int] = set()
    try:
        if row == "link-loss":
            proxy = LinkProxy(mission.vehicle_port(plan.victim))
            proxy.start()
            swarm.urls[plan.victim] = f"udpout:127.0.0.1:{proxy.port}"
        swarm.start()
        actions: dict[str, Callable[[], set[int]]] = {
            "restart": lambda: _restart(swarm, plan, outcome),
            "sim-restart": lambda: _sim_restart(swarm, plan, outcome),
            "link-loss": lambda: _link_loss(swarm, plan, outcome, proxy),
            "partition": lambda: _network(swarm, plan, outcome),
            "loss": lambda: _network(swarm, plan, outcome),
        }
        before = actions[row]()
        outcome.exit_codes = swarm.finish(STEP_S + 5.0 * plan.steps)
    except RuntimeError as exc:
        outcome.failures.append(str(exc))
        outcome.exit_codes = swarm.finish(0.0)
    finally:
        if proxy is not None:
            proxy.stop()
    outcome.seconds = time.monotonic() - started
    measure(outcome, mission, out, before)
    (out / "outcome.json").write_text(json.dumps(asdict(outcome), indent=2) + "\n")
    return outcome


def measure(outcome: RowOutcome, mission: Mission, out: Path, before: set[int]) -> None:
    """Fill in the outcome from the run's files and list what the swarm failed to keep."""
    n, fail = mission.n_uavs, outcome.failures.append
    logs = CompanionLogs(out, n)
    logs.poll()
    searched = mission_rows(logs.logs)
    last = [max(searched[i], default=-1) for i in range(n)]
    outcome.completed = all(s == outcome.steps - 1 for s in last)
    if not outcome.completed:
        fail(f"mission not completed: last steps {last} of {outcome.steps}")
    fly_out = list(range(outcome.steps, outcome.steps + mission.algorithm.horizon + 1))
    closing = [sorted(set(logs.logs[i]) - set(searched[i])) for i in range(n)]
    if any(steps != fly_out for steps in closing):
        fail(f"the mission's end not flown out: steps {closing}, expected {fly_out}")
    paths = [out / f"uav{i}.json" for i in range(n)]
    loaded = [json.loads(p.read_text()) if p.exists() else None for p in paths]
    reports: list[dict] = [r for r in loaded if r is not None]
    if len(reports) < n:
        fail("a companion wrote no end-of-run report")
        return
    found = [set(r["found_cells"]) for r in reports]
    # a target first known at the last step has no step left to be told in (one step of latency)
    told = set().union(before, *(journal_found(out / f"uav{i}.journal", outcome.steps - 2) for i in range(n)))
    outcome.targets_known = [len(f) for f in found]
    outcome.detections = len(set().union(told, *found))
    outcome.notes["known_only_at_the_last_step"] = sorted(set().union(*found) - told)
    outcome.lost_detections = sorted(told - set.intersection(*found))
    if outcome.lost_detections:
        fail(f"detections not known to every UAV: {outcome.lost_detections}")
    truth_path = out / "truth.json"
    if not truth_path.exists():  # the simulator never came up: what failed is already in `failures`
        fail("the simulator wrote no truth record (truth.json)")
        return
    truth = json.loads(truth_path.read_text())
    outcome.notes["targets"] = len(truth.get("targets", []))
    separation = read_approach(out / "approach.csv")
    if separation:
        outcome.closest_approach_m = min(separation.values())
    outcome.separation_losses = losses_3d(out / "approach.csv", mission)
    if outcome.separation_losses:
        fail(
            f"{outcome.separation_losses} steps within R_s = {mission.comms.safety:g} m and "
            f"{mission.vertical_floor:g} m vertically"
        )
    vertical = read_vertical(out / "approach.csv")
    if vertical:
        outcome.closest_vertical_within_rs_m = min(vertical.values())
    rows = [_last_row(out / f"uav{i}.csv") for i in range(n)]
    peers = [int(r["peers"]) for r in rows]
    tasks = [int(r["task"]) for r in rows if int(r["task"]) >= 0]
    outcome.notes.update(final_peers=peers, final_tasks=[int(r["task"]) for r in rows])
    outcome.notes["fault_dropped"] = [r.get("fault_dropped", 0) for r in reports]
    outcome.converged = not outcome.lost_detections and all(p == n - 1 for p in peers)
    outcome.converged &= all(f >= told for f in found)
    outcome.converged &= len(tasks) == len(set(tasks))
    if not outcome.converged:
        fail(f"knowledge did not converge: peers known {peers}, tasks {outcome.notes['final_tasks']}")


def _last_row(path: Path) -> dict[str, str]:
    """The last complete row of a companion's step log (every field -1: none)."""
    lines = path.read_text(errors="replace").splitlines()
    header = lines[0].split(",")
    for line in reversed(lines[1:]):
        cells = line.split(",")
        if len(cells) == len(header):
            return dict(zip(header, cells, strict=True))
    return dict.fromkeys(header, "-1")
