"""Shared fixtures of the companion's end-to-end tests: real processes over loopback only.

- `make_mission`: a temporary mission derived from mission_files/scenario1.toml with its own free
  UDP port per vehicle (`mavlink_port`), a unique `[mesh] key_prefix` and free `seed_endpoint` /
  `router` TCP ports, all on 127.0.0.1, so tests never meet another run on the machine.
- `procs`: starts subprocesses in their own session, records their PIDs (and, while they run,
  the PIDs of their descendants, e.g. the launcher's children) and stops every one of them by PID
  in the finalizer: SIGINT, then SIGKILL after a generous timeout. Nothing is ever killed by name.
- `Ground`: a small pymavlink ground station on one vehicle's UDP endpoint.
- CSV helpers for the companion's step log (uav{i}.csv).
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.app.loopback import free_ports
from companion.contracts.mission import ALTITUDE_KEEPING, Mission
from companion.core.feasibility import load_mission
from tests.thread_signal import signal_another_thread

ROOT = Path(__file__).resolve().parents[2]
SCENARIO1 = ROOT / "mission_files" / "scenario1.toml"
SCENARIO1_NOFLY = ROOT / "mission_files" / "scenario1_nofly.toml"  # its area from areas/*.plan
PY = sys.executable
STARTUP_S = 90.0  # generous: a busy 2-core machine imports numpy, numba, pymavlink and zenoh slowly
STOP_S = 30.0  # how long a process gets after SIGINT before SIGKILL
GUIDED, LOITER = 15, 12  # ArduPlane custom modes
# The autopilots' guidance timeout (SIM_GUIDED_TMO, COM_OF_LOSS_T) in simulated seconds: at
# --speedup 10 the default 3 s is 0.3 s of wall time, less than a companion may be starved of
# CPU on a loaded 2-core machine; 20 s (2 s wall) keeps the tests about steering, not about load.
SLACK_GUIDED_TIMEOUT = "guided_timeout = 20.0"
# The same for the autopilot's failsafe for a silent companion (FS_LONG_TIMEOUT, which the
# companion sets with --takeover): one step (2 s) by default, 0.2 s of wall time at --speedup 10.
# The contingency clause widens with it (`world.failsafe_stray`: 530 m of failsafe region at 20 s),
# so these swarms keep far apart and loiter more: none of the tests using it minds.
SLACK_FAILSAFE_TIMEOUT = "failsafe_timeout = 20.0"


# -- ports and missions ---------------------------------------------------------------------------
@dataclass(frozen=True)
class MissionFile:
    path: Path
    ports: list[int]  # UDP port of vehicle i
    mission: Mission

    @property
    def n(self) -> int:
        return self.mission.n_uavs


def write_mission(
    directory: Path,
    *,
    n: int = 4,
    kinematics: str = "continuous",
    sim: str = SLACK_GUIDED_TIMEOUT,
    safety: str = SLACK_FAILSAFE_TIMEOUT,
    base: Path = SCENARIO1,
) -> MissionFile:
    """`base` (scenario1) with its first n vehicles (same starts), on free ports and its own key space.

    `kinematics` "continuous" makes the vehicles respond to guidance during the step it is sent
    in (grid mode applies guidance at the next step boundary only, one step late in real time).
    A `[region] area` file is found where `base` is.
    """
    text = base.read_text(encoding="utf-8").replace('area = "', f'area = "{base.parent}/')
    head, *vehicles = text.split("[[vehicles]]")
    vehicles[-1] = vehicles[-1].split("[pass_criteria]")[0]
    assert 1 <= n <= len(vehicles)
    prefix = f"e2e{uuid.uuid4().hex[:12]}"
    head = head.replace('mode = "grid"', f'mode = "{kinematics}"')
    *ports, seed, router = free_ports(n + 2)
    out = head
    for body, port in zip(vehicles[:n], ports, strict=True):
        out += "[[vehicles]]" + body.rstrip() + f"\nmavlink_port = {port}\n\n"
    out += f'[sim]\nhost = "127.0.0.1"\n{sim}\n\n[safety]\n{safety}\n\n'
    out += f'[mesh]\nkey_prefix = "{prefix}"\nseed_endpoint = "tcp/127.0.0.1:{seed}"\n'
    out += f'router = "tcp/127.0.0.1:{router}"\n\n[pass_criteria]\nmin_targets_found = 0\n'
    path = directory / f"mission-{prefix}.toml"
    path.write_text(out, encoding="utf-8")
    return MissionFile(path, ports, load_mission(path))


@pytest.fixture
def make_mission(tmp_path: Path) -> Callable[..., MissionFile]:
    return lambda **kw: write_mission(tmp_path, **kw)


# -- processes ------------------------------------------------------------------------------------
def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time) of a live process, from /proc; None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    if fields[0] == "Z":
        return None
    return int(fields[1]), int(fields[19])


def _children_of(pids: set[int]) -> dict[int, int]:
    """{pid: start time} of the live processes whose parent is in `pids`."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (st := _stat(int(entry.name))) is not None and st[0] in pids:
            found[int(entry.name)] = st[1]
    return found


