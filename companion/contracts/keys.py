"""A swarm's key directory: written by `uavsearch keys`, read by every process that joins the mesh.

It holds `swarm.json` (every UAV's Ed25519 signing keys), the CA (`ca.pem`, `ca.key`), a folder
`uav-{i}/` per UAV (mesh certificate, signing key, MAVLink2 secret) and the camera's, view's and
router's certificates; an aircraft needs `swarm.json`, `ca.pem` and its own folder. A run identity
(`run_id`) is bound into everything signed (`run_secret`: each vehicle's MAVLink2 key for the run),
and `rotate` gives one UAV a new signing key while its old one stays accepted. The layout and the
reasoning: docs/reliability.md, "Keys", "Run identity" and "Key rotation".
"""

from __future__ import annotations

import datetime
import hashlib
import hmac
import json
import os
import re
import secrets
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from companion.contracts.mission import Mission

SWARM_FILE = "swarm.json"
FORMAT = 1
ROLES = ("camera", "view", "router")  # identities besides the UAVs
VALID_DAYS = 365
RUN_ENV = "UAVSEARCH_RUN"  # the run identity of a process started without --run
RUN_RE = re.compile(r"[A-Za-z0-9._-]{0,64}")


class KeyDirectoryError(ValueError):
    """A key directory that cannot be used: names the file and the reason."""


def uav_identity(uav: int) -> str:
    """The mesh identity (certificate common name) of UAV `uav`."""
    return f"uav-{uav}"


@dataclass(frozen=True)
class TlsFiles:
    """One identity's TLS material: the swarm CA, its certificate and private key (paths)."""

    ca: Path
    cert: Path
    key: Path


@dataclass(frozen=True)
class SwarmKeys:
    """What one identity loads from a key directory.

    Its TLS files, the swarm's signing keys and, for a UAV, its own signing key and MAVLink secret.
    """

    directory: Path
    identity: str
    tls: TlsFiles
    public: tuple[tuple[Ed25519PublicKey, ...], ...]  # per UAV: the keys accepted for it
    signing: Ed25519PrivateKey | None = None
    mavlink_secret: bytes | None = None  # for this run (`run_secret`)
    run: str = ""

    @property
    def n_uavs(self) -> int:
        return len(self.public)

    def reload_public(self) -> tuple[tuple[Ed25519PublicKey, ...], ...]:
        """The accepted keys as swarm.json lists them now (a rotation adds one)."""
        return _public_keys(self.directory / SWARM_FILE)


def run_id(explicit: str | None = None) -> str:
    """This process's run identity: `explicit` (`--run`), else $UAVSEARCH_RUN, else "".

    "" is none: what it signs is bound to no run. KeyDirectoryError for one that is not 0-64 of
    [A-Za-z0-9._-].
    """
    run = explicit if explicit is not None else os.environ.get(RUN_ENV, "")
    if not RUN_RE.fullmatch(run):
        raise KeyDirectoryError(f"run id {run[:80]!r}: at most 64 letters, digits, '.', '_' or '-'")
    return run


def new_run_id() -> str:
    """A fresh run identity (what `uavsearch run` issues)."""
    return secrets.token_hex(8)


def run_secret(secret: bytes, run: str) -> bytes:
    """The MAVLink2 signing key of one run: HMAC-SHA256 of the run under the vehicle's secret.

    The secret itself when no run is named.
    """
    if not run:
        return secret
    return hmac.new(secret, b"uavsearch mavlink run\0" + run.encode(), hashlib.sha256).digest()


