"""`uavsearch fuzz`: fuzzing campaigns against the inputs a companion and the simulator take from outside.

docs/reliability.md, "Fuzzing", describes the campaigns. Each input, drawn by Hypothesis
(`companion.app.fuzz_inputs`), goes through the real code that receives it: `mesh` bundles into the
mesh's checks, an `Agent` and a real Zenoh `Mesh`; `mavlink` datagrams into a running simulator and
a companion's `VehicleLink`; `camera` frames into a real `CameraFeed`; `mission` files into
`load_mission` and `uavsearch mc`. Every campaign counts what was accepted and what was rejected;
any other outcome is a failure.
"""

from __future__ import annotations

import logging
import math
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
import zenoh
from hypothesis import strategies as st

from companion.app.fuzz_inputs import JUNK, Campaign, mutations, one_field_replaced, run_examples
from companion.app.loopback import free_ports
from companion.batch.engine import simulate
from companion.contracts import detections
from companion.contracts.frames import LocalFrame
from companion.contracts.mission import Mission, MissionError
from companion.contracts.zenoh_config import MeshConfig
from companion.core.agent import Agent, Observation
from companion.core.feasibility import load_mission
from companion.core.messages import MessageError
from companion.core.world import World, build_world
from companion.node.camera_feed import CameraFeed
from companion.node.mesh import Bundle, Mesh, check_bundle, decode_bundle, encode_bundle, key_base

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # isort: skip

CAMPAIGNS = ("mesh", "mavlink", "camera", "mission")
FULL = {"mesh": 100_000, "mavlink": 10_000, "camera": 10_000, "mission": 1_000}
MISSION_SECONDS = 10.0  # the longest a mission file may take to load or be refused
ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "mission_files" / "scenario1.toml"


# -- mesh -------------------------------------------------------------------------------------------
def _valid_bundles(mission: Mission, steps: int = 40) -> list[Bundle]:
    """Real bundles: the outboxes of a short batch-engine run of the mission."""
    world = build_world(mission, mission.seed, 0)
    agents = [Agent(world, i) for i in range(mission.n_uavs)]
    poses = [(v.x, v.y, math.radians(v.heading_deg)) for v in mission.vehicles]
    bundles: list[Bundle] = []
    inboxes: list[list] = [[] for _ in agents]
    for k in range(steps):
        outs = []
        for i, a in enumerate(agents):
            x, y, h = poses[i]
            cmd, out = a.step(Observation(step=k, x=x, y=y, heading=h, detections=((x, y),)), inboxes[i])
            bundles.append(Bundle(sender=i, stamp=k, x=x, y=y, messages=tuple(out)))
            poses[i] = (*cmd.waypoint, cmd.heading)
            outs.append(out)
        inboxes = [[m for j, o in enumerate(outs) if j != i for m in o] for i in range(len(agents))]
    simulate(mission, mission.seed, 0, 2)  # compiled kernels loaded
    return bundles


def fuzz_mesh(count: int, seed: int) -> Campaign:
    """Bundles through the mesh's checks into an `Agent`, then a share over Zenoh to a real `Mesh`."""
    c = Campaign("mesh")
    mission = load_mission(SCENARIO)
    world = build_world(mission, mission.seed, 0)
    assert world.tessellation is not None  # scenario 1 flies the proposed algorithm: its tasks are cells
    n, cells, tasks = mission.n_uavs, world.grid.n_cells, world.tessellation.n_tasks
    bundles = _valid_bundles(mission)
    valid = [encode_bundle(b) for b in bundles]
    agent = Agent(world, 0)
    accepted: list[bytes] = []
    last = [-1]  # the agent's latest step

    def body(data: object) -> None:
        assert isinstance(data, bytes)
        c.inputs += 1
        try:
            bundle = decode_bundle(data)
            check_bundle(bundle, n, cells, tasks)
        except (MessageError, ValueError) as exc:
            c.reject(str(exc).split(":")[0])
            return
        except Exception as exc:
            c.failures.append(f"{type(exc).__name__}: {exc}")
            return
        c.accepted += 1
        if len(accepted) < 2000:
            accepted.append(data)
        if bundle.sender != 0 and bundle.stamp + 1 > last[0]:  # as on the mesh: steps go forward
            last[0] = bundle.stamp + 1
            try:
                obs = Observation(step=bundle.stamp + 1, x=0.0, y=0.0, heading=0.0)
                agent.step(obs, list(bundle.messages))
            except Exception as exc:
                c.failures.append(f"agent: {type(exc).__name__}: {exc}")

    structured = one_field_replaced([msgspec.to_builtins(b) for b in bundles[:200]])
    run_examples(st.one_of(mutations(valid), structured), count, seed, body)
    over = (accepted + valid)[: min(2000, count)]  # the accepted inputs first, topped up with valid ones
    c.notes["over_zenoh"] = _mesh_over_zenoh(mission, world, over, c)
    return c


