"""`uavsearch` and `python -m companion.cli`: the command line, imported interruptibly."""

from __future__ import annotations

from companion.contracts.entry import interruptible


def main() -> int:
    """`uavsearch`."""
    return interruptible("companion.cli.main")