def generate(directory: Path, n_uavs: int, valid_days: int = VALID_DAYS) -> None:
    """Write a new key directory for `n_uavs` UAVs; refuses to overwrite an existing one."""
    if n_uavs < 1:
        raise ValueError("a swarm needs at least one UAV")
    if (directory / SWARM_FILE).exists():
        raise KeyDirectoryError(f"{directory / SWARM_FILE}: a key directory is already there")
    directory.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "uavsearch swarm CA")])
    ca_cert = (
        _builder(ca_name, ca_name, ca_key.public_key(), now, valid_days)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_key_usage(ca=True), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    _write_private(directory / "ca.key", _pem(ca_key))
    (directory / "ca.pem").write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    public = []
    for identity in [uav_identity(i) for i in range(n_uavs)] + list(ROLES):
        folder = directory / identity
        folder.mkdir(exist_ok=True)
        _issue(folder, identity, ca_key, ca_cert, now, valid_days)
        if identity.startswith("uav-"):
            signing = Ed25519PrivateKey.generate()
            _write_private(folder / "sign.key", _pem(signing))
            _write_private(folder / "mavlink.key", (secrets.token_hex(32) + "\n").encode())
            public.append(_raw(signing.public_key()).hex())
    swarm = {"format": FORMAT, "uavs": n_uavs, "signing_keys": public}
    (directory / SWARM_FILE).write_text(json.dumps(swarm, indent=2) + "\n")


def rotate(directory: Path, uav: int, keep: int = 2) -> None:
    """Give UAV `uav` a new signing key while its `keep` - 1 latest older keys stay accepted.

    Writes its sign.key and lists the new key first in swarm.json, followed by the `keep` - 1 latest
    of its older keys: peers take the new key once they read swarm.json again, with no restart; only
    UAV `uav`'s companion restarts (on its journal).
    """
    path = directory / SWARM_FILE
    public = _public_keys(path)
    if not 0 <= uav < len(public):
        raise KeyDirectoryError(f"{path}: no uav {uav}")
    signing = Ed25519PrivateKey.generate()
    swarm = json.loads(path.read_text())
    listed = [[_raw(k).hex() for k in keys] for keys in public]
    listed[uav] = [_raw(signing.public_key()).hex(), *listed[uav]][: max(keep, 1)]
    swarm["signing_keys"] = [keys[0] if len(keys) == 1 else keys for keys in listed]
    _write_private(directory / uav_identity(uav) / "sign.key", _pem(signing))
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(swarm, indent=2) + "\n")
    tmp.replace(path)  # readers see the old list or the new, never half of one


def load(directory: str | Path, identity: str, run: str = "") -> SwarmKeys:
    """The key material of `identity` ("uav-{i}", "camera", "view" or "router") in `directory`.

    Raises KeyDirectoryError naming the file and the reason for anything missing or malformed.
    """
    d = Path(directory)
    public = _public_keys(d / SWARM_FILE)
    folder = d / identity
    tls = TlsFiles(d / "ca.pem", folder / "tls.pem", folder / "tls.key")
    for path in (tls.ca, tls.cert, tls.key):
        if not path.is_file():
            raise KeyDirectoryError(f"{path}: missing (is {d} a key directory from `uavsearch keys`?)")
    if not identity.startswith("uav-"):
        return SwarmKeys(d, identity, tls, public, run=run)
    signing = _private_key(folder / "sign.key")
    uav = int(identity.removeprefix("uav-"))
    if uav >= len(public) or _raw(signing.public_key()) not in {_raw(k) for k in public[uav]}:
        raise KeyDirectoryError(f"{folder / 'sign.key'}: not the key {SWARM_FILE} lists for {identity}")
    secret = run_secret(mavlink_secret(folder / "mavlink.key"), run)
    return SwarmKeys(d, identity, tls, public, signing, secret, run)


def for_mission(mission: Mission, identity: str, run: str | None = None) -> SwarmKeys | None:
    """`identity`'s keys from the mission's key directory for the run `run_id(run)`; None if insecure."""
    if not mission.secured:
        return None
    keys = load(mission.security.keys, identity, run_id(run))
    if keys.n_uavs != mission.n_uavs:
        raise KeyDirectoryError(
            f"{keys.directory / SWARM_FILE}: keys for {keys.n_uavs} uavs, the mission has {mission.n_uavs}"
        )
    return keys


def mavlink_secrets(mission: Mission, run: str | None = None) -> list[bytes] | None:
    """Every vehicle's MAVLink signing key for the run `run_id(run)` (what the autopilots hold).

    None when the mission does not sign its MAVLink links.
    """
    if not (mission.secured and mission.security.mavlink_signing):
        return None
    directory, name = Path(mission.security.keys), run_id(run)
    paths = [directory / uav_identity(i) / "mavlink.key" for i in range(mission.n_uavs)]
    return [run_secret(mavlink_secret(p), name) for p in paths]