def _mesh_over_zenoh(mission: Mission, world: World, payloads: list[bytes], c: Campaign) -> dict[str, int]:
    """Garbled and valid payloads published over loopback to a real Mesh: every sample is counted."""
    ports = free_ports(1)
    m = msgspec.structs.replace(
        mission,
        mesh=msgspec.structs.replace(
            mission.mesh, key_prefix=f"fuzz{uuid.uuid4().hex[:10]}", seed_endpoint=f"tcp/127.0.0.1:{ports[0]}"
        ),
    )
    rng = np.random.default_rng(0)
    garbled = [bytes(rng.integers(0, 256, size=int(rng.integers(0, 300)), dtype=np.uint8)) for _ in payloads]
    assert world.tessellation is not None
    n_tasks = world.tessellation.n_tasks
    endpoint = f"tcp/127.0.0.1:{ports[0]}"
    n_cells = world.grid.n_cells
    with Mesh(m, 0, n_cells, n_tasks, config=MeshConfig("peer", (endpoint,), ())) as receiver:
        sender = Mesh(m, 1, n_cells, n_tasks, config=MeshConfig("peer", (), (endpoint,)))
        try:
            receiver.wait_alive({1}, 30.0)
            pub = sender.session.declare_publisher(  # BLOCK: a busy machine must not drop the storm
                f"{key_base(m)}/uav/1/msg", congestion_control=zenoh.CongestionControl.BLOCK
            )
            sent = 0
            for data in [*payloads, *garbled]:
                pub.put(data)
                sent += 1
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                s = receiver.stats
                if s.samples >= sent:
                    break
                time.sleep(0.1)
            s = receiver.stats
            counted = s.samples
            if counted < sent:
                c.failures.append(f"mesh over zenoh: {sent} sent, {counted} counted")
            probe = Bundle(sender=1, stamp=10**6, x=0.0, y=0.0)
            pub.put(encode_bundle(probe))
            if receiver.wait_for(10**6, {1}, 30.0):
                c.failures.append("mesh over zenoh: a valid bundle after the storm did not arrive")
            pub.undeclare()
        finally:
            sender.close()
    return {
        "sent": sent, "received": s.received, "malformed": s.malformed, "spoofed": s.spoofed,
        "duplicates": s.duplicates, "stale": s.stale,
    }  # fmt: skip


# -- mavlink ----------------------------------------------------------------------------------------
def _valid_frames() -> list[bytes]:
    """MAVLink 2 frames of the messages a vehicle or a companion acts on, with odd values."""
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    rng = np.random.default_rng(1)
    odd = [0.0, -1.0, 1e9, -1e30, math.nan, math.inf, 31010, 3.5]
    frames = []
    for _ in range(40):
        p = [float(rng.choice(odd)) for _ in range(7)]
        msgs = [
            mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3),
            mavlink.MAVLink_command_long_message(1, 1, int(rng.choice([176, 400, 31010, 511, 178])), 0, *p),
            mavlink.MAVLink_set_attitude_target_message(
                0, 1, 1, int(rng.integers(0, 256)), [1, 0, 0, 0], *p[:3], p[3]
            ),
            mavlink.MAVLink_param_set_message(1, 1, b"SIM_GUIDED_TMO", p[0], 9),
            mavlink.MAVLink_param_request_read_message(1, 1, b"TRIM_ARSPD_CM", -1),
            mavlink.MAVLink_mission_count_message(1, 1, int(rng.integers(0, 65536)), int(rng.integers(0, 3))),
            mavlink.MAVLink_set_position_target_global_int_message(
                0, 1, 1, int(rng.choice([0, 3, 5, 6])), 0, int(rng.integers(-2**31, 2**31)),
                int(rng.integers(-2**31, 2**31)), p[0], *p[1:6], 0, 0, 0,
            ),
            mavlink.MAVLink_global_position_int_message(
                0, int(rng.integers(-(2**31), 2**31)), 0, 0, 0, 0, 0, 0, 65535
            ),
            mavlink.MAVLink_attitude_message(0, p[0], p[1], p[2], p[3], p[4], p[5]),
            mavlink.MAVLink_local_position_ned_message(0, *p[:6]),
        ]  # fmt: skip
        for msg in msgs:
            frames.append(bytes(msg.pack(mav)))
    return frames


