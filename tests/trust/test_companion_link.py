"""One forged packet cannot cut a companion off from its vehicle: a running secured companion
(real process, real simulator, MAVLink2-signed UDP on 127.0.0.1) is sent a HEARTBEAT posing as its
vehicle (system 1, component 1, link 0: the vehicle's own stream), signed with a wrong key and
stamped ten years ahead. pymavlink moves a stream's timestamp before it checks the signature, so
before the fix every genuine frame after it looked like a replay and the link was lost for good;
now the companion keeps flying its vehicle and logs the refusal once.
"""

from __future__ import annotations

import os
import secrets
import socket
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.contracts import keys
from companion.contracts.mavlink_signing import signing_timestamp
from tests.e2e.conftest import Procs, read_csv, wait_rows, write_mission
from tests.trust.conftest import secure_file

pytestmark = pytest.mark.timeout(300)
TEN_YEARS_S = 10 * 365 * 86400
REFUSED = "refused bad signature from system 1 component 1"


def _udp_ports(pid: int) -> list[tuple[str, int]]:
    """The UDP sockets process `pid` has bound (from /proc): (address, port)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[9] in inodes:
            host, port = fields[1].split(":")
            address = socket.inet_ntoa(bytes.fromhex(host)[::-1])
            found.append((address, int(port, 16)))
    return found


def _forged_heartbeat() -> bytes:
    """A HEARTBEAT as vehicle 1's autopilot on link 0, signed with a wrong key, ten years ahead."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = secrets.token_bytes(32)
    mav.signing.sign_outgoing = True
    mav.signing.link_id = 0
    mav.signing.timestamp = signing_timestamp(time.time() + TEN_YEARS_S)
    msg = mav.heartbeat_encode(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
    return bytes(msg.pack(mav))


def test_a_forged_far_future_heartbeat_does_not_cut_the_companion_off(tmp_path: Path, procs: Procs) -> None:
    keys.generate(tmp_path / "keys", 1)
    mission = secure_file(write_mission(tmp_path, n=1), tmp_path / "keys")
    out = tmp_path / "out"
    csv_path = out / "uav0.csv"
    procs.sim(mission, "--speedup", "5")
    comp = procs.companion(mission, 0, out, "--takeover", "--steps", "100000")
    wait_rows(csv_path, 3, comp, cond=lambda r: r["steered"] == 1)

    ports = [p for p in _udp_ports(comp.pid) if p[1] != mission.ports[0]]
    assert ports, "the companion's MAVLink socket"
    assert all(address == "127.0.0.1" for address, _ in ports), f"bound beyond loopback: {ports}"
    forged = _forged_heartbeat()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
        for address, port in ports:
            attacker.sendto(forged, (address, port))
    last = int(read_csv(csv_path)[-1]["step"])
    rows = wait_rows(csv_path, 10, comp, cond=lambda r: r["step"] > last and r["steered"] == 1)
    assert sum(r["step"] > last for r in rows) >= 10
    text = comp.text()
    assert "vehicle link lost" not in text, text[-2000:]
    assert text.count(REFUSED) == 1, text[-2000:]
    assert "old timestamp" not in text
    assert comp.stop() == 0, comp.text()[-2000:]
