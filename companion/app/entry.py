"""The `uavsearch` entry point. It loads the command line inside `main`, so that a SIGINT while the
modules load (a Ctrl-C in the first second, or the launcher stopping a child it has just started)
ends the process with exit code 130 and no traceback, as it does once they are loaded."""

from __future__ import annotations

INTERRUPTED = 130  # 128 + SIGINT, as a shell reports it


def main() -> int:
    try:
        from companion.app.cli import main as command_line
    except KeyboardInterrupt:
        return INTERRUPTED
    return command_line()