def fuzz_mavlink(count: int, seed: int) -> Campaign:
    """Half the datagrams to a simulator process, half to a companion's VehicleLink."""
    from companion.node.vehicle_link import VehicleLink

    c = Campaign("mavlink")
    frames = _valid_frames()
    datagrams: list[bytes] = []
    run_examples(mutations(frames), count, seed, lambda d: datagrams.append(d))
    c.inputs = len(datagrams)
    half = len(datagrams) // 2
    with tempfile.TemporaryDirectory() as tmp:
        sim_port, link_port = free_ports(2)
        text = SCENARIO.read_text(encoding="utf-8")
        text = text.replace("[pass_criteria]", f"[sim]\nbase_port = {sim_port}\n\n[pass_criteria]", 1)
        mission_path = Path(tmp) / "fuzz.toml"
        mission_path.write_text(text.replace('name = "scenario1"', f'name = "fuzz{uuid.uuid4().hex[:8]}"'))
        sim = subprocess.Popen(
            [sys.executable, "-m", "sim_vehicles", "--mission", str(mission_path), "--no-camera"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        )  # fmt: skip
        try:
            c.notes["simulator"] = _to_simulator(sim, sim_port, datagrams[:half], c)
        finally:
            if sim.poll() is None:
                sim.send_signal(signal.SIGINT)
            try:
                out = sim.communicate(timeout=30)[0]
            except subprocess.TimeoutExpired:
                sim.kill()
                out = sim.communicate()[0]
        stats = re.search(r"sim_vehicles stats: (\{.*\})", out)
        if stats is None or "Traceback" in out:
            c.failures.append(f"simulator: no clean stop:\n{out[-2000:]}")
        else:
            inp = msgspec.json.decode(stats.group(1))["input"]
            c.notes["simulator_counters"] = inp
            c.rejected += inp["bad_frames"] + inp["rejected"] + inp["unhandled"]
            c.accepted += max(inp["frames"] - inp["rejected"] - inp["unhandled"], 0)
    frame = LocalFrame(load_mission(SCENARIO).region.origin)
    link = VehicleLink(f"udpin:127.0.0.1:{link_port}", frame)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for i, d in enumerate(datagrams[half:]):
                s.sendto(d, ("127.0.0.1", link_port))
                if i % 64 == 63:
                    link.poll(0.0)
            for _ in range(20):
                link.poll(0.01)
        state = link.state
        c.notes["companion_rejected"] = link.rejected
        c.rejected += link.rejected
        for name in ("x", "y", "heading", "time_s"):
            value = getattr(state, name)
            if isinstance(value, float) and math.isnan(value) and state.has_pose:
                c.failures.append(f"companion: pose field {name} is NaN after the storm")
    except Exception as exc:
        c.failures.append(f"companion: {type(exc).__name__}: {exc}")
    finally:
        link.close()
    return c


def _to_simulator(
    sim: subprocess.Popen, port: int, datagrams: list[bytes], c: Campaign
) -> dict[str, int | bool]:
    """The datagrams to a simulator vehicle, then a parameter read it must still answer."""
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    deadline = time.monotonic() + 120
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(0.5)
        hello = bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav))
        while True:  # the vehicle answers once it is up
            s.sendto(hello, ("127.0.0.1", port))
            try:
                s.recvfrom(65535)
                break
            except TimeoutError:
                if sim.poll() is not None or time.monotonic() > deadline:
                    c.failures.append("simulator did not start")
                    return {}
        for i, d in enumerate(datagrams):
            s.sendto(d, ("127.0.0.1", port))
            if i % 100 == 99:
                time.sleep(0.002)  # a UDP socket's buffer is finite: pace the storm
        ask = bytes(mavlink.MAVLink_param_request_read_message(1, 1, b"SIM_GUIDED_TMO", -1).pack(mav))
        answered = False
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        end = time.monotonic() + 30
        while not answered and time.monotonic() < end:
            s.sendto(ask, ("127.0.0.1", port))
            try:
                data, _ = s.recvfrom(65535)
            except TimeoutError:
                continue
            for msg in parser.parse_buffer(data) or []:
                answered |= msg.get_type() == "PARAM_VALUE"
        if not answered or sim.poll() is not None:
            c.failures.append("simulator: no answer to a parameter read after the storm")
    return {"datagrams_sent": len(datagrams), "answered_after": answered}


