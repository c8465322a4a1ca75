"""The companion's journal: what its agent knew, on disk, so that a restarted companion goes on.

An append-only file of CRC-checked records (`length | CRC-32 | msgpack payload`): a `Header` naming
the mission, UAV, seed and run, then after every step a `Checkpoint` (the agent's snapshot, every
`CHECKPOINT_STEPS` steps) or the step's `StepDelta`, each written and `fdatasync`ed before the step's
bundle is published. A record torn by a kill is cut off; recovery restores the last checkpoint and
replays the deltas after it, bit for bit. Format, durability and rejoining: docs/reliability.md,
"Restart without loss".
"""

from __future__ import annotations

import hashlib
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import msgspec

from companion.contracts.mission import Mission
from companion.core.agent import Agent, AgentSnapshot, StepDelta

JOURNAL_VERSION = 1
CHECKPOINT_STEPS = 100
MAX_RECORD_BYTES = 1 << 28  # a checkpoint of the largest grid the mission files allow fits
_PREFIX = struct.Struct("<II")


class JournalError(ValueError):
    """A journal that cannot be used for this companion (the message says why)."""


class Header(msgspec.Struct, frozen=True, tag="header", array_like=True):
    v: int
    mission: str
    digest: str
    uav: int
    seed: int
    run: str = ""


class Checkpoint(msgspec.Struct, frozen=True, tag="checkpoint", array_like=True):
    state: AgentSnapshot


class Delta(msgspec.Struct, frozen=True, tag="delta", array_like=True):
    delta: StepDelta


Record = Header | Checkpoint | Delta
_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(Record)


def header_of(mission: Mission, uav: int, seed: int, run: str = "") -> Header:
    digest = hashlib.sha256(msgspec.msgpack.encode(mission)).hexdigest()[:32]
    return Header(JOURNAL_VERSION, mission.name, digest, uav, seed, run)


def journal_run(path: Path) -> str | None:
    """The run identity a journal's header names (None: no journal there, or no header yet)."""
    try:
        with path.open("rb") as f:
            data = f.read(_PREFIX.size + 4096)
    except FileNotFoundError:
        return None
    records, _ = read_records(data)
    return records[0].run if records and isinstance(records[0], Header) else None


def frame(record: Record) -> bytes:
    """One record as it is written: length, CRC-32, payload."""
    payload = _encoder.encode(record)
    return _PREFIX.pack(len(payload), zlib.crc32(payload)) + payload


def read_records(data: bytes) -> tuple[list[Record], int]:
    """The whole records at the start of `data` and the length of that prefix (the rest is torn)."""
    records: list[Record] = []
    at = 0
    while at + _PREFIX.size <= len(data):
        length, crc = _PREFIX.unpack_from(data, at)
        end = at + _PREFIX.size + length
        if length > MAX_RECORD_BYTES or end > len(data):
            break
        payload = data[at + _PREFIX.size : end]
        if zlib.crc32(payload) != crc:
            break
        try:
            records.append(_decoder.decode(payload))
        except (msgspec.DecodeError, msgspec.ValidationError):
            break
        at = end
    return records, at


@dataclass(frozen=True)
class Recovered:
    """What a journal gave back on opening.

    The last step journaled, how many steps it holds, the records read and the bytes of a torn tail
    cut off.
    """

    step: int
    steps: int
    records: int
    torn_bytes: int


class Journal:
    """The journal of one companion: `open` recovers into the agent, `append` after every step."""

    def __init__(self, path: Path, fd: int, last_checkpoint: int) -> None:
        self.path, self._fd, self._last_checkpoint = path, fd, last_checkpoint
        self.records = self.bytes = 0

    @classmethod
    def open(cls, path: Path, header: Header, agent: Agent) -> tuple[Journal, Recovered | None]:
        """Open (or create) the journal at `path`, restoring `agent` to its last step if it holds any.

        The journal is for `header`'s mission, UAV and seed. Raises JournalError for another
        mission's journal or one that does not fit the agent.
        """
        data = path.read_bytes() if path.exists() else b""
        records, good = read_records(data)
        if data and not records:
            raise JournalError(f"journal {path}: not a journal (or its header is torn): remove it")
        if records and records[0] != header:
            h = records[0]
            what = (
                f"mission {h.mission!r} (digest {h.digest}), uav {h.uav}, seed {h.seed}, run {h.run!r}"
                if isinstance(h, Header)
                else "no header"
            )
            raise JournalError(
                f"journal {path}: written for {what}, not for this companion "
                f"(mission {header.mission!r} (digest {header.digest}), uav {header.uav}, "
                f"seed {header.seed}, run {header.run!r})"
            )
        recovered, last_checkpoint = None, -CHECKPOINT_STEPS
        checkpoints = [i for i, r in enumerate(records) if isinstance(r, Checkpoint)]
        if checkpoints:
            first = checkpoints[-1]
            snap = records[first]
            assert isinstance(snap, Checkpoint)
            try:
                agent.restore(snap.state)
            except ValueError as exc:
                raise JournalError(f"journal {path}: {exc}") from None
            last_checkpoint = step = snap.state.step
            for r in records[first + 1 :]:
                if isinstance(r, Delta) and r.delta.step > step:
                    agent.replay(r.delta)
                    step = r.delta.step
            steps = sum(isinstance(r, Checkpoint | Delta) for r in records)
            recovered = Recovered(step, steps, len(records), len(data) - good)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            os.ftruncate(fd, good)  # a torn last record goes: appends follow the last whole one
            os.lseek(fd, good, os.SEEK_SET)
            journal = cls(path, fd, last_checkpoint)
            if not records:
                journal._write(header)
        except BaseException:
            os.close(fd)
            raise
        return journal, recovered

    def append(self, agent: Agent) -> None:
        """Journal the agent's latest step, durable on return.

        A checkpoint is written when one is due, else the step's delta.
        """
        delta = agent.last
        if delta is None:
            return
        if delta.step - self._last_checkpoint >= CHECKPOINT_STEPS:
            self._write(Checkpoint(agent.snapshot()))
            self._last_checkpoint = delta.step
        else:
            self._write(Delta(delta))

    def _write(self, record: Record) -> None:
        data = frame(record)
        written = os.write(self._fd, data)
        if written != len(data):
            raise OSError(f"journal {self.path}: short write ({written} of {len(data)} bytes)")
        os.fdatasync(self._fd)
        self.records += 1
        self.bytes += written

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