def _signal_state(pid: int) -> str:
    """A process's state and signal masks (blocked, ignored, caught), from /proc."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return "gone"
    keys = ("State", "SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt")
    return ", ".join(" ".join(line.split()) for line in lines if line.startswith(keys))


def _same_process_alive(pid: int, start: int) -> bool:
    st = _stat(pid)
    return st is not None and st[1] == start


class Proc:
    """A subprocess with its output in a log file; its descendants are tracked while it runs."""

    def __init__(
        self,
        name: str,
        argv: list[str],
        log: Path,
        cwd: Path = ROOT,
        stdin: int | None = subprocess.DEVNULL,
        env: dict[str, str] | None = None,
        stop_signal: int = signal.SIGINT,
    ) -> None:
        self.name, self.argv, self.log, self.stop_signal = name, argv, log, stop_signal
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "MAVLINK20": "1", **(env or {})}
        with log.open("w") as f:
            self.popen = subprocess.Popen(
                argv,
                cwd=cwd,
                stdout=f,
                stderr=subprocess.STDOUT,
                stdin=stdin,
                env=env,
                start_new_session=True,
                text=True,
            )
        self.pid = self.popen.pid
        self.descendants: dict[int, int] = {}  # pid -> start time, PIDs recorded while running
        self._lock = threading.Lock()
        self._watch = threading.Thread(target=self._track, daemon=True)
        self._watch.start()

    def _track(self) -> None:
        while self.popen.poll() is None:
            self.refresh()
            time.sleep(0.3)

    def refresh(self) -> None:
        with self._lock:
            known = {self.pid, *self.descendants}
            while new := {p: s for p, s in _children_of(known).items() if p not in self.descendants}:
                self.descendants.update(new)
                known |= set(new)

    def alive(self) -> bool:
        return self.popen.poll() is None

    def text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def wait_for_text(self, text: str, timeout: float = STARTUP_S) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.text():
            assert self.alive(), f"{self.name} exited with {self.popen.returncode}:\n{self.text()}"
            assert time.monotonic() < deadline, f"{self.name}: no '{text}' in {timeout:.0f} s:\n{self.text()}"
            time.sleep(0.1)

    def wait(self, timeout: float) -> int:
        return self.popen.wait(timeout)

    def stop(self, timeout: float = STOP_S, through_a_thread: bool = False) -> int:
        """`stop_signal` (SIGINT unless told), wait, SIGKILL if still running; then SIGINT and the same
        for any descendant left behind. `through_a_thread`: the signal goes to one of the process's
        threads other than the main one, as the kernel may deliver it."""
        if self.alive():
            self.refresh()
            with contextlib.suppress(ProcessLookupError):
                if through_a_thread:
                    signal_another_thread(self.pid, self.stop_signal)
                else:
                    os.kill(self.pid, self.stop_signal)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                warnings.warn(
                    f"{self.name} (pid {self.pid}) ignored {signal.Signals(self.stop_signal).name} for "
                    f"{timeout:.0f} s: killed "
                    f"({_signal_state(self.pid)})",
                    stacklevel=2,
                )
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.pid, signal.SIGKILL)
                self.popen.wait()
        self._watch.join(timeout=5)
        with self._lock:
            left = {p: s for p, s in self.descendants.items() if _same_process_alive(p, s)}
        for pid, start in left.items():
            if _same_process_alive(pid, start):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGINT)
        deadline = time.monotonic() + timeout
        for pid, start in left.items():
            while _same_process_alive(pid, start) and time.monotonic() < deadline:
                time.sleep(0.1)
            if _same_process_alive(pid, start):
                warnings.warn(f"{self.name}: descendant pid {pid} outlived SIGINT: killed", stacklevel=2)
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        return self.popen.returncode


MAVPROXY = str(Path(sys.executable).parent / "mavproxy.py")  # installed with the test extras


def mavproxy_argv(master: str, directory: Path) -> tuple[list[str], Path]:
    """MAVProxy as a ground station on `master`, its state in `directory`: its argv and its tlog."""
    directory.mkdir(parents=True, exist_ok=True)
    tlog = directory / "gcs.tlog"
    argv = [MAVPROXY, f"--master={master}", "--daemon", "--state-basedir", str(directory)]
    return [*argv, "--logfile", str(tlog)], tlog


class Procs:
    """Every process a test started; `stop_all` (the finalizer) stops them by PID, newest first."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.started: list[Proc] = []

    def start(self, name: str, argv: list[str], **kw: object) -> Proc:
        proc = Proc(name, argv, self.directory / f"{name}.log", **kw)  # type: ignore[arg-type]
        self.started.append(proc)
        return proc

    def sim(self, mission: MissionFile, *args: str, name: str = "sim") -> Proc:
        """The simulator, up when it has printed every vehicle's endpoint."""
        proc = self.start(name, [PY, "-m", "sim_vehicles", "--mission", str(mission.path), *args])
        proc.wait_for_text(f"vehicle {mission.n - 1} sysid")
        return proc

    def companion(self, mission: MissionFile, uav: int, out: Path, *args: str) -> Proc:
        argv = [
            PY,
            "-m",
            "companion.cli",
            "companion",
            "--mission",
            str(mission.path),
            "--uav",
            str(uav),
            "--out",
            str(out),
            *args,
        ]
        return self.start(f"companion{uav}", argv)

    def stop_all(self) -> None:
        for proc in reversed(self.started):
            proc.stop()