# -- camera -----------------------------------------------------------------------------------------
def fuzz_camera(count: int, seed: int) -> Campaign:
    """Frames over Zenoh to a real `CameraFeed`: every one taken or counted as rejected."""
    from companion.contracts.zenoh_config import open_session

    c = Campaign("camera")
    mission = load_mission(SCENARIO)
    frame_of = LocalFrame(mission.region.origin)
    valid_frames = [
        detections.CameraFrame(uav=0, time_usec=t, lat=-35.36, lon=149.16, alt=684.0, heading=0.5,
                               detections=((-35.3632, 149.1652),) * (t % 3))
        for t in range(50)
    ]  # fmt: skip
    valid = [detections.encode(f) for f in valid_frames]
    payloads: list[bytes] = []
    structured = one_field_replaced([msgspec.to_builtins(f) for f in valid_frames])
    run_examples(st.one_of(mutations(valid), structured), count, seed, lambda d: payloads.append(d))
    c.inputs = len(payloads)
    port = free_ports(1)[0]
    key = f"fuzz{uuid.uuid4().hex[:10]}/cam/uav/0/camera"
    rx = open_session(MeshConfig("peer", (f"tcp/127.0.0.1:{port}",), ()))
    tx = open_session(MeshConfig("peer", (), (f"tcp/127.0.0.1:{port}",)))
    try:
        feed = CameraFeed(rx, key, 0, mission.n_uavs, frame_of)
        pub = tx.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        time.sleep(1.0)  # the subscription reaches the publisher's session
        taken = 0
        for i, p in enumerate(payloads):
            pub.put(p)
            if i % 500 == 499:  # consume what arrived (frames, not their detections)
                with feed._cond:
                    taken += len(feed._frames)
                    feed._frames.clear()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with feed._cond:
                seen = feed.rejected + len(feed._frames)
            if seen + taken >= len(payloads):
                break
            time.sleep(0.1)
        with feed._cond:
            accepted = taken + len(feed._frames)
        c.accepted, c.rejected = accepted, feed.rejected
        if accepted + feed.rejected != len(payloads):
            c.failures.append(f"camera: {len(payloads)} sent, {accepted + feed.rejected} counted")
        feed.close()
    finally:
        tx.close()
        rx.close()
    return c


# -- mission files ----------------------------------------------------------------------------------
_FIELDS = [
    "region.cell_size", "region.polygon", "prior.targets", "prior.sigma", "prior.centres", "sensor.radius",
    "kinematics.speed", "kinematics.step", "kinematics.turn_limit_deg", "comms.range", "comms.safety",
    "algorithm.n_g", "algorithm.horizon", "steps", "vehicles", "mesh.max_bundle_bytes", "sim.physics_hz",
    "algorithm.lloyd_max_iterations", "safety.margin", "faults.network",
    "kinematics.mode", "safety.failsafe_reach", "safety.buffer", "safety.failsafe_timeout", "sim.physics_hz",
    "sim.camera_hz", "comms.attraction", "comms.repulsion", "algorithm.name", "kinematics.altitude_step",
]  # fmt: skip
_VALUES = st.one_of(
    JUNK,
    st.sampled_from([0.001, 1e-9, 1e12, -40.0, 0, 10**9, 10**18, 2500, 2501, 1e308]),
    st.sampled_from([1e200, 5e-324, 0.499, 0.5, 3600.5, 1e5]),
    st.sampled_from(["continuous", "grid", "proposed", "no-ta", "pheromone"]),
    st.lists(st.tuples(st.floats(-1e7, 1e7), st.floats(-1e7, 1e7)), max_size=6),
)


