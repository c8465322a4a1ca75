"""CPU seconds of processes and of the whole machine, from /proc."""

from __future__ import annotations

import os
import time
from pathlib import Path

import msgspec


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (0 if gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def tree_cpu_s(pid: int) -> float:
    """CPU seconds of a live process and all its live descendants."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    tree, grew = {pid}, True
    while grew:
        new = {p for p, parent in parents.items() if parent in tree and p not in tree}
        tree |= new
        grew = bool(new)
    return sum(proc_cpu_s(p) for p in tree)


def machine_ticks() -> tuple[int, int]:
    """(busy, total) jiffies over all CPUs from /proc/stat."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + (values[4] if len(values) > 4 else 0)
    return sum(values) - idle, sum(values)


class MachineLoad(msgspec.Struct, frozen=True):
    """The machine before a benchmark: its cores, how many were busy, the 1-minute load average."""

    cores: int
    busy_cores: float
    loadavg: float


def machine_load(seconds: float = 2.0) -> MachineLoad:
    """How busy the machine is before we start: cores busy over `seconds`, and the load average."""
    b0, t0 = machine_ticks()
    time.sleep(seconds)
    b1, t1 = machine_ticks()
    cores = os.cpu_count() or 1
    return MachineLoad(cores, cores * (b1 - b0) / max(1, t1 - t0), os.getloadavg()[0])