def companion_pid(run: Proc, uav: int) -> int:
    """The PID of the launcher's companion process for `uav` (from /proc: its command line)."""
    deadline = time.monotonic() + STARTUP_S
    while True:
        run.refresh()
        for pid in run.descendants:
            try:
                argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if (
                b"companion" in argv
                and b"--uav" in argv
                and argv[argv.index(b"--uav") + 1] == str(uav).encode()
            ):
                return pid
        assert run.alive() and time.monotonic() < deadline, f"no companion {uav}:\n{run.text()}"
        time.sleep(0.2)


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    group = Procs(tmp_path)
    try:
        yield group
    finally:
        group.stop_all()


# -- a ground station -----------------------------------------------------------------------------
class Ground:
    """A pymavlink ground station (system 250) on one vehicle's endpoint (the vehicle listens)."""

    def __init__(self, port: int, sysid: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=250, dialect="ardupilotmega"
        )
        self.sysid = sysid
        self._hello = 0.0

    def _say_hello(self) -> None:
        if time.monotonic() - self._hello >= 1.0:
            self.conn.mav.heartbeat_send(
                mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )
            self._hello = time.monotonic()

    def wait(
        self, kind: str | list[str], cond: Callable[[object], bool] = lambda _m: True, timeout: float = 30.0
    ) -> object | None:
        """The next message of `kind` from our vehicle satisfying `cond`, or None on timeout."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            self._say_hello()
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=min(left, 0.5))
            if msg is not None and msg.get_srcSystem() == self.sysid and cond(msg):
                return msg
        return None

    def set_guided_and_arm(self, timeout: float = 30.0) -> None:
        """What a pilot does before a companion may steer: GUIDED, armed (retried until seen)."""
        m = mavutil.mavlink
        deadline = time.monotonic() + timeout
        while True:
            self.conn.mav.command_long_send(
                self.sysid,
                1,
                m.MAV_CMD_DO_SET_MODE,
                0,
                m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                GUIDED,
                0,
                0,
                0,
                0,
                0,
            )
            self.conn.mav.command_long_send(
                self.sysid, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            )
            beat = self.wait("HEARTBEAT", lambda h: h.get_srcComponent() == 1, timeout=1.5)
            if (
                beat is not None
                and beat.custom_mode == GUIDED
                and beat.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED
            ):
                return
            assert time.monotonic() < deadline, "the vehicle did not take GUIDED + armed"

    def set_mode(self, custom_mode: int, timeout: float = 30.0) -> None:
        """A pilot's mode change (retried until the vehicle's HEARTBEAT shows it)."""
        m = mavutil.mavlink
        deadline = time.monotonic() + timeout
        while True:
            self.conn.mav.command_long_send(
                self.sysid, 1, m.MAV_CMD_DO_SET_MODE, 0, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode,
                0, 0, 0, 0, 0,
            )  # fmt: skip
            beat = self.wait("HEARTBEAT", lambda h: h.get_srcComponent() == 1, timeout=1.5)
            if beat is not None and beat.custom_mode == custom_mode:
                return
            assert time.monotonic() < deadline, f"the vehicle did not take mode {custom_mode}"

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.close()


@pytest.fixture
def ground() -> Iterator[Callable[[int, int], Ground]]:
    opened: list[Ground] = []

    def open_ground(port: int, sysid: int) -> Ground:
        g = Ground(port, sysid)
        opened.append(g)
        return g

    yield open_ground
    for g in opened:
        g.close()


# -- the companion's step log ---------------------------------------------------------------------
def read_csv(path: Path) -> list[dict[str, float]]:
    """Complete rows of a companion's uav{i}.csv (a line cut short by a kill is skipped)."""
    if not path.exists():
        return []
    rows = []
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            try:
                rows.append({k: float(v) for k, v in row.items()})
            except (TypeError, ValueError):
                continue
    return rows


