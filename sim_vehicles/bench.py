"""Benchmark: how many vehicles one simulator process holds in real time, and how fast it runs.

`python -m sim_vehicles.bench` (or `bench_main(argv)`) starts the simulator as a subprocess on a
temporary copy of a mission with N vehicles on free loopback ports, attaches one UDP client per
vehicle (armed, GUIDED, loitering) that drains the telemetry, and reads the simulator's own CPU
time (time.process_time of its loop) and simulated time from its final stats line.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgspec
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts.arguments import HelpFormatter

DEFAULT_MISSION = Path(__file__).resolve().parents[1] / "mission_files" / "scenario1.toml"
REAL_TIME = 0.95  # achieved / requested simulated time that counts as keeping up


def _free_udp_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def _mission_text(base: Path, n: int) -> str:
    """`base` with its vehicles replaced by n vehicles on a connected grid.

    `base` with its vehicles replaced by n vehicles on a grid inside [-900, 900]^2, at most 400 m
    apart (a start layout must be connected within the radio range)."""
    text = base.read_text(encoding="utf-8").split("[[vehicles]]")[0]
    text = text.replace("[pass_criteria]", "[unused]") if "[pass_criteria]" in text else text
    side = math.ceil(math.sqrt(n))
    spacing = min(400.0, 1800 / max(1, side - 1))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        seed_port = s.getsockname()[1]
    for i, port in enumerate(_free_udp_ports(n)):
        x = -900 + spacing * (i % side)
        y = -900 + spacing * (i // side)
        text += f"\n[[vehicles]]\nx = {x:.1f}\ny = {y:.1f}\nmavlink_port = {port}\n"
    text += f'\n[mesh]\nkey_prefix = "bench{os.getpid()}"\nseed_endpoint = "tcp/127.0.0.1:{seed_port}"\n'
    return text


class SimFigures(msgspec.Struct, frozen=True):
    """One `measure` of the simulator.

    The fleet, its speedup asked and achieved, the simulator's CPU share of one core, the telemetry
    its clients received and the simulated seconds it let slip."""

    vehicles: int
    speedup: float
    cpu_share: float
    achieved_speedup: float
    messages_per_s: float
    slipped_s: float


def measure(mission: Path, n: int, speedup: float, duration: float) -> SimFigures:
    """Run n vehicles at `speedup` for `duration` wall seconds; CPU share and achieved speed."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(_mission_text(mission, n), encoding="utf-8")
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim_vehicles", "--mission", str(path), "--speedup", str(speedup)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        assert proc.stdout is not None
        ports, lines = [], []
        for line in proc.stdout:
            lines.append(line)
            if found := re.match(r"vehicle \d+ sysid \d+ mavlink udp [^ ]+:(\d+)", line):
                ports.append(int(found.group(1)))
                if len(ports) == n:
                    break
        if len(ports) < n:
            proc.kill()
            proc.wait()
            raise RuntimeError("simulator did not start:\n" + "".join(lines))
        received = _drive(ports, duration)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
    stats = next(
        json.loads(line.split(": ", 1)[1])
        for line in out.splitlines()
        if line.startswith("sim_vehicles stats: ")
    )
    wall = stats["wall_time"]
    return SimFigures(
        vehicles=n,
        speedup=speedup,
        cpu_share=stats["cpu_time"] / wall,
        achieved_speedup=stats["sim_time"] / wall,
        messages_per_s=received / duration,
        slipped_s=stats["slipped"],
    )


def _drive(ports: list[int], duration: float) -> int:
    """One client per vehicle: arm, GUIDED, then drain telemetry for `duration` s."""
    mav = mavlink.MAVLink(None, srcSystem=250, srcComponent=190)
    sel = selectors.DefaultSelector()
    socks = []
    for i, port in enumerate(ports):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        sysid = i + 1
        for msg in (
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3
            ),
            mavlink.MAVLink_command_long_message(
                sysid, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            ),
            mavlink.MAVLink_command_long_message(
                sysid, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 15, 0, 0, 0, 0, 0
            ),
        ):
            s.sendto(msg.pack(mav), ("127.0.0.1", port))
        sel.register(s, selectors.EVENT_READ)
        socks.append(s)
    received = 0
    end = time.monotonic() + duration
    while (left := end - time.monotonic()) > 0:
        for key, _ in sel.select(left):
            sock = key.fileobj
            assert isinstance(sock, socket.socket)
            while True:
                try:
                    sock.recv(65535)
                    received += 1
                except BlockingIOError:
                    break
    for s in socks:
        s.close()
    sel.close()
    return received


def bench_main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="uavsearch sim-bench", description=__doc__.splitlines()[0], formatter_class=HelpFormatter
    )
    parser.add_argument("--mission", type=Path, default=DEFAULT_MISSION, help="the mission flown")
    parser.add_argument("--vehicles", type=int, default=50, help="fleet size for the real-time run")
    parser.add_argument("--duration", type=float, default=10.0, help="wall seconds per run")
    parser.add_argument(
        "--speedups",
        default="25,50,100,200,400",
        help="speedups tried with 4 vehicles (comma separated, increasing)",
    )
    args = parser.parse_args(argv)
    fleet = measure(args.mission, args.vehicles, 1.0, args.duration)
    print(
        f"{args.vehicles} vehicles in real time: {100 * fleet.cpu_share:.1f} % of one core, "
        f"achieved speedup {fleet.achieved_speedup:.3f}, "
        f"{fleet.messages_per_s:.0f} messages/s received",
        flush=True,
    )
    best = 0.0
    for speedup in (float(s) for s in args.speedups.split(",")):
        r = measure(args.mission, 4, speedup, args.duration)
        ok = r.achieved_speedup >= REAL_TIME * speedup
        print(
            f"4 vehicles at speedup {speedup:g}: achieved {r.achieved_speedup:.1f}, "
            f"{100 * r.cpu_share:.0f} % of one core, {r.slipped_s:.0f} simulated s slipped "
            f"{'ok' if ok else 'FALLS BEHIND'}",
            flush=True,
        )
        if not ok:
            break
        best = speedup
    print(f"highest speedup kept with 4 vehicles: {best:g}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(bench_main())
