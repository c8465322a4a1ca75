"""Process entry: a command line imported inside `interruptible`, so that an early Ctrl-C ends it quietly.

A SIGINT while its modules load (a Ctrl-C in the first second) ends the process with exit code 130
and no traceback, as it does once they are loaded.
"""

from __future__ import annotations

import importlib

INTERRUPTED = 130  # 128 + SIGINT, as a shell reports it


def interruptible(module: str) -> int:
    """`main()` of `module`, imported here: INTERRUPTED on a SIGINT before it takes SIGINT over."""
    try:
        return importlib.import_module(module).main()
    except KeyboardInterrupt:
        return INTERRUPTED