def assert_at_layer_while_steered(m: Mission, uav: int, rows: dict[int, dict[str, float]]) -> None:
    """Every step the companion steered, from the first on, within `ALTITUDE_KEEPING` of its layer.

    The bound the layers' vertical floor rests on. A hand-over on the climb (its plans keep apart
    only the UAVs of its own layer) or before the aircraft gathered speed (it sinks) breaks it
    (`takeover.Levelling`). `rows`: its uav{i}.csv by step."""
    steered = [(k, rows[k]["up"]) for k in sorted(rows) if rows[k]["steered"]]
    assert steered, f"uav{uav} never steered"
    layer = m.altitude_of(uav)
    k, up = max(steered, key=lambda row: abs(row[1] - layer))
    assert abs(up - layer) <= ALTITUDE_KEEPING, (
        f"uav{uav} steered at {up:.1f} m at step {k} (first steered: {steered[0][0]}), its layer {layer:g} m"
    )


def searched(rows: list[dict[str, float]]) -> list[dict[str, float]]:
    """The rows of the mission's steps: without those flown out after its end (`closing`)."""
    return [r for r in rows if not r["closing"]]


def assert_flown_out(rows: list[dict[str, float]], horizon: int) -> None:
    """The companion flew out its trajectory in force after the mission's last step: the next
    horizon + 1 steps, logged with `closing` (docs/companion.md, "The mission's end")."""
    last = int(searched(rows)[-1]["step"])
    flown = [int(r["step"]) for r in rows if r["closing"]]
    assert flown == list(range(last + 1, last + horizon + 2)), f"flown out: {flown} after step {last}"


def wait_vehicles(run: Proc, out: Path, n: int) -> None:
    """Wait until a `uavsearch run`'s simulator (sim.log in `out`) has its n vehicles up."""
    deadline = time.monotonic() + STARTUP_S
    log = out / "sim.log"
    while f"vehicle {n - 1} sysid" not in (log.read_text() if log.exists() else ""):
        assert run.alive() and time.monotonic() < deadline, run.text()
        time.sleep(0.2)


