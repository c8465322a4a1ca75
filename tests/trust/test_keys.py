"""`uavsearch keys` and the key directory: what it writes, what loads, and clear errors otherwise."""

from __future__ import annotations

import json
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from companion.cli.main import main
from companion.contracts import keys
from companion.contracts.mission import MissionError
from companion.core.feasibility import load_mission
from tests.trust.conftest import secured

ROOT = Path(__file__).resolve().parents[2]
SCENARIO1 = ROOT / "mission_files" / "scenario1.toml"


def test_keys_command_writes_a_swarm_from_the_mission(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    mission = tmp_path / "m.toml"
    mission.write_text(SCENARIO1.read_text() + '\n[security]\nkeys = "swarm-keys"\n')
    assert main(["keys", "--mission", str(mission)]) == 0
    d = tmp_path / "swarm-keys"  # relative to the mission file, not to the working directory
    assert json.loads((d / "swarm.json").read_text())["uavs"] == 4
    ca = x509.load_pem_x509_certificate((d / "ca.pem").read_bytes())
    for identity in ["uav-0", "uav-3", "camera", "view", "router"]:
        cert = x509.load_pem_x509_certificate((d / identity / "tls.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == identity
        cert.verify_directly_issued_by(ca)
        assert stat.S_IMODE((d / identity / "tls.key").stat().st_mode) == 0o600
    loaded = keys.for_mission(load_mission(mission), "uav-2")
    assert loaded is not None and loaded.signing is not None and len(loaded.mavlink_secret or b"") == 32
    assert keys.for_mission(load_mission(mission), "view").signing is None  # type: ignore[union-attr]
    # never over an existing swarm: that would orphan every aircraft's keys
    assert main(["keys", "--mission", str(mission)]) == 2
    assert "already there" in capsys.readouterr().err


def test_broken_key_directories_are_named_with_the_reason(tmp_path: Path, key_dir: Path) -> None:
    with pytest.raises(keys.KeyDirectoryError, match=r"swarm\.json"):
        keys.load(tmp_path / "nowhere", "uav-0")
    (key_dir / "uav-1" / "sign.key").write_bytes((key_dir / "uav-2" / "sign.key").read_bytes())
    with pytest.raises(keys.KeyDirectoryError, match=r"not the key swarm\.json lists for uav-1"):
        keys.load(key_dir, "uav-1")
    (key_dir / "uav-0" / "mavlink.key").write_text("abc\n")
    with pytest.raises(keys.KeyDirectoryError, match=r"mavlink\.key: not hex"):
        keys.load(key_dir, "uav-0")
    three = tmp_path / "three"
    keys.generate(three, 3)
    with pytest.raises(keys.KeyDirectoryError, match="keys for 3 uavs, the mission has 4"):
        keys.for_mission(secured(load_mission(SCENARIO1), three), "uav-0")


def test_mission_security_section_is_validated(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        SCENARIO1.read_text() + '\n[mesh]\nrouter = "udp/127.0.0.1:7447"\n\n[security]\nkeys = "k"\n'
    )
    with pytest.raises(MissionError, match=r"mesh.router: a secured mesh .* runs over TLS"):
        load_mission(bad)
    bad.write_text(SCENARIO1.read_text() + "\n[security]\nkeys = 3\n")
    with pytest.raises(MissionError, match=r"security\.keys"):
        load_mission(bad)


def test_an_insecure_mission_says_so_loudly(tmp_path: Path) -> None:
    """The router (the quickest process to start) warns on stderr for a mission without keys;
    here its port is taken, so it stops right after."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        mission = tmp_path / "m.toml"
        port = taken.getsockname()[1]
        mission.write_text(SCENARIO1.read_text() + f'\n[mesh]\nrouter = "tcp/127.0.0.1:{port}"\n')
        proc = subprocess.run(
            [sys.executable, "-m", "companion.cli", "router", "--mission", str(mission)],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
    assert proc.returncode == 1, proc.stderr
    assert "WARNING: INSECURE MODE" in proc.stderr
