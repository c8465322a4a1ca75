"""A signal sent to one thread of another process (tgkill), as the kernel may deliver a process's
SIGTERM to any of its threads that does not block it: Zenoh's and asyncio's included."""

from __future__ import annotations

import ctypes
import errno
import os
from pathlib import Path

_LIBC = ctypes.CDLL(None, use_errno=True)


def other_threads(pid: int) -> list[int]:
    """The ids of the threads of process `pid` other than its main thread, oldest first."""
    return sorted(int(t.name) for t in Path(f"/proc/{pid}/task").iterdir() if int(t.name) != pid)


def signal_another_thread(pid: int, sig: int) -> int:
    """Send `sig` to one thread of process `pid` other than its main thread (glibc's tgkill),
    the oldest that still exists (a pool's idle thread may end meanwhile); its id."""
    for tid in other_threads(pid):
        if _LIBC.tgkill(pid, tid, sig) == 0:
            return tid
        err = ctypes.get_errno()
        if err != errno.ESRCH:
            raise OSError(err, f"tgkill({pid}, {tid}, {sig}): {os.strerror(err)}")
    raise ProcessLookupError(f"process {pid} has no thread besides its main thread")