def insecure_warning(mission: Mission) -> str:
    """The warning every process of an insecure mission prints when it starts."""
    return (
        f"WARNING: INSECURE MODE: mission {mission.name!r} names no key directory ([security] keys): "
        "the mesh is plain TCP with no authentication and the MAVLink link is unsigned, so any process "
        "that reaches them can join, inject messages as any UAV and command the vehicles. Fine for a "
        "quick local run; otherwise generate keys with `uavsearch keys` (docs/reliability.md)."
    )


def warn_if_insecure(mission: Mission, stream: TextIO | None = None) -> None:
    """Print `insecure_warning` to `stream` (stderr) when the mission is not secured."""
    if not mission.secured:
        print(insecure_warning(mission), file=stream or sys.stderr, flush=True)


def mavlink_secret(path: str | Path) -> bytes:
    """A MAVLink2 signing secret: 32 bytes written as 64 hex digits."""
    p = Path(path)
    try:
        secret = bytes.fromhex(p.read_text().strip())
    except OSError as exc:
        raise KeyDirectoryError(f"{p}: {exc.strerror or exc}") from None
    except ValueError:
        raise KeyDirectoryError(f"{p}: not hex") from None
    if len(secret) != 32:
        raise KeyDirectoryError(f"{p}: a MAVLink signing secret is 64 hex digits, not {2 * len(secret)}")
    return secret


def _public_keys(path: Path) -> tuple[tuple[Ed25519PublicKey, ...], ...]:
    try:
        swarm = json.loads(path.read_text())
        if swarm.get("format") != FORMAT:
            raise KeyDirectoryError(f"{path}: format {swarm.get('format')!r}, expected {FORMAT}")
        keys = tuple(
            tuple(
                Ed25519PublicKey.from_public_bytes(bytes.fromhex(h))
                for h in ([k] if isinstance(k, str) else k)
            )
            for k in swarm["signing_keys"]
        )
        if not all(keys):
            raise KeyDirectoryError(f"{path}: a UAV with no signing key")
    except OSError as exc:
        raise KeyDirectoryError(f"{path}: {exc.strerror or exc}") from None
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        if isinstance(exc, KeyDirectoryError):
            raise
        raise KeyDirectoryError(f"{path}: malformed ({exc})") from None
    if len(keys) != swarm.get("uavs"):
        raise KeyDirectoryError(f"{path}: {len(keys)} signing keys for {swarm.get('uavs')} uavs")
    return keys


def _private_key(path: Path) -> Ed25519PrivateKey:
    try:
        key = serialization.load_pem_private_key(path.read_bytes(), password=None)
    except OSError as exc:
        raise KeyDirectoryError(f"{path}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise KeyDirectoryError(f"{path}: not a PEM private key ({exc})") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyDirectoryError(f"{path}: not an Ed25519 key")
    return key


def _raw(key: Ed25519PublicKey) -> bytes:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def _issue(
    folder: Path,
    identity: str,
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    now: datetime.datetime,
    valid_days: int,
) -> None:
    """A certificate for `identity` (CN), usable as TLS client and server, issued by the CA."""
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, identity)])
    cert = (
        _builder(name, ca_cert.subject, key.public_key(), now, valid_days)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_key_usage(ca=False), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
            critical=False,
        )
        .add_extension(x509.SubjectAlternativeName([x509.DNSName(identity)]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    _write_private(folder / "tls.key", _pem(key))
    (folder / "tls.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _builder(
    subject: x509.Name, issuer: x509.Name, public_key: object, now: datetime.datetime, valid_days: int
) -> x509.CertificateBuilder:
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(public_key)  # type: ignore[arg-type]
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=valid_days))
    )


def _key_usage(ca: bool) -> x509.KeyUsage:
    return x509.KeyUsage(
        digital_signature=not ca,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=ca,
        crl_sign=ca,
        encipher_only=False,
        decipher_only=False,
    )


def _pem(key: ec.EllipticCurvePrivateKey | Ed25519PrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