def wait_rows(
    path: Path,
    count: int,
    proc: Proc | None = None,
    timeout: float = STARTUP_S,
    cond: Callable[[dict[str, float]], bool] = lambda _r: True,
) -> list[dict[str, float]]:
    """Wait until `count` rows satisfying `cond` are logged; returns all rows."""
    deadline = time.monotonic() + timeout
    while True:
        rows = read_csv(path)
        if sum(1 for r in rows if cond(r)) >= count:
            return rows
        if proc is not None:
            assert proc.alive(), f"{proc.name} exited with {proc.popen.returncode}:\n{proc.text()}"
        assert time.monotonic() < deadline, f"{path.name}: fewer than {count} rows in {timeout:.0f} s"
        time.sleep(0.1)


@dataclass(frozen=True)
class Following:
    """How the vehicle flew the steps after each command, against flying straight on."""

    informative: int  # consecutive steered steps whose command differs from straight on
    closer: int  # ... after which the vehicle was closer to the commanded point than straight on
    err_command: float  # mean distance of the next pose to the commanded point (m)
    err_straight: float  # mean distance of the next pose to the straight-on prediction (m)


def following(
    rows: list[dict[str, float]], speed: float, dt: float, skip: int = 3, min_gap: float = 5.0
) -> Following:
    """Compare the pose one step after each command with the commanded point (cmd_x, cmd_y: where
    the plan puts the UAV one step later) and with where flying straight on would have put it.

    Only consecutive steered steps count whose commanded point is at least `min_gap` metres from
    the straight-on point (a command to fly straight cannot tell following from ignoring)."""
    by_step = {int(r["step"]): r for r in rows}
    steps = sorted(by_step)[skip:]
    n = closer = 0
    err_c = err_s = 0.0
    for k in steps:
        a, b = by_step[k], by_step.get(k + 1)
        if b is None or not (a["steered"] and b["steered"]):
            continue
        sx = a["x"] + speed * dt * math.cos(a["heading"])
        sy = a["y"] + speed * dt * math.sin(a["heading"])
        if math.hypot(a["cmd_x"] - sx, a["cmd_y"] - sy) < min_gap:
            continue
        c = math.hypot(b["x"] - a["cmd_x"], b["y"] - a["cmd_y"])
        s = math.hypot(b["x"] - sx, b["y"] - sy)
        n += 1
        closer += c < s
        err_c += c
        err_s += s
    return Following(n, closer, err_c / max(n, 1), err_s / max(n, 1))


def assert_follows(
    rows: list[dict[str, float]],
    speed: float,
    dt: float,
    what: str,
    skip: int = 3,
    ratio: float = 0.6,
    closer_share: float = 0.7,
) -> None:
    """The companion steered on most steps and the vehicle flew its commands, not straight on: it
    ended at least `closer_share` of the steps closer to the planned point than straight on would
    have, and on average within `ratio` of straight on's distance to it."""
    later = [r for r in rows if r["step"] >= rows[0]["step"] + skip]
    assert later, f"{what}: no steps logged"
    steered = sum(r["steered"] for r in later) / len(later)
    assert steered >= 0.9, f"{what}: steered on only {steered:.0%} of the steps"
    f = following(rows, speed, dt, skip)
    assert f.informative >= 5, f"{what}: too few turning commands to judge ({f})"
    assert f.closer >= closer_share * f.informative, f"{what}: the vehicle did not follow its commands ({f})"
    assert f.err_command < ratio * f.err_straight, f"{what}: the vehicle did not follow its commands ({f})"


def assert_turns(
    rows: list[dict[str, float]], what: str, skip: int = 3, least: float = 0.4, share: float = 0.9
) -> None:
    """The vehicle turned as commanded: after at least `share` of the steered steps with a turn of
    10 degrees or more, its heading had turned the same way by at least `least` of the turn."""
    by_step = {int(r["step"]): r for r in rows}
    turning = turned = 0
    for k in sorted(by_step)[skip:]:
        a, b = by_step[k], by_step.get(k + 1)
        if b is None or not (a["steered"] and b["steered"]) or abs(a["turn"]) < math.radians(10):
            continue
        flown = math.remainder(b["heading"] - a["heading"], 2 * math.pi)
        turning += 1
        turned += flown / a["turn"] >= least
    assert turning >= 5, f"{what}: too few turns to judge ({turning})"
    assert turned >= share * turning, f"{what}: turned as commanded after {turned} of {turning} turns"
