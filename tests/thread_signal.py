"""A signal sent to one thread of another process (tgkill), as the kernel may deliver a process's
SIGTERM to any of its threads that does not block it: Zenoh's and asyncio's included."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

_LIBC = ctypes.CDLL(None, use_errno=True)


def other_threads(pid: int) -> list[int]:
    """The ids of the threads of process `pid` other than its main thread."""
    return sorted(int(t.name) for t in Path(f"/proc/{pid}/task").iterdir() if int(t.name) != pid)


def signal_thread(pid: int, tid: int, sig: int) -> None:
    """Send `sig` to thread `tid` of process `pid` alone (glibc's tgkill)."""
    if _LIBC.tgkill(pid, tid, sig) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"tgkill({pid}, {tid}, {sig}): {os.strerror(err)}")
