"""Peers and routers in separate processes: lockstep exchange, SIGKILL and liveliness, router mode."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import threading
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
from mesh_helpers import ROOT, make_mission, outbox, until

from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.node.mesh import Mesh, router_main, run_router
from tests.thread_signal import signal_another_thread

pytestmark = pytest.mark.timeout(60)
Spawn = Callable[..., subprocess.Popen[str]]
OpenMesh = Callable[..., Mesh]
HERE = Path(__file__).resolve().parent


def _readline(proc: subprocess.Popen[str]) -> str:
    assert proc.stdout is not None
    return proc.stdout.readline().strip()


def _start_peer(
    spawn: Spawn, tmp_path: Path, mission: Mission, uav: int, peers: str, steps: int
) -> subprocess.Popen[str]:
    """A peer_proc.py peer, returned once its session is open."""
    path = tmp_path / f"mission-{uav}.json"
    path.write_bytes(msgspec.json.encode(mission))
    proc = spawn(str(HERE / "peer_proc.py"), str(path), str(uav), peers, str(steps))
    assert _readline(proc) == "ready"
    return proc


def test_subprocess_peer_runs_lockstep_then_vanishes_on_sigkill(
    open_mesh: OpenMesh, spawn: Spawn, tmp_path: Path
) -> None:
    mission = make_mission()
    a = open_mesh(mission, 0)  # claims the seed endpoint
    proc = _start_peer(spawn, tmp_path, mission, 1, "0", 3)
    assert a.wait_alive({1}, 15.0) == set()
    for step in range(3):
        a.publish(step, outbox(0, step, 0.0, float(step)))
        assert a.wait_for(step, {1}, 15.0) == set()
        assert a.inbox(step + 1, (0.0, float(step))) == outbox(1, step, 10.0, float(step))
        assert json.loads(_readline(proc)) == {"step": step, "missing": [], "senders": [0, 0, 0]}
    os.kill(proc.pid, signal.SIGKILL)
    assert until(lambda: 1 not in a.alive_peers(), 10.0)
    assert proc.wait(timeout=10) == -signal.SIGKILL


def _client_mission(tmp_path: Path) -> Path:
    """Scenario 1 as a file, in client mode with a fresh router endpoint and key prefix."""
    m = make_mission()
    text = (ROOT / "mission_files/scenario1.toml").read_text()
    text += f'\n[mesh]\nmode = "client"\nkey_prefix = "{m.mesh.key_prefix}"\nrouter = "{m.mesh.router}"\n'
    path = tmp_path / "client.toml"
    path.write_text(text)
    return path


def test_clients_talk_through_a_router_process_that_exits_0_on_sigterm(
    open_mesh: OpenMesh, spawn: Spawn, tmp_path: Path
) -> None:
    path = _client_mission(tmp_path)
    mission = load_mission(path)
    router = spawn("-m", "companion.node.mesh", "router", "--mission", str(path))
    assert _readline(router) == f"router listening on {mission.mesh.router}"
    a, b = open_mesh(mission, 0), open_mesh(mission, 1)
    assert a.wait_alive({1}, 15.0) == set()
    assert b.wait_alive({0}, 15.0) == set()
    a.publish(0, outbox(0, 0, 0.0, 0.0))
    b.publish(0, outbox(1, 0, 1.0, 1.0))
    assert a.wait_for(0, {1}, 10.0) == set()
    assert b.wait_for(0, {0}, 10.0) == set()
    assert a.inbox(1, (0.0, 0.0)) == outbox(1, 0, 1.0, 1.0)
    assert b.inbox(1, (1.0, 1.0)) == outbox(0, 0, 0.0, 0.0)
    a.close()
    assert until(lambda: b.alive_peers() == set())
    router.send_signal(signal.SIGTERM)
    assert router.wait(timeout=15) == 0


def test_router_exits_0_when_sigterm_reaches_one_of_zenohs_threads(spawn: Spawn) -> None:
    """The kernel hands a process's SIGTERM to any thread that does not block it; Python runs the
    handler only when its main thread runs Python code, so a main thread asleep with no timeout
    never sees it (the router's 15 s hang in CI)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{probe.getsockname()[1]}"
    router = spawn("-m", "companion.node.mesh", "router", "--endpoint", endpoint)
    assert _readline(router) == f"router listening on {endpoint}"
    signal_another_thread(router.pid, signal.SIGTERM)
    assert router.wait(timeout=15) == 0


def test_client_waits_for_a_router_started_later_and_run_router_stops_on_event(open_mesh: OpenMesh) -> None:
    mission = make_mission(mode="client")
    stop = threading.Event()
    router = threading.Timer(0.3, run_router, args=(mission.mesh.router, stop))
    router.start()
    try:
        a = open_mesh(mission, 0)  # blocks until the router is up (connect_timeout 10 s)
        b = open_mesh(mission, 1)
        assert a.wait_alive({1}, 15.0) == set()
        b.publish(0, outbox(1, 0, 0.0, 0.0))
        assert a.wait_for(0, {1}, 10.0) == set()
        a.close()
        b.close()
    finally:
        stop.set()
        router.join(timeout=15)
    assert not router.is_alive()


def test_router_main_reports_errors(tmp_path: Path) -> None:
    assert router_main(["--mission", str(tmp_path / "missing.toml")]) == 2
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        assert router_main(["--endpoint", f"tcp/127.0.0.1:{busy.getsockname()[1]}"]) == 1
