"""A child of `uavsearch run` ends with its launcher, even one that is SIGKILLed.

The launcher names itself in `UAVSEARCH_LAUNCHER_PID`; the child asks the kernel for SIGTERM when
its parent dies (Linux's prctl PR_SET_PDEATHSIG) and so takes its own clean-shutdown path, even
when the launcher is SIGKILLed (a CI job's timeout, the OOM killer) and could stop nothing itself.
"""

from __future__ import annotations

import ctypes
import os
import signal

LAUNCHER_ENV = "UAVSEARCH_LAUNCHER_PID"
_PR_SET_PDEATHSIG = 1


def launcher_env() -> dict[str, str]:
    """What the launcher adds to its children's environment."""
    return {LAUNCHER_ENV: str(os.getpid())}


def end_with_launcher() -> None:
    """If a launcher started this process: ask for SIGTERM when the launcher dies.

    Exits now if the launcher already has died (this process was reparented before it could ask).
    """
    value = os.environ.get(LAUNCHER_ENV, "")
    if not value.isdigit():
        return
    prctl = getattr(ctypes.CDLL(None, use_errno=True), "prctl", None)
    if prctl is None:  # not Linux: the launcher's own stop on SIGINT/SIGTERM still applies
        return
    prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != int(value):
        raise SystemExit(f"error: the launcher (pid {value}) that started this process is gone")