def _mission_files() -> st.SearchStrategy[bytes]:
    """Scenario files with one field set to anything, or their bytes mutated (not UTF-8 included)."""
    base = [p.read_bytes() for p in sorted((ROOT / "mission_files").glob("scenario*.toml"))]

    @st.composite
    def field_set(draw: st.DrawFn) -> bytes:
        import tomllib

        import tomli_w

        raw = tomllib.loads(draw(st.sampled_from(base)).decode())
        path = draw(st.sampled_from(_FIELDS)).split(".")
        node = raw
        for key in path[:-1]:
            node = node.setdefault(key, {})
        value = draw(_VALUES)
        if value is None:
            node.pop(path[-1], None)
        else:
            node[path[-1]] = value
        try:
            return tomli_w.dumps(raw).encode()
        except (TypeError, ValueError):
            return repr(raw).encode()

    return st.one_of(field_set(), mutations(base))


def fuzz_missions(count: int, seed: int) -> Campaign:
    """Mission files through `load_mission`, and a few of the refused ones through `uavsearch mc`."""
    c = Campaign("mission")
    with tempfile.TemporaryDirectory() as tmp:
        files: list[Path] = []

        def body(data: object) -> None:
            assert isinstance(data, bytes)
            path = Path(tmp) / f"m{c.inputs:06d}.toml"
            path.write_bytes(data)
            c.inputs += 1
            started = time.monotonic()
            try:
                load_mission(path)
                c.accepted += 1
            except MissionError as exc:
                c.reject(exc.field)
                if exc.source != str(path):
                    c.failures.append(f"{path.name}: the error names {exc.source!r}, not the file")
                if len(files) < 4:
                    files.append(path)
            except Exception as exc:
                c.failures.append(f"{path.name}: {type(exc).__name__}: {exc}")
            seconds = time.monotonic() - started
            if seconds > MISSION_SECONDS:
                c.failures.append(f"{path.name}: {seconds:.1f} s to load")
            elif path not in files:  # those kept go through `uavsearch mc` below
                path.unlink()

        run_examples(_mission_files(), count, seed, body)
        c.notes["cli_checked"] = len(files)  # a few: each is a Python process start
        for path in files:
            _check_cli(path, c)
    return c


ERROR_LINE = re.compile(r"^error: mission file (?P<file>\S+): (?P<field>[^:]+): (?P<reason>.+)$")


def _check_cli(path: Path, c: Campaign) -> None:
    """`uavsearch mc` on a bad file: exit 2, one error line naming the file, no traceback."""
    argv = [sys.executable, "-m", "companion.cli", "mc", "--mission", str(path), "--runs", "1"]
    try:
        r = subprocess.run(argv, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        c.failures.append(f"{path.name}: uavsearch mc did not answer within 120 s")
        return
    line = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ""
    m = ERROR_LINE.match(line)
    if r.returncode != 2 or m is None or m["file"] != str(path) or "Traceback" in r.stderr:
        c.failures.append(f"{path.name}: exit {r.returncode}, stderr {r.stderr[-300:]!r}")


# -- helpers ----------------------------------------------------------------------------------------
RUNNERS: dict[str, Callable[[int, int], Campaign]] = {
    "mesh": fuzz_mesh,
    "mavlink": fuzz_mavlink,
    "camera": fuzz_camera,
    "mission": fuzz_missions,
}


def run_campaign(name: str, count: int | None = None, seed: int = 0) -> Campaign:
    """One campaign of `count` inputs (default: the full size, FULL)."""
    started = time.monotonic()
    # the receivers' refusal warnings (one per kind and sender) would fill the output: the campaign
    # counts every refusal itself
    logging.getLogger("companion").setLevel(logging.ERROR)
    c = RUNNERS[name](count or FULL[name], seed)
    c.seconds = time.monotonic() - started
    return c
